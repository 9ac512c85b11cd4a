"""Fixtures of the knowledge_sources tests: a small scenario that runs end to end in seconds."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import pytest
import yaml

SMALL = {
    "name": "small",
    "seed": 3,
    "terrain": {"cell_size": 10.0, "procedural": {"size": 96, "relief": 80.0, "seed": 5}},
    "landmarks": [
        {"id": "H1", "kind": "house", "x": 300, "y": 330, "width": 18, "depth": 12, "height": 8, "yaw_deg": 10},
        {"id": "T1", "kind": "tower", "x": 420, "y": 420, "width": 4, "depth": 4, "height": 30},
        {"id": "H2", "kind": "house", "x": 520, "y": 470, "width": 18, "depth": 12, "height": 8, "yaw_deg": 60},
    ],
    "route": [[220, 260], [260, 290], [300, 300], [340, 320], [380, 350], [420, 370], [460, 400], [500, 420]],
    "camera": {"width": 160, "height": 120, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 5000.0},
    "sensor": {"simulate": {"per_point": 1, "jitter_m": 0.5, "jitter_deg": 1.0, "advance": 0.05}},
    # the scheduler's own query timeout (10 s): a question answered late on a loaded machine is
    # still answered, so one run's results equal another's; tests of dead agents set a short one
    # a viewframe per route point: the agents' tests count and index them by route point;
    # viewframes between the points (the default on short routes) in test_views.py
    "render": {"views_per_leg": 1},
}


def inline_viewframe(vf: Any) -> Any:
    """The viewframe message ``vf`` (:class:`knowledge_sources.levels.Viewframe`) with its pixels
    and description inline, read from its cache entry when it names one (the map renderer posts
    them by reference when the viewframes come from the cache, as in the tests)."""
    import dataclasses

    if vf.entry is None:
        return vf
    px = vf.pixels(agent="test")
    description = dict(_entry_descriptions(vf.entry)[vf.index])
    return dataclasses.replace(
        vf,
        image=px.image,
        mask=px.mask,
        background=px.background,
        description=description,
        entry=None,
        entry_count=None,
    )


@functools.lru_cache(maxsize=4)
def _entry_descriptions(entry: str) -> tuple[dict, ...]:
    """The symbolic descriptions (plain data) of every viewframe of the cache entry folder ``entry``."""
    from models.viewframe_cache import ViewframeCache

    folder = Path(entry)
    viewframes = ViewframeCache(folder.parent).read(folder.name)
    assert viewframes is not None, f"{entry}: not a readable viewframe cache entry"
    return tuple(vf.description.to_dict() for vf in viewframes)


@pytest.fixture
def small_data() -> dict:
    """A deep copy of SMALL, to change freely."""
    return yaml.safe_load(yaml.safe_dump(SMALL))


@pytest.fixture
def small(tmp_path) -> Path:
    """The SMALL scenario written to a YAML file."""
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump(SMALL))
    return path


@pytest.fixture(scope="session")
def small_rendered(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """SMALL rendered once by the map renderer on an in-memory board: ``{"path", "viewframes", "map"}``
    (the viewframe and map hypotheses), for the tests of the agents downstream of it."""
    from blackboard.memory_board import MemoryBlackboard
    from knowledge_sources import levels
    from knowledge_sources.map_renderer import MapRenderer

    path = tmp_path_factory.mktemp("small") / "small.yaml"
    path.write_text(yaml.safe_dump(SMALL))
    bb = MemoryBlackboard()
    bb.add(MapRenderer("map-renderer"))
    levels.post(bb.user, levels.Scenario(path=str(path), strategy="associative"))
    bb.run()
    mp = bb.user.get(levels.map_id())
    assert mp is not None
    return {"path": path, "viewframes": bb.hypotheses(levels.VIEWFRAME), "map": mp}
