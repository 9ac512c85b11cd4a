"""Drives ranked by the associative memory, without the blackboard: the data the tracker's
calibration (bench/tracking_calibrate.py) and benchmark (bench/tracking.py) read.

:func:`ranked_drive` renders a scenario's viewframes, stores them in the scenario's memory,
simulates (or reads) its camera frames and ranks each one, exactly as the agents do
(models.world.World, models.index.ViewframeIndex). It returns plain
arrays: per frame the variances indexed by route point, the true position, the time, and the
true route point (nearest to the truth, the results' criterion).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from models.index import ViewframeIndex  # noqa: E402
from models.scenario import Scenario, load_scenario  # noqa: E402
from models.tracking import ranking_vector  # noqa: E402
from models.world import World  # noqa: E402

__all__ = ["ranked_drive", "with_drive"]


def with_drive(scenario: Scenario, drive: dict[str, Any], *, seed: int, path: Path) -> Scenario:
    """``scenario`` with ``sensor.simulate.drive = drive`` and simulation seed ``seed``, as a file
    at ``path`` (so it can also run on the blackboard)."""
    import yaml

    data = scenario.model_dump(mode="json", exclude_none=True)
    sim = dict((data.get("sensor") or {}).get("simulate") or {})
    sim.update({"drive": drive, "seed": int(seed)})
    data["sensor"] = {"simulate": sim}
    data.pop("expect", None)
    path.write_text(yaml.safe_dump(data))
    return load_scenario(path)


def ranked_drive(scenario: Scenario | str | Path) -> dict[str, Any]:
    """Rank every camera frame of ``scenario`` against its viewframes (see the module docstring).

    Returns ``{"name", "route" (N, 2), "variances" (T, N), "truth" (T, 3) x, y, heading,
    "times" (T,) or NaN, "true_point" (T,), "rank_ms" (T,)}``.
    """
    from knowledge_sources.results import nearest_viewframe

    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    with World(sc) as world:
        vfs = world.viewframes
        frames = world.sensor_frames
    index = ViewframeIndex(sc.memory, seed=0)
    index.add([v.image for v in vfs], list(range(len(vfs))))
    n = len(vfs)
    variances, rank_ms = [], []
    for f in frames:
        t0 = time.perf_counter()
        r = index.rank(f.image)
        rank_ms.append((time.perf_counter() - t0) * 1e3)
        variances.append(ranking_vector(r.viewframes, r.variances, n))
    route = np.asarray(sc.route, dtype=np.float64)
    truth = np.array([f.truth if f.truth is not None else (np.nan, np.nan, np.nan) for f in frames], float)
    true_point = np.array([nearest_viewframe(t[0], t[1], route) if np.isfinite(t[0]) else -1 for t in truth])
    return {
        "name": sc.name,
        "route": route,
        "variances": np.array(variances),
        "truth": truth,
        "times": np.array([np.nan if f.time is None else f.time for f in frames], float),
        "true_point": true_point,
        "rank_ms": np.array(rank_ms),
    }
