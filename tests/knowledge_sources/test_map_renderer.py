"""The map renderer on an in-memory board (real rendering, no zenoh)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
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
    assert mp.route.tolist() == [[float(x), float(y)] for x, y in SMALL["route"]]
    assert mp.poses.tolist() == [v.pose for v in sorted(vfs, key=lambda v: v.index)]
    assert [mp.pose(v.index) for v in vfs] == [v.pose for v in vfs]
    assert [lm["id"] for lm in mp.landmarks] == [lm["id"] for lm in SMALL["landmarks"]]
    seen = mp.seen()
    assert set(seen) == set(range(n)) and any(seen.values())
    # what the map says is visible is what the viewframe masks show, with the descriptions' pixels
    # (by reference the messages carry no description: the entry's, as the map renderer read them)
    from models.world import World

    with World.from_scenario(small_rendered["path"]) as world:
        described = {vf.index: vf.description.to_dict() for vf in world.viewframes}
    for v in vfs:
        assert v.description is None and v.entry == mp.entry
        shown = {mp.landmarks[i]["id"] for i in set(v.pixels(agent="test").mask.ravel().tolist()) - {-1}}
        assert set(seen[v.index]) <= shown
        d = described[v.index]
        assert seen[v.index] == {lm: d["nodes"][lm]["pixels"] for lm in d["visible"]}
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
    from models import viewframe_cache

    monkeypatch.setattr(viewframe_cache, "RELEASE_EVERY", 3)
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


#: the map's array fields
ARRAYS = ("route", "poses", "visible", "placements")

#: how the map renderer is told to post the pixels: (scenario render block, option, cache on,
#: pixels expected inline)
POSTING = {
    "cache-by-reference": ({}, {}, True, False),
    "render-inline": ({"inline": True}, {}, True, True),
    "inline-option": ({}, {"inline": True}, True, True),
    "no-cache": ({}, {}, False, True),
}


@pytest.mark.parametrize(("render", "option", "cache", "inline"), POSTING.values(), ids=POSTING.keys())
def test_viewframes_from_the_cache_are_posted_by_reference_unless_inline_is_asked(
    tmp_path, monkeypatch, small_rendered, render, option, cache, inline
) -> None:
    """With a cache entry, each viewframe message names the entry and carries no pixel array;
    with ``render.inline``, the ``inline`` option (``--inline-viewframes``) or without a cache
    they carry them. Either way the readers get the same pixels."""
    import yaml

    from blackboard.codec import encode

    if not cache:
        monkeypatch.setenv("MAPINTERP_CACHE", "off")
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump({**SMALL, "render": {**SMALL["render"], **render}}))
    bb = MemoryBlackboard()
    bb.add(MapRenderer("map-renderer", **option))
    levels.post(bb.user, levels.Scenario(path=str(path), strategy="associative"))
    bb.run()
    mp = levels.Map.from_hypothesis(bb.user.get(levels.map_id()))
    assert (mp.entry is not None) == cache
    # the map is the same however its viewframes came (rendered, or read with their descriptions' data)
    first = levels.Map.from_hypothesis(small_rendered["map"])
    for name in ("viewframes", "priors", "landmarks", "route", "poses", "visible", "placements"):
        assert (
            np.array_equal(getattr(mp, name), getattr(first, name))
            if name in ARRAYS
            else (getattr(mp, name) == getattr(first, name))
        ), name
    reference = {h.id: levels.Viewframe.from_hypothesis(h).pixels(agent="test") for h in small_rendered["viewframes"]}
    from models.world import World

    with World.from_scenario(small_rendered["path"]) as world:  # the descriptions, from the tests' cache entry
        described = {vf.index: vf.description.to_dict() for vf in world.viewframes}
    for h in bb.hypotheses(levels.VIEWFRAME):
        vf = levels.Viewframe.from_hypothesis(h)
        if inline:
            assert vf.entry is None and vf.image is not None and vf.mask is not None
            assert vf.description == described[vf.index]  # inline, the description travels too
        else:
            assert (vf.entry, vf.entry_count) == (mp.entry, mp.viewframes)
            assert (vf.image, vf.mask, vf.background, vf.description) == (None, None, None, None)
            # pose, skyline and the entry's name only: no description (it is in the entry)
            assert len(encode(h.body)) < 200 + vf.skyline.nbytes + len(vf.entry)
        px, ref = vf.pixels(agent="test"), reference[h.id]
        for name in ("image", "mask", "background"):
            a, b = getattr(px, name), getattr(ref, name)
            assert (a is None) == (b is None), name
            if a is not None:
                assert a.dtype == b.dtype and np.array_equal(a, b), name


def test_inline_viewframes_is_passed_to_the_map_renderer_as_its_option(small) -> None:
    """``mapinterp run --inline-viewframes`` reaches the map renderer as its ``inline`` option in the
    mission's plan (as every agent option, also in a remote agent's command line), not through
    the environment; without it the renderer gets no option (the scenario's ``render.inline`` holds)."""
    from knowledge_sources.commands.agent import command_line
    from knowledge_sources.mission import agent_plan
    from models.scenario import load_scenario

    scenario = load_scenario(small)
    options = {name: (factory, opts) for factory, name, opts in agent_plan(scenario, inline_viewframes=True)}
    factory, opts = options["map-renderer"]
    assert opts == {"inline": True}
    assert "inline=true" in command_line(factory, "map-renderer", opts, run_id="r", connect="tcp/127.0.0.1:1")
    assert {name: opts for _, name, opts in agent_plan(scenario)}["map-renderer"] == {}


def _identical(a, b) -> bool:
    """Bodies equal bit for bit: the same keys in the same order, arrays of the same dtype and bytes."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (
            isinstance(a, np.ndarray)
            and isinstance(b, np.ndarray)
            and (a.dtype, a.shape) == (b.dtype, b.shape)
            and a.tobytes() == b.tobytes()
        )
    if isinstance(a, dict):
        return isinstance(b, dict) and list(a) == list(b) and all(_identical(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(_identical(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


def test_from_a_filled_cache_the_map_comes_from_the_entrys_summary_as_it_would_from_its_viewframes(
    tmp_path, monkeypatch
) -> None:
    """A warm run posts from the cache entry's summary without parsing the descriptions (meta.json
    is not parsed at all); every viewframe message and the map are bit for bit what the renderer
    posts from the viewframes (rendering on a miss, or reading them), and so from an entry
    written before summaries (its summary made from its meta.json, and written beside it)."""
    import yaml

    from models import viewframe_cache
    from models.world import World

    monkeypatch.setenv("MAPINTERP_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump(SMALL))

    def run() -> tuple[dict, dict]:
        bb = MemoryBlackboard()
        bb.add(MapRenderer("map-renderer"))
        levels.post(bb.user, levels.Scenario(path=str(path), strategy="associative"))
        bb.run()
        return bb.user.get(levels.map_id()).body, {h.id: h.body for h in bb.hypotheses(levels.VIEWFRAME)}

    rendered = run()  # a miss: rendered into the cache, posted from the viewframes
    (entry,) = (tmp_path / "cache").iterdir()
    with monkeypatch.context() as m:
        m.setattr(viewframe_cache.json, "loads", lambda *a, **k: pytest.fail("meta.json parsed"))
        summarised = run()
    (entry / "summary.npz").unlink()  # as an entry of the code before summaries
    old = run()
    assert (entry / "summary.npz").is_file()
    monkeypatch.setattr(World, "summary", lambda self: None)
    read = run()  # the viewframes read from the entry
    assert len(rendered[1]) == len(SMALL["route"]) and rendered[0]["entry"] == str(entry.resolve())
    for other in (summarised, old, read):
        assert _identical(rendered[0], other[0])
        assert list(rendered[1]) == list(other[1]) and all(_identical(rendered[1][k], other[1][k]) for k in other[1])
