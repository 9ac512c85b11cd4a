"""The lifecycle every route ranker shares (:class:`knowledge_sources.ranker.RouteRanker`), for the
associative indexer and the skyline ranker alike, on an in-memory board: frames that wait for the
map, viewframes read back, the track window, tracks ignored when untracked."""

from __future__ import annotations

import pytest

from blackboard.memory_board import MemoryBlackboard
from knowledge_sources import levels
from knowledge_sources.indexer import AssociativeIndexer
from knowledge_sources.ranker import RouteRanker
from knowledge_sources.skyline import SKYLINE_SOURCE, SkylineRanker
from models.scenario import SkylineSpec
from tests.knowledge_sources.rankers import frames_from_viewframes, post_map, repost, track

KINDS = ["indexer", "skyline"]


def make(kind: str, *, tracked: bool = False) -> RouteRanker:
    if kind == "indexer":
        return AssociativeIndexer("indexer-0", tracked=tracked)
    return SkylineRanker("skyline", fov_y_deg=45.0, tracked=tracked, **SkylineSpec().match_options())


def ranking(bb: MemoryBlackboard, kind: str, frame: int) -> levels.Ranking | None:
    got = bb.user.get(levels.ranking_id(frame, 0, "associative" if kind == "indexer" else SKYLINE_SOURCE))
    return None if got is None else levels.Ranking.from_hypothesis(got)


@pytest.mark.parametrize("kind", KINDS)
def test_frames_before_the_map_wait_and_late_viewframes_are_read_back(small_rendered: dict, kind: str) -> None:
    bb = MemoryBlackboard()
    for h in small_rendered["viewframes"]:  # posted before the ranker joins: it reads them back
        repost(bb, h)
    ranker = make(kind)
    bb.add(ranker)
    frames_from_viewframes(bb, small_rendered, [2, 5])
    bb.run()
    assert bb.hypotheses(levels.RANKING) == [] and not ranker.built  # waiting for the map
    repost(bb, small_rendered["map"])
    bb.run()
    assert ranker.built
    got = {f: ranking(bb, kind, f) for f in (2, 5)}
    n = len(small_rendered["viewframes"])
    for f, r in got.items():
        assert r is not None and sorted(r.viewframes) == list(range(n)) and r.viewframes[0] == f
        assert r.variances == sorted(r.variances)


@pytest.mark.parametrize("kind", KINDS)
def test_an_untracked_ranker_ignores_tracks(small_rendered: dict, kind: str) -> None:
    bb = MemoryBlackboard()
    ranker = make(kind)
    bb.add(ranker)
    n = len(small_rendered["viewframes"])
    post_map(bb, small_rendered, window_route_points=1, window_margin=0)
    frames_from_viewframes(bb, small_rendered, [0])
    levels.post(bb.user, track(0, "tracking", 3, n))
    bb.run()
    frames_from_viewframes(bb, small_rendered, [1])
    bb.run()
    assert ranker.windows == {0: None, 1: None}
    assert sorted(ranking(bb, kind, 1).viewframes) == list(range(n))


@pytest.mark.parametrize("early", [False, True], ids=["track-after-map", "track-before-map"])
@pytest.mark.parametrize("kind", KINDS)
def test_while_tracking_the_ranking_holds_the_tracks_neighbourhood_and_when_lost_everything(
    small_rendered: dict, kind: str, early: bool
) -> None:
    bb = MemoryBlackboard()
    ranker = make(kind, tracked=True)
    bb.add(ranker)
    n = len(small_rendered["viewframes"])
    if early:  # the track of frame 0 comes before the map: kept for frame 1
        levels.post(bb.user, track(0, "tracking", 2, n))
        bb.run()
    post_map(bb, small_rendered, window_route_points=n, window_margin=1, window_full_every=4)
    bb.run()
    frames_from_viewframes(bb, small_rendered, [0])
    bb.run()
    assert sorted(ranking(bb, kind, 0).viewframes) == list(range(n))  # frame 0: everything
    if not early:
        levels.post(bb.user, track(0, "tracking", 2, n))  # frame 1 predicted at route point 2
        bb.run()
    frames_from_viewframes(bb, small_rendered, [1])
    bb.run()
    got = ranking(bb, kind, 1)
    assert ranker.windows[1] == (1, 3)
    assert sorted(got.viewframes) == [1, 2, 3] and got.viewframes[0] == 1  # the frame is viewframe 1
    full = MemoryBlackboard()  # the same frame ranked by an untracked ranker: the full order within the window
    full.add(make(kind))
    post_map(full, small_rendered)
    frames_from_viewframes(full, small_rendered, [1])
    full.run()
    assert got.viewframes == [k for k in ranking(full, kind, 1).viewframes if 1 <= k <= 3]
    for frame, state in [(2, "lost"), (3, "tracking"), (4, "tracking")]:
        levels.post(bb.user, track(frame - 1, state, frame, n))
        bb.run()
        frames_from_viewframes(bb, small_rendered, [frame])
        bb.run()
    frames_from_viewframes(bb, small_rendered, [6])  # the track of frame 5 never comes: no waiting
    bb.run()
    assert ranker.windows == {0: None, 1: (1, 3), 2: None, 3: (2, 4), 4: None, 6: None}
    assert set(ranking(bb, kind, 6).viewframes) == set(range(n))
    assert set(ranking(bb, kind, 2).viewframes) == set(range(n))  # lost: everything
    assert sorted(ranking(bb, kind, 3).viewframes) == [2, 3, 4]
    assert set(ranking(bb, kind, 4).viewframes) == set(range(n))  # every 4th frame: everything


def _ranked_frame_0(small_rendered: dict, kind: str) -> tuple[MemoryBlackboard, RouteRanker, int]:
    """A tracked ranker of ``kind`` on a board with the map (every route point windowed, margin 1,
    a full ranking every 4th frame) that has ranked frame 0: ``(board, ranker, viewframes)``."""
    bb = MemoryBlackboard()
    ranker = make(kind, tracked=True)
    bb.add(ranker)
    n = len(small_rendered["viewframes"])
    post_map(bb, small_rendered, window_route_points=n, window_margin=1, window_full_every=4)
    frames_from_viewframes(bb, small_rendered, [0])
    bb.run()
    return bb, ranker, n


@pytest.mark.parametrize("kind", KINDS)
def test_a_frame_that_comes_before_the_track_of_the_frame_before_reads_that_track_from_the_board(
    small_rendered: dict, kind: str
) -> None:
    """A camera paced on the track posts frame k once the track of frame k - 1 is posted, but the
    two reach a ranker by different subscriptions: when the frame comes first, the ranker reads the
    track from the blackboard and ranks the track's window, as if the track had come first (it
    ranked everything before); a track that is not on the board is not waited for."""
    bb, ranker, n = _ranked_frame_0(small_rendered, kind)
    plain = ranker.precondition
    # frames now rated above tracks: the frame's event is taken before the track's (the race)
    ranker.precondition = lambda e: 3.0 if e.hypothesis.level == levels.SENSOR_FRAME else plain(e)  # type: ignore[method-assign]
    levels.post(bb.user, track(0, "tracking", 2, n))
    frames_from_viewframes(bb, small_rendered, [1])
    bb.run()
    got = ranking(bb, kind, 1)
    assert ranker.windows[1] == (1, 3) and sorted(got.viewframes) == [1, 2, 3] and got.viewframes[0] == 1
    frames_from_viewframes(bb, small_rendered, [2])  # no track of frame 1 anywhere: everything, no waiting
    bb.run()
    assert ranker.windows[2] is None and set(ranking(bb, kind, 2).viewframes) == set(range(n))


@pytest.mark.parametrize("kind", KINDS)
def test_a_frame_after_a_lost_track_it_has_ranks_everything_without_reading_the_board(
    small_rendered: dict, kind: str, monkeypatch
) -> None:
    """The track of frame k - 1 came and says ``lost``: frame k is ranked in full, and the ranker
    does not read that track back from the blackboard (on a long route 21 rankers did so for each
    such frame, each read a query to the node)."""
    from blackboard.memory_board import MemoryBoard

    bb, ranker, n = _ranked_frame_0(small_rendered, kind)
    levels.post(bb.user, track(0, "lost", 2, n))
    bb.run()
    reads: list[tuple[str, str]] = []
    plain = MemoryBoard.get
    monkeypatch.setattr(MemoryBoard, "get", lambda self, i: reads.append((self.agent, i)) or plain(self, i))
    frames_from_viewframes(bb, small_rendered, [1])
    bb.run()
    assert ranker.windows[1] is None and set(ranking(bb, kind, 1).viewframes) == set(range(n))
    assert (ranker.name, levels.track_id(0)) not in reads
