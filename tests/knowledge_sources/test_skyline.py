"""The skyline ranker on an in-memory board: the track window it shares with the indexers."""

from __future__ import annotations

import numpy as np

from blackboard.memory_board import MemoryBlackboard
from knowledge_sources import levels
from knowledge_sources.indexer import AssociativeIndexer
from knowledge_sources.skyline import SKYLINE_SOURCE, SkylineRanker
from models.scenario import SkylineSpec
from tests.knowledge_sources.test_indexer import _frames_from_viewframes, _repost, _track


def _ranker(tracked: bool) -> SkylineRanker:
    return SkylineRanker("skyline", fov_y_deg=45.0, tracked=tracked, **SkylineSpec().match_options())


def test_while_tracking_the_skyline_ranks_the_indexers_window(small_rendered: dict) -> None:
    bb = MemoryBlackboard()
    sky, indexer = _ranker(True), AssociativeIndexer("indexer-0", tracked=True)
    bb.add(sky)
    bb.add(indexer)
    for h in small_rendered["viewframes"]:
        _repost(bb, h)
    n = len(small_rendered["viewframes"])
    body = dict(small_rendered["map"].body)
    body["memory"] = {**body["memory"], "window_route_points": n, "window_margin": 1, "window_full_every": 4}
    bb.post(levels.MAP, body, id=levels.map_id())
    bb.run()

    def ranking(frame: int) -> levels.Ranking:
        got = bb.user.get(levels.ranking_id(frame, 0, SKYLINE_SOURCE))
        assert got is not None
        return levels.Ranking.from_hypothesis(got)

    _frames_from_viewframes(bb, small_rendered, [0])
    bb.run()
    full = ranking(0)
    assert sorted(full.viewframes) == list(range(n))  # frame 0: everything
    for frame, state in [(1, "tracking"), (2, "lost"), (3, "tracking"), (4, "tracking")]:
        levels.post(bb.user, _track(frame - 1, state, frame + 1, n))
        bb.run()
        _frames_from_viewframes(bb, small_rendered, [frame])
        bb.run()
    assert sky.windows == indexer.windows == {0: None, 1: (1, 3), 2: None, 3: (3, 5), 4: None}
    assert sorted(ranking(1).viewframes) == [1, 2, 3] and ranking(1).viewframes[0] == 1
    assert sorted(ranking(3).viewframes) == [3, 4, 5]
    assert sorted(ranking(2).viewframes) == list(range(n))  # lost: everything
    # within a window, the errors are the full match's (no roll-candidate cut on 8 viewframes)
    bb2 = MemoryBlackboard()
    bb2.add(_ranker(False))
    for h in small_rendered["viewframes"]:
        _repost(bb2, h)
    _repost(bb2, small_rendered["map"])
    _frames_from_viewframes(bb2, small_rendered, [1])
    bb2.run()
    got = bb2.user.get(levels.ranking_id(1, 0, SKYLINE_SOURCE))
    assert got is not None
    every = levels.Ranking.from_hypothesis(got)
    errors = dict(zip(every.viewframes, every.variances))
    win = ranking(1)
    assert np.allclose(win.variances, [errors[k] for k in win.viewframes])


def test_an_untracked_skyline_ranker_ignores_tracks(small_rendered: dict) -> None:
    bb = MemoryBlackboard()
    sky = _ranker(False)
    bb.add(sky)
    for h in small_rendered["viewframes"]:
        _repost(bb, h)
    body = dict(small_rendered["map"].body)
    body["memory"] = {**body["memory"], "window_route_points": 1, "window_margin": 0}
    bb.post(levels.MAP, body, id=levels.map_id())
    levels.post(bb.user, _track(0, "tracking", 3, len(small_rendered["viewframes"])))
    _frames_from_viewframes(bb, small_rendered, [0, 1])
    bb.run()
    assert sky.windows == {0: None, 1: None}
