"""The associative indexer on an in-memory board: shards, waiting frames, late joining."""

from __future__ import annotations

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
