"""What a finished run looked at, rebuilt from its scenario: viewframes and camera frames.

Results files and traces keep no images (a trace summarises arrays); the report, the HTML
report and the Rerun export redraw them from the scenario the run used: the viewframes are
rendered again and simulated camera frames simulated again with the scenario's seed, which
gives the images the run saw (rendering is deterministic on one machine).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["Replay", "replay", "scenario_path_of_trace", "answer_box"]


@dataclass
class Replay:
    """``scenario``; ``environment``; ``viewframes`` (by viewframe index: the route points', and
    those between them with ``render.views_per_leg`` > 1); ``frames`` camera frames by index;
    ``pattern`` the scenario's memory preprocessing (for edge images)."""

    scenario: Any
    environment: Any
    viewframes: list[Any]
    frames: dict[int, Any]
    pattern: Callable[[np.ndarray], np.ndarray]

    def edges(self, image: np.ndarray) -> np.ndarray:
        """The edge image the associative memory stores for ``image``, float32 (N, N)."""
        return self.pattern(image)


def replay(scenario: Any, *, progress: Callable[[int, int], None] | None = None) -> Replay:
    """Render the scenario's viewframes and camera frames again (offscreen), through its
    :class:`~models.world.World`; ``progress(done, total)`` follows the viewframes."""
    from models.index import ViewframeIndex
    from models.world import World

    with World(scenario, progress=progress) as world:
        env = world.environment
        viewframes = world.viewframes
        frames = {f.index: f for f in world.sensor_frames}
    return Replay(scenario, env, viewframes, frames, ViewframeIndex(scenario.memory).pattern)


def scenario_path_of_trace(records: list[dict[str, Any]]) -> Path | None:
    """The scenario file a traced run used (the body of its ``scenario`` post), or None."""
    for r in records:
        if r.get("kind") == "post" and r.get("level") == "scenario" and isinstance(r.get("body"), dict):
            path = r["body"].get("path")
            if path:
                return Path(path)
    return None


def answer_box(viewframe: Any, landmark: str) -> tuple[int, int, int, int] | None:
    """(row0, col0, row1, col1) inclusive of ``landmark`` in ``viewframe``'s description: the
    image region a detector was asked about, or None when the landmark is not visible there."""
    graph = viewframe.description.graph
    if landmark not in graph.nodes:
        return None
    r0, c0, r1, c1 = graph.nodes[landmark]["bbox"]
    return int(r0), int(c0), int(r1), int(c1)
