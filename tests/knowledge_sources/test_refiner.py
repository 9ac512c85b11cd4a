"""The pose refiner on an in-memory board (through the whole mission: test_skyline_refiner.py)."""

from __future__ import annotations

import numpy as np
import pytest

from blackboard.memory_board import MemoryBlackboard
from knowledge_sources import levels
from knowledge_sources.refiner import PoseRefiner
from models.scenario import RefineSpec, SkylineSpec
from tests.knowledge_sources.rankers import repost


def _refiner(**changed: object) -> PoseRefiner:
    ref, sky = RefineSpec(), SkylineSpec()
    opts = {
        "along_m": ref.along_m,
        "across_m": ref.across_m,
        "levels": ref.levels,
        "grid": ref.grid,
        "edge_weight": ref.edge_weight,
        "step_deg": sky.step_deg,
        "max_heading_deg": sky.max_heading_deg,
        "max_pitch_deg": sky.max_pitch_deg,
        "truncate_deg": sky.truncate_deg,
        "position": ref.position,
        **changed,
    }
    return PoseRefiner("refiner", **opts)


def _poses(small_rendered: dict, refiner: PoseRefiner, chosen: dict[int, int]) -> dict[int, levels.Pose]:
    """Frames ``chosen`` (frame -> viewframe; each frame the image of viewframe frame + 1) refined."""
    bb = MemoryBlackboard()
    bb.add(refiner)
    repost(bb, small_rendered["map"])
    bb.run()
    for frame, k in chosen.items():
        vf = levels.Viewframe.from_hypothesis(small_rendered["viewframes"][frame + 1])
        levels.post(bb.user, levels.SensorFrame(frame=frame, image=vf.pixels(agent="test").image, source="test"))
        x, y, _, heading, _ = levels.Map.from_hypothesis(small_rendered["map"]).pose(k)
        levels.post(
            bb.user,
            levels.Position(
                frame=frame,
                viewframe=k,
                position=[float(x), float(y)],
                heading_deg=float(heading),
                confidence=0.9,
                queries=0,
                backtracks=0,
                latency_ms=1.0,
                ranking=[[k, 0.0]],
                reason="test",
                degraded=[],
                steps=[],
                strategy="associative",
            ),
        )
    bb.run()
    return {p.frame: p for p in (levels.Pose.from_hypothesis(h) for h in bb.hypotheses(levels.POSE))}


@pytest.mark.parametrize("position", [False, True])
def test_the_chosen_viewframes_view_comes_from_the_cache_entry_with_the_same_pose(
    small_rendered: dict, position: bool
) -> None:
    """With the map's viewframe cache entry holding what the refiner's emulator renders, the view at
    the chosen viewframe's pose is read from the entry (its image and depth), not rendered again:
    the same pixels as the render, one render a frame fewer, the same refinement (heading only:
    within 1e-3, as two runs of the rendering path itself differ by ~1e-8 in the score; with the
    position search only the start view's score is compared: the search's choice among nearly
    equal scores follows that noise)."""
    assert small_rendered["map"].body["entry"] is not None
    chosen = {0: 2, 1: 3, 2: 2}
    read = _refiner(position=position)
    got = _poses(small_rendered, read, chosen)
    rendering = _refiner(position=position)
    rendering._open = lambda mp, plain=rendering._open: (plain(mp), setattr(rendering.views, "depths", None))  # type: ignore[method-assign]
    want = _poses(small_rendered, rendering, chosen)
    assert read.views is not None and rendering.views is not None
    assert read.views.depths is not None and rendering.views.depths is None
    assert sorted(got) == sorted(want) == sorted(chosen)
    for k in set(chosen.values()):  # the view read is the view rendered, pixel for pixel
        start = read.views.start_pose(k)
        view, rendered = read.views.own_view(k, start), read.views.emulator.render(start)
        assert view is not None
        np.testing.assert_array_equal(view.image, rendered.image)
        np.testing.assert_array_equal(view.depth, rendered.depth)
        np.testing.assert_array_equal(view.mask, rendered.mask)
    fields = ("heading_deg", "pitch_deg", "score", "start_score", "sigma_heading_deg", "x", "y")
    for frame in chosen:
        a, b = got[frame], want[frame]
        assert a.renders == b.renders - 1
        assert a.start_score == pytest.approx(b.start_score, abs=1e-3)
        if not position:
            assert [getattr(a, f) for f in fields] == pytest.approx([getattr(b, f) for f in fields], abs=1e-3)


def test_an_entry_of_another_rendering_is_not_read(small_rendered: dict, monkeypatch) -> None:
    """A map whose entry is not the refiner's own world's (another camera, renderer, terrain: another
    cache key) leaves every view rendered."""
    from models.world import World

    monkeypatch.setattr(World, "_cache_key", lambda self: "0" * 64)
    refiner = _refiner()
    poses = _poses(small_rendered, refiner, {0: 2})
    assert (
        refiner.views is not None and refiner.views.depths is None and poses[0].renders == 1
    )  # the start view, rendered
    assert np.isfinite(poses[0].heading_deg)
