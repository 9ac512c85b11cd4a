"""The map renderer on an in-memory board (real rendering, no zenoh)."""

from __future__ import annotations

from pathlib import Path

import pytest

from blackboard.memory_board import MemoryBlackboard
from knowledge_sources import levels
from knowledge_sources.errors import MAPINTERP_ERRORS
from knowledge_sources.map_renderer import MapRenderer
from tests.knowledge_sources.conftest import SMALL


def test_posts_every_viewframe_then_the_map(small_rendered: dict) -> None:
    vfs = [levels.Viewframe.from_hypothesis(h) for h in small_rendered["viewframes"]]
    n = len(SMALL["route"])
    assert sorted(v.index for v in vfs) == list(range(n))
    assert {h.id for h in small_rendered["viewframes"]} == {levels.viewframe_id(k) for k in range(n)}
    cam = SMALL["camera"]
    for v in vfs:
        px = v.pixels(agent="test")
        assert px.image.shape == (cam["height"], cam["width"], 3) and px.mask.shape == px.image.shape[:2]
        assert v.pose[:2] == pytest.approx(SMALL["route"][v.index])
    mp_h = small_rendered["map"]
    mp = levels.Map.from_hypothesis(mp_h)
    assert mp_h.timestamp >= max(h.timestamp for h in small_rendered["viewframes"])
    assert mp.viewframes == n and mp.scenario == "small" and mp.path == str(small_rendered["path"])
    assert mp.route == [[float(x), float(y)] for x, y in SMALL["route"]]
    assert mp.poses == [v.pose for v in sorted(vfs, key=lambda v: v.index)]
    assert [lm["id"] for lm in mp.landmarks] == [lm["id"] for lm in SMALL["landmarks"]]
    assert set(mp.visible) == {str(k) for k in range(n)}
    # what the map says is visible is what the viewframe masks show
    for v in vfs:
        shown = {mp.landmarks[i]["id"] for i in set(v.pixels(agent="test").mask.ravel().tolist()) - {-1}}
        assert set(mp.visible[str(v.index)]) <= shown
    assert set(mp.priors) == {lm["id"] for lm in SMALL["landmarks"]}
    assert all(0.0 <= p <= 1.0 for p in mp.priors.values())
    assert mp_h.links == (levels.scenario_id(),)
    # the tests' cache (tests/conftest.py) holds the viewframes: the map names its entry
    assert mp.entry is not None and (Path(mp.entry) / "meta.json").is_file() and Path(mp.entry).is_absolute()


def test_the_renderer_waits_for_the_board_after_each_batch(tmp_path, monkeypatch) -> None:
    """Flow control: after every batch of viewframes the renderer reads the last one back (a read
    the node answers once it has received every post the renderer sent), so a renderer reading a
    filled cache cannot queue the whole route's messages at the node."""
    import yaml

    from blackboard.memory_board import MemoryBoard
    from knowledge_sources import map_renderer

    monkeypatch.setattr(map_renderer, "RELEASE_EVERY", 3)
    reads: list[tuple[str, str, int]] = []
    plain = MemoryBoard.get

    def get(self, hypothesis_id):
        got = plain(self, hypothesis_id)
        reads.append((self.agent, hypothesis_id, len(self._bb.hypotheses(levels.VIEWFRAME))))
        return got

    monkeypatch.setattr(MemoryBoard, "get", get)
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump(SMALL))
    bb = MemoryBlackboard()
    bb.add(MapRenderer("map-renderer"))
    levels.post(bb.user, levels.Scenario(path=str(path), strategy="associative"))
    bb.run()
    n = len(SMALL["route"])
    mine = [(k, posted) for agent, k, posted in reads if agent == "map-renderer"]
    last = sorted({*range(2, n, 3), n - 1})
    assert mine == [(levels.viewframe_id(k), k + 1) for k in last]  # each read after its batch's posts


def test_a_missing_scenario_file_is_named(tmp_path) -> None:
    bb = MemoryBlackboard()
    bb.add(MapRenderer("map-renderer"))
    missing = tmp_path / "nope.yaml"
    levels.post(bb.user, levels.Scenario(path=str(missing), strategy="associative"))
    with pytest.raises(MAPINTERP_ERRORS, match="nope.yaml"):
        bb.run()
    assert bb.hypotheses(levels.VIEWFRAME) == []
