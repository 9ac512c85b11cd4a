"""The associative indexer on an in-memory board: shards, waiting frames, late joining."""

from __future__ import annotations

import numpy as np
import pytest

from blackboard.hypothesis import Hypothesis
from blackboard.memory_board import MemoryBlackboard
from knowledge_sources import levels
from knowledge_sources.indexer import AssociativeIndexer


def _repost(bb: MemoryBlackboard, h: Hypothesis) -> None:
    bb.post(h.level, h.body, id=h.id)


def _frames_from_viewframes(bb: MemoryBlackboard, small_rendered: dict, ks: list[int]) -> None:
    """Camera frames that are exactly viewframes ``ks`` (each must rank its own viewframe first)."""
    for k in ks:
        vf = levels.Viewframe.from_hypothesis(small_rendered["viewframes"][k])
        levels.post(bb.user, levels.SensorFrame(frame=k, image=vf.image, source="test"))


@pytest.mark.parametrize("shards", [1, 2])
def test_each_shard_stores_its_viewframes_and_ranks_every_frame(small_rendered: dict, shards: int) -> None:
    bb = MemoryBlackboard()
    for b in range(shards):
        bb.add(AssociativeIndexer(f"indexer-{b}", shard=b, shards=shards))
    for h in small_rendered["viewframes"]:
        _repost(bb, h)
    _repost(bb, small_rendered["map"])
    bb.run()
    n = len(small_rendered["viewframes"])
    index = {i.shard: i for i in (levels.Index.from_hypothesis(h) for h in bb.hypotheses(levels.INDEX))}
    assert sorted(index) == list(range(shards)) and sum(i.viewframes for i in index.values()) == n
    _frames_from_viewframes(bb, small_rendered, list(range(n)))
    bb.run()
    rankings = [levels.Ranking.from_hypothesis(h) for h in bb.hypotheses(levels.RANKING)]
    assert len(rankings) == n * shards
    for r in rankings:
        assert set(r.viewframes) == {k for k in range(n) if k % shards == r.shard}
        assert r.variances == sorted(r.variances) and r.shards == shards
        if r.frame % shards == r.shard:
            assert r.viewframes[0] == r.frame  # the frame is its own viewframe
        h = bb.user.get(levels.ranking_id(r.frame, r.shard))
        assert h is not None and h.links == (levels.frame_id(r.frame),) and 0.0 <= h.credibility <= 1.0


def test_frames_before_the_map_wait_and_late_viewframes_are_read_back(small_rendered: dict) -> None:
    bb = MemoryBlackboard()
    for h in small_rendered["viewframes"]:  # posted before the indexer joins: it reads them back
        _repost(bb, h)
    bb.add(AssociativeIndexer("indexer-0"))
    _frames_from_viewframes(bb, small_rendered, [2, 5])
    bb.run()
    assert bb.hypotheses(levels.RANKING) == []  # waiting for the map
    _repost(bb, small_rendered["map"])
    bb.run()
    best = {
        r.frame: r.viewframes[0] for r in (levels.Ranking.from_hypothesis(h) for h in bb.hypotheses(levels.RANKING))
    }
    assert best == {2: 2, 5: 5}


def test_a_missing_viewframe_is_an_error(small_rendered: dict) -> None:
    bb = MemoryBlackboard()
    bb.add(AssociativeIndexer("indexer-0"))
    for h in small_rendered["viewframes"][:-1]:
        _repost(bb, h)
    _repost(bb, small_rendered["map"])
    with pytest.raises(RuntimeError, match="viewframe 7 is on neither"):
        bb.run()


def test_bad_shard_options() -> None:
    with pytest.raises(ValueError, match="shard"):
        AssociativeIndexer("indexer", shard=2, shards=2)


def _track(frame: int, state: str, point: int, n: int) -> levels.Track:
    prior = np.zeros(n, np.float32)
    prior[point] = 1.0
    return levels.Track(
        frame=frame,
        route_point=point,
        arc_m=0.0,
        position=[0.0, 0.0],
        heading_deg=0.0,
        confidence=0.9 if state == "tracking" else 0.1,
        state=state,
        evidence=True,
        belief=prior,
        prior_next=prior,
        loglik=None,
        dt=None,
        window_next=[point, point],
    )


def test_while_tracking_the_ranking_holds_the_tracks_neighbourhood_and_when_lost_everything(
    small_rendered: dict,
) -> None:
    bb = MemoryBlackboard()
    indexer = AssociativeIndexer("indexer-0", tracked=True)
    bb.add(indexer)
    for h in small_rendered["viewframes"]:
        _repost(bb, h)
    n = len(small_rendered["viewframes"])
    body = dict(small_rendered["map"].body)
    body["memory"] = {**body["memory"], "window_route_points": n, "window_margin": 1, "window_full_every": 4}
    bb.post(levels.MAP, body, id=levels.map_id())
    bb.run()

    def ranking(frame: int) -> levels.Ranking | None:
        got = bb.user.get(levels.ranking_id(frame, 0))
        return None if got is None else levels.Ranking.from_hypothesis(got)

    full = {}
    _frames_from_viewframes(bb, small_rendered, [0])
    bb.run()
    assert ranking(0) is not None and set(ranking(0).viewframes) == set(range(n))  # frame 0: everything
    levels.post(bb.user, _track(0, "tracking", 2, n))  # frame 1 predicted at route point 2
    bb.run()
    _frames_from_viewframes(bb, small_rendered, [1])
    bb.run()
    got = ranking(1)
    assert got is not None and indexer.windows[1] == (1, 3)
    assert sorted(got.viewframes) == [1, 2, 3] and got.viewframes[0] == 1  # the frame is viewframe 1
    full[1] = indexer._index.rank(levels.Viewframe.from_hypothesis(small_rendered["viewframes"][1]).image)
    assert got.viewframes == [k for k in full[1].viewframes.tolist() if 1 <= k <= 3]  # the full order within it
    for frame, state in [(2, "lost"), (3, "tracking"), (4, "tracking")]:
        levels.post(bb.user, _track(frame - 1, state, frame, n))
        bb.run()
        _frames_from_viewframes(bb, small_rendered, [frame])
        bb.run()
    _frames_from_viewframes(bb, small_rendered, [6])  # the track of frame 5 never comes: no waiting
    bb.run()
    assert set(ranking(6).viewframes) == set(range(n)) and indexer.windows[6] is None
    assert set(ranking(2).viewframes) == set(range(n)) and indexer.windows[2] is None  # lost: everything
    assert sorted(ranking(3).viewframes) == [2, 3, 4] and indexer.windows[3] == (2, 4)
    assert set(ranking(4).viewframes) == set(range(n)) and indexer.windows[4] is None  # every 4th frame: everything


def test_an_untracked_indexer_never_waits_nor_windows(small_rendered: dict) -> None:
    bb = MemoryBlackboard()
    indexer = AssociativeIndexer("indexer-0")
    bb.add(indexer)
    for h in small_rendered["viewframes"]:
        _repost(bb, h)
    body = dict(small_rendered["map"].body)
    body["memory"] = {**body["memory"], "window_route_points": 1, "window_margin": 0}
    bb.post(levels.MAP, body, id=levels.map_id())
    _frames_from_viewframes(bb, small_rendered, [0, 3])
    levels.post(bb.user, _track(0, "tracking", 3, len(small_rendered["viewframes"])))
    bb.run()
    assert indexer.windows == {0: None, 3: None}


def test_consecutive_shards_outside_the_track_window_post_an_empty_ranking(small_rendered: dict) -> None:
    """Shards of consecutive route points (``block``): a windowed frame's ranking comes from the
    shards the window covers; the others post an empty ranking; together the full order within it."""
    bb = MemoryBlackboard()
    n = len(small_rendered["viewframes"])
    indexers = [AssociativeIndexer(f"indexer-{b}", shard=b, shards=3, block=3, tracked=True) for b in range(3)]
    for ix in indexers:
        bb.add(ix)
    for h in small_rendered["viewframes"]:
        _repost(bb, h)
    body = dict(small_rendered["map"].body)
    body["memory"] = {**body["memory"], "window_route_points": n, "window_margin": 0, "window_full_every": 10}
    bb.post(levels.MAP, body, id=levels.map_id())
    bb.run()
    stored = {i.shard: i.viewframes for i in (levels.Index.from_hypothesis(h) for h in bb.hypotheses(levels.INDEX))}
    assert stored == {0: 3, 1: 3, 2: 2}
    _frames_from_viewframes(bb, small_rendered, [0])
    bb.run()
    full = {b: levels.Ranking.from_hypothesis(bb.user.get(levels.ranking_id(0, b))) for b in range(3)}
    assert [sorted(full[b].viewframes) for b in range(3)] == [[0, 1, 2], [3, 4, 5], [6, 7]]
    levels.post(bb.user, _track(0, "tracking", 4, n))  # frame 1 predicted at route point 4 only
    bb.run()
    _frames_from_viewframes(bb, small_rendered, [1])
    bb.run()
    got = {b: levels.Ranking.from_hypothesis(bb.user.get(levels.ranking_id(1, b))) for b in range(3)}
    assert all(ix.windows[1] == (4, 4) for ix in indexers)
    assert got[0].viewframes == [] and got[2].viewframes == [] and got[1].viewframes == [4]


def test_bad_block_option() -> None:
    with pytest.raises(ValueError, match="block"):
        AssociativeIndexer("indexer", block=0)
