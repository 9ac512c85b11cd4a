"""The skyline ranker on an in-memory board: it ranks the indexers' track window, with the errors
of the full match (the lifecycle it shares with the indexer is tested in test_ranker.py)."""

from __future__ import annotations

import numpy as np

from blackboard.memory_board import MemoryBlackboard
from knowledge_sources import levels
from knowledge_sources.indexer import AssociativeIndexer
from knowledge_sources.skyline import SKYLINE_SOURCE, SkylineRanker
from models.scenario import SkylineSpec
from tests.knowledge_sources.rankers import frames_from_viewframes, post_map, repost, track


def _ranker(tracked: bool) -> SkylineRanker:
    return SkylineRanker("skyline", fov_y_deg=45.0, tracked=tracked, **SkylineSpec().match_options())


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
