"""The skyline ranker on an in-memory board: it ranks the indexers' track window, with the errors
of the full match (the lifecycle it shares with the indexer is tested in test_ranker.py)."""

from __future__ import annotations

import numpy as np
import pytest

from blackboard.memory_board import MemoryBlackboard
from knowledge_sources import levels
from knowledge_sources.indexer import AssociativeIndexer
from knowledge_sources.skyline import SKYLINE_SOURCE, SkylineRanker
from models.scenario import SkylineSpec
from tests.knowledge_sources.rankers import frames_from_viewframes, post_map, repost, track


def _ranker(tracked: bool, **options: object) -> SkylineRanker:
    return SkylineRanker("skyline", fov_y_deg=45.0, tracked=tracked, **{**SkylineSpec().match_options(), **options})


def _ranking(bb: MemoryBlackboard, frame: int) -> levels.Ranking:
    got = bb.user.get(levels.ranking_id(frame, 0, SKYLINE_SOURCE))
    assert got is not None
    return levels.Ranking.from_hypothesis(got)


def test_while_tracking_the_skyline_ranks_the_indexers_window_with_the_full_matchs_errors(
    small_rendered: dict,
) -> None:
    bb = MemoryBlackboard()
    sky, indexer = _ranker(True), AssociativeIndexer("indexer-0", tracked=True)
    bb.add(sky)
    bb.add(indexer)
    n = len(small_rendered["viewframes"])
    post_map(bb, small_rendered, window_route_points=n, window_margin=1, window_full_every=4)
    bb.run()
    frames_from_viewframes(bb, small_rendered, [0])
    bb.run()
    for frame, state in [(1, "tracking"), (2, "lost"), (3, "tracking"), (4, "tracking")]:
        levels.post(bb.user, track(frame - 1, state, frame + 1, n))
        bb.run()
        frames_from_viewframes(bb, small_rendered, [frame])
        bb.run()
    assert sky.windows == indexer.windows == {0: None, 1: (1, 3), 2: None, 3: (3, 5), 4: None}
    # within a window, the errors are the full match's (no roll-candidate cut on 8 viewframes)
    bb2 = MemoryBlackboard()
    bb2.add(_ranker(False))
    for h in small_rendered["viewframes"]:
        repost(bb2, h)
    repost(bb2, small_rendered["map"])
    frames_from_viewframes(bb2, small_rendered, [1])
    bb2.run()
    every = _ranking(bb2, 1)
    errors = dict(zip(every.viewframes, every.variances))
    win = _ranking(bb, 1)
    assert sorted(win.viewframes) == [1, 2, 3]
    assert np.allclose(win.variances, [errors[k] for k in win.viewframes])


@pytest.mark.parametrize("candidates", [3, 8])
def test_with_the_coarse_stage_the_skyline_ranks_its_candidates_with_the_full_matchs_errors(
    small_rendered: dict, candidates: int
) -> None:
    """``coarse_candidates`` M: the ranking holds the coarse stage's M best viewframes (all 8 for
    M = 8: the full ranking), with the errors of the full match of every viewframe."""
    from models.skyline import skyline_from_image
    from models.skyline_coarse import CoarseSkylines, coarse_candidates

    every, coarse = _ranker(False), _ranker(False, coarse_candidates=candidates)
    got = {}
    for sky in (every, coarse):
        bb = MemoryBlackboard()
        bb.add(sky)
        post_map(bb, small_rendered)
        frames_from_viewframes(bb, small_rendered, [2, 5])
        bb.run()
        got[sky] = {k: _ranking(bb, k) for k in (2, 5)}
    refs = np.stack([levels.Viewframe.from_hypothesis(h).skyline for h in small_rendered["viewframes"]])
    for k in (2, 5):
        full, part = got[every][k], got[coarse][k]
        errors = dict(zip(full.viewframes, full.variances))
        image = levels.Viewframe.from_hypothesis(small_rendered["viewframes"][k]).pixels(agent="test").image
        q = skyline_from_image(image, fov_y_deg=45.0)
        want = coarse_candidates(q, CoarseSkylines.prepare(refs), candidates)
        assert sorted(part.viewframes) == want.tolist() and len(part.viewframes) == candidates
        assert np.allclose(part.variances, [errors[v] for v in part.viewframes])
        assert part.viewframes[0] == full.viewframes[0] == k
        if candidates >= len(refs):
            assert part.viewframes == full.viewframes and part.variances == full.variances


def test_a_bad_coarse_candidates_is_refused_naming_the_option() -> None:
    with pytest.raises(ValueError, match="coarse_candidates must be >= 1 or None, got 0"):
        _ranker(False, coarse_candidates=0)


def test_the_scheduler_fuses_the_coarse_stages_ranking_in_a_mission(tmp_path, small_data: dict) -> None:
    """A whole mission (every agent in one process) with ``skyline.coarse_candidates: 3`` on the
    8-viewframe route: every skyline ranking holds 3 viewframes, the scheduler fuses them with the
    associative rankings of all 8 and localizes every frame."""
    import yaml

    from knowledge_sources.mission import run_mission

    small_data["skyline"] = {"coarse_candidates": 3}
    path = tmp_path / "coarse.yaml"
    path.write_text(yaml.safe_dump(small_data))
    sizes: dict[str, list[int]] = {"skyline": [], "associative": []}

    def seen(level: str, body, stamp: float) -> None:
        if level == levels.RANKING:
            sizes[str(body["source"])].append(len(body["viewframes"]))

    results = run_mission(path, track=False, on_hypothesis=seen)
    n = len(small_data["route"])
    assert results["summary"]["posted"] == n and results["summary"]["localized"] == n
    assert sizes["skyline"] == [3] * n
    assert sizes["associative"] and all(s == n for s in sizes["associative"])
    assert results["summary"]["top1"] >= 0.75


def test_with_a_cache_the_skylines_come_from_the_entry_not_the_messages(small_rendered: dict) -> None:
    """With a viewframe cache on (as in the tests) the ranker does not consume the viewframe
    level: it reads the skylines from the entry the map names, and ranks as a ranker fed by the
    viewframe messages (a map without an entry)."""
    sky = _ranker(False)
    assert not sky.keep_profiles and levels.VIEWFRAME not in sky.consumes
    bb = MemoryBlackboard()
    bb.add(sky)
    repost(bb, small_rendered["map"])  # no viewframe message on this board
    frames_from_viewframes(bb, small_rendered, [1, 5])
    bb.run()
    fed = _ranker(False, keep_profiles=True)
    assert levels.VIEWFRAME in fed.consumes
    bb2 = MemoryBlackboard()
    bb2.add(fed)
    for h in small_rendered["viewframes"]:
        repost(bb2, h)
    bb2.post(levels.MAP, {**small_rendered["map"].body, "entry": None}, id=levels.map_id())
    frames_from_viewframes(bb2, small_rendered, [1, 5])
    bb2.run()
    for frame in (1, 5):
        a, b = _ranking(bb, frame), _ranking(bb2, frame)
        assert a.viewframes == b.viewframes and a.variances == b.variances and a.shifts == b.shifts
        assert a.viewframes[0] == frame
