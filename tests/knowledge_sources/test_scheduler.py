"""The scene-analysis scheduler on an in-memory board: merging shards, queries, answers, timeouts, positions.

The test plays the detectors: it answers the scheduler's queries by posting ``answer`` messages."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from blackboard.memory_board import MemoryBlackboard
from knowledge_sources import levels
from knowledge_sources.scheduler import Scheduler, detector_name

POSES = [
    [0.0, 0.0, 2.0, 0.0, 0.0],
    [10.0, 0.0, 2.0, 90.0, 0.0],
    [20.0, 5.0, 2.0, 180.0, 0.0],
    [30.0, 5.0, 2.0, 270.0, 0.0],
]
MAP = levels.Map.of(
    scenario="synthetic",
    path="/nonexistent/synthetic.yaml",
    priors={"H1": 0.75, "T1": 0.5},
    landmarks=[
        {"id": "H1", "kind": "house", "index": 0, "x": 5.0, "y": 5.0},
        {"id": "T1", "kind": "tower", "index": 1, "x": 25.0, "y": 10.0},
    ],
    route=[p[:2] for p in POSES],
    poses=POSES,
    visible={0: {"H1": 500}, 1: {"T1": 500}, 2: {"H1": 500, "T1": 30}, 3: {"H1": 400}},
    memory={},
)


def _rank(bb: MemoryBlackboard, frame: int, shards: dict[int, list[tuple[int, float]]]) -> None:
    for shard, entries in shards.items():
        levels.post(
            bb.user,
            levels.Ranking(
                frame=frame,
                frame_time=0.0,
                shard=shard,
                shards=len(shards),
                viewframes=[k for k, _ in entries],
                variances=[v for _, v in entries],
                reliability=3.0,
            ),
        )


def _answer(
    bb: MemoryBlackboard,
    query: levels.Query,
    query_id: str,
    present: bool | None,
    llr: float | None = None,
    where: list[float] | None = None,
) -> None:
    levels.post(
        bb.board("user"),
        levels.Answer(
            query=query_id,
            frame=query.frame,
            landmark=query.landmark,
            viewframe=query.viewframe,
            present=present,
            score=0.9 if present else 0.0,
            location=None,
            detector="test",
            reason="scripted",
            llr=llr,
            where=where,
        ),
        links=(query_id,),
    )


def _answer_each(bb: MemoryBlackboard, reply) -> set[str]:
    """Answer the scheduler's queries one at a time as they come (at most 10), each with
    ``reply(query) -> dict`` of :func:`_answer`'s arguments; returns the ids answered."""
    answered: set[str] = set()
    for _ in range(10):
        pending = [(qid, q) for qid, q in _queries(bb) if qid not in answered]
        if not pending:
            break
        ((qid, q),) = pending
        answered.add(qid)
        _answer(bb, q, qid, **reply(q))
        bb.run(timeouts=False)
    return answered


def _board(**options: object) -> MemoryBlackboard:
    bb = MemoryBlackboard()
    bb.add(Scheduler("scheduler", query_timeout_s=5.0, **options))  # type: ignore[arg-type]
    levels.post(bb.user, MAP)
    return bb


def _queries(bb: MemoryBlackboard) -> list[tuple[str, levels.Query]]:
    return [(h.id, levels.Query.from_hypothesis(h)) for h in bb.hypotheses(levels.QUERY)]


SHARDS = {0: [(2, 1e-5), (0, 8e-5)], 1: [(3, 6e-5), (1, 9e-5)]}


def test_waits_for_the_rankings_of_every_shard() -> None:
    bb = _board()
    levels.post(
        bb.user,
        levels.Ranking(
            frame=4, frame_time=0.0, shard=0, shards=2, viewframes=[2, 0], variances=[1e-5, 8e-5], reliability=3.0
        ),
    )
    bb.run()  # only shard 0 of 2 reported: nothing to decide on yet
    assert _queries(bb) == [] and bb.hypotheses(levels.POSITION) == []
    levels.post(
        bb.user,
        levels.Ranking(
            frame=4, frame_time=0.0, shard=1, shards=2, viewframes=[3, 1], variances=[6e-5, 9e-5], reliability=3.0
        ),
    )
    bb.run(timeouts=False)
    assert len(_queries(bb)) == 1


def test_a_confirmed_landmark_localizes_the_frame_at_the_viewframe_pose() -> None:
    bb = _board()
    _rank(bb, 4, SHARDS)
    bb.run(timeouts=False)
    ((qid, q),) = _queries(bb)
    h = bb.user.get(qid)
    assert h is not None and h.addressed_to == detector_name(q.kind) and h.deadline_s == 5.0
    assert qid == levels.query_id(4, 1) and q.frame == 4 and q.landmark == "H1" and q.landmark_index == 0
    assert set(h.links) == {levels.frame_id(4), levels.viewframe_id(q.viewframe)}
    _answer(bb, q, qid, True)
    bb.run()
    (ph,) = bb.hypotheses(levels.POSITION)
    p = levels.Position.from_hypothesis(ph)
    assert ph.id == levels.position_id(4)
    assert p.viewframe == 2 and p.position == POSES[2][:2] and p.heading_deg == POSES[2][3]
    assert p.queries == 1 and p.degraded == [] and p.strategy == "associative"
    assert p.ranking == [[2, 1e-5], [3, 6e-5], [0, 8e-5], [1, 9e-5]]
    assert levels.frame_id(4) in ph.links and levels.answer_id(qid) in ph.links


def test_an_absent_landmark_backtracks() -> None:
    bb = _board(backtracking="hard", questions="probability")  # the seed paper's rule
    _rank(bb, 1, SHARDS)
    bb.run(timeouts=False)
    # H1 is absent: every candidate showing it goes
    answered = _answer_each(bb, lambda q: {"present": q.landmark != "H1"})
    p = levels.Position.from_hypothesis(bb.hypotheses(levels.POSITION)[0])
    assert p.backtracks >= 1 and p.viewframe not in (0, 2, 3)
    assert [q.number for _, q in _queries(bb)] == list(range(1, len(answered) + 1))


def test_soft_backtracking_takes_the_answers_likelihood_ratio() -> None:
    """The default rule: the answers' ratios decide between close candidates even when the
    detector's own three-way answer is undecided (which the seed rule takes as no evidence); such
    an answer is evidence, not a degraded query."""
    close = {0: [(2, 1.0e-5), (0, 1.2e-5)], 1: [(1, 1.05e-5), (3, 1.1e-5)]}  # near-equal weights
    results = {}
    for llr in (-3.0, 3.0):
        bb = _board()
        _rank(bb, 1, close)
        bb.run(timeouts=False)
        # the detector itself undecided
        _answer_each(bb, lambda q, llr=llr: {"present": None, "llr": llr if q.viewframe == 2 else -llr})
        (ph,) = bb.hypotheses(levels.POSITION)
        results[llr] = levels.Position.from_hypothesis(ph)
    # H1 (seen by 0, 2, 3) there and T1 (seen by 1) not: 2, the best of them; the other way: 1
    assert results[3.0].viewframe == 2 and results[-3.0].viewframe == 1
    assert all(p.degraded == [] for p in results.values())
    assert [s["llr"] for s in results[-3.0].steps] == [-3.0, 3.0]


def test_an_unanswered_query_times_out_and_the_position_says_degraded() -> None:
    bb = _board()
    _rank(bb, 0, SHARDS)
    bb.run()  # nobody answers: the board times the query out when nothing else is left
    (ph,) = bb.hypotheses(levels.POSITION)
    p = levels.Position.from_hypothesis(ph)
    assert p.degraded and "detector-house" in p.degraded[0] and "degraded" in p.reason
    assert p.queries >= 1


def test_an_undecided_answer_is_no_evidence() -> None:
    bb = _board()
    _rank(bb, 0, SHARDS)
    bb.run(timeouts=False)
    ((qid, q),) = _queries(bb)
    _answer(bb, q, qid, None)
    bb.run()
    p = levels.Position.from_hypothesis(bb.hypotheses(levels.POSITION)[0])
    assert any("undecided" in d for d in p.degraded)


def test_a_late_answer_is_ignored() -> None:
    bb = _board()
    _rank(bb, 0, SHARDS)
    bb.run()
    (qid, q), *_ = _queries(bb)
    positions = len(bb.hypotheses(levels.POSITION))
    _answer(bb, q, qid, True)  # after its timeout: the frame is decided already
    bb.run()
    assert positions == 1 and len(bb.hypotheses(levels.POSITION)) == 1


def test_the_prior_strategy_asks_in_prior_order() -> None:
    bb = _board(strategy="prior")
    _rank(bb, 0, SHARDS)
    bb.run(timeouts=False)
    first = _queries(bb)[0][1]
    assert first.landmark == "H1"  # the larger prior
    bb.run()
    assert levels.Position.from_hypothesis(bb.hypotheses(levels.POSITION)[0]).strategy == "prior"


def test_unknown_strategy() -> None:
    with pytest.raises(ValueError, match="strategy"):
        Scheduler("scheduler", strategy="guess")


def _track(bb: MemoryBlackboard, frame: int, state: str, prior_next: list[float]) -> None:
    import numpy as np

    levels.post(
        bb.board("user"),
        levels.Track(
            frame=frame,
            route_point=1,
            arc_m=10.0,
            position=[10.0, 0.0],
            heading_deg=0.0,
            confidence=0.9,
            state=state,
            evidence=True,
            belief=np.asarray(prior_next, np.float32),
            prior_next=np.asarray(prior_next, np.float32),
            loglik=None,
            dt=None,
        ),
    )


def test_tracked_frames_wait_for_the_previous_track_and_are_conditioned_on_it() -> None:
    bb = _board(tracked=True, candidates=1)
    _rank(bb, 1, {0: [(2, 1e-5), (1, 2e-5), (0, 8e-5), (3, 9e-5)]})  # blind, the one candidate would be 2
    bb.run(timeouts=False)
    assert _queries(bb) == []  # frame 1 waits for the track of frame 0
    _track(bb, 0, "tracking", [0.01, 0.97, 0.01, 0.01])  # the track says: next at route point 1
    bb.run(timeouts=False)
    ((qid, q),) = _queries(bb)
    assert q.viewframe == 1 and q.landmark == "T1"  # the one candidate is the tracked place, not the ranking's best
    _answer(bb, q, qid, True)
    bb.run()
    p = levels.Position.from_hypothesis(bb.hypotheses(levels.POSITION)[0])
    assert p.viewframe == 1 and p.track_prior


def test_a_lost_track_releases_the_frame_blind() -> None:
    bb = _board(tracked=True, candidates=1)
    _track(bb, 0, "lost", [0.01, 0.97, 0.01, 0.01])
    _rank(bb, 1, {0: [(2, 1e-5), (1, 2e-5), (0, 8e-5), (3, 9e-5)]})
    bb.run(timeouts=False)
    ((_, q),) = _queries(bb)
    assert q.viewframe == 2  # the ranking's best: the lost track's prior is not used


def test_without_the_track_of_the_frame_before_the_next_frame_is_analysed_blind() -> None:
    bb = _board(tracked=True, candidates=1, track_timeout_s=2.5)  # no tracker on the board: its track queries time out
    _rank(bb, 0, {0: [(2, 1e-5), (1, 2e-5), (0, 8e-5), (3, 9e-5)]})
    _rank(bb, 1, {0: [(2, 1e-5), (1, 2e-5), (0, 8e-5), (3, 9e-5)]})
    bb.run(timeouts=False)
    ((qid, q),) = _queries(bb)  # frame 0 (nothing before it) is analysed; frame 1 waits for track 0
    assert q.frame == 0
    _answer(bb, q, qid, True)
    bb.run(timeouts=False)
    # with its position, frame 0's track query: addressed to the tracker, with the scheduler's deadline
    (tq,) = bb.hypotheses(levels.TRACK_QUERY)
    assert tq.addressed_to == "tracker" and tq.deadline_s == 2.5
    assert levels.TrackQuery.from_hypothesis(tq) == levels.TrackQuery(frame=0, position=levels.position_id(0))
    assert [levels.Query.from_hypothesis(h).frame for h in bb.hypotheses(levels.QUERY)] == [0]  # frame 1 waits
    bb.run()  # nobody answers: the track query times out, frame 1 goes blind (its own query times out too)
    p1 = levels.Position.from_hypothesis(bb.user.get(levels.position_id(1)))
    assert not p1.track_prior and p1.viewframe == 2  # the blind ranking's best
    assert any(d.startswith("tracker: no track of frame 0") for d in p1.degraded) and "tracker" in p1.reason
    # a track of frame 0 arriving now is not used (frame 1 is decided), and nothing breaks
    _track(bb, 0, "tracking", [0.01, 0.97, 0.01, 0.01])
    bb.run()
    assert len(bb.hypotheses(levels.POSITION)) == 2


def test_a_track_answers_the_track_query() -> None:
    bb = _board(tracked=True, candidates=1)
    _rank(bb, 0, {0: [(2, 1e-5), (1, 2e-5), (0, 8e-5), (3, 9e-5)]})
    bb.run(timeouts=False)
    ((qid, q),) = _queries(bb)
    _answer(bb, q, qid, True)
    bb.run(timeouts=False)
    levels.post(
        bb.board("user"),
        levels.Track(
            frame=0,
            route_point=1,
            arc_m=10.0,
            position=[10.0, 0.0],
            heading_deg=0.0,
            confidence=0.9,
            state="tracking",
            evidence=True,
            belief=np.asarray([0.01, 0.97, 0.01, 0.01], np.float32),
            prior_next=np.asarray([0.01, 0.97, 0.01, 0.01], np.float32),
            loglik=None,
            dt=None,
        ),
        links=(levels.track_query_id(0),),
    )
    _rank(bb, 1, {0: [(2, 1e-5), (1, 2e-5), (0, 8e-5), (3, 9e-5)]})
    bb.run()  # the query was answered: no timeout, frame 1 conditioned on the track
    p1 = levels.Position.from_hypothesis(bb.user.get(levels.position_id(1)))
    assert p1.track_prior and not any(d.startswith("tracker") for d in p1.degraded)


# viewframes 0, 2 and 3 show H1: from 0 (the right one here) larger and further right than from 2
PLACED = dataclasses.replace(
    MAP,
    placements=np.array([[1.0, 6.0, 4.2], [5.0, 0.0, 3.0], [1.0, 2.0, 3.0], [9.0, 9.0, 9.0], [0.5, -9.0, 2.5]]),
)  # a row per visible row: 0 H1, 1 T1, 2 H1, 2 T1, 3 H1


@pytest.mark.parametrize("position, decided", [(True, 0), (False, 2)])
def test_the_place_of_a_found_landmark_decides_between_candidates_that_show_it(position: bool, decided: int) -> None:
    """The ranking prefers 2 a little; the detector (the test) finds H1 present where 0 shows it,
    the camera turned by 1 degree against every viewframe (the ranking's shifts, as the skyline
    posts them). With the position evidence the scheduler decides 0, without it 2."""
    bb = MemoryBlackboard()
    bb.add(Scheduler("scheduler", query_timeout_s=5.0, position_evidence=position))
    levels.post(bb.user, PLACED)
    entries = [(2, 1.0e-5), (0, 1.05e-5), (3, 1.1e-5), (1, 1.2e-5)]
    levels.post(
        bb.user,
        levels.Ranking(
            frame=1,
            frame_time=0.0,
            shard=0,
            shards=1,
            viewframes=[k for k, _ in entries],
            variances=[v for _, v in entries],
            reliability=3.0,
            shifts=[[1.0, 0.0]] * len(entries),
        ),
    )
    bb.run(timeouts=False)
    found = {"present": True, "llr": 2.0, "where": [1.1, 7.1, 4.0]}  # where: 0's place, turned by 1 degree
    _answer_each(bb, lambda q: found if q.landmark == "H1" else {"present": False, "llr": -2.0})
    (ph,) = bb.hypotheses(levels.POSITION)
    p = levels.Position.from_hypothesis(ph)
    assert p.viewframe == decided, p.steps
    h1 = next(s for s in p.steps if s["landmark"] == "H1")
    assert ("position" in h1) is position
    if position:
        assert h1["position"]["0"] == 0.0 and h1["position"]["2"] < -1.0


def test_an_uncertain_ranking_is_verified_and_re_ranked_before_the_analysis() -> None:
    bb = _board(verify_candidates=2, verify_margin=1.0, verify_weight=2.8)
    _rank(bb, 0, SHARDS)
    bb.run(timeouts=False)
    assert not bb.hypotheses(levels.POSITION) and not _queries(bb)  # waiting for the verifier
    (vh,) = bb.hypotheses(levels.VERIFY_QUERY)
    vq = levels.VerifyQuery.from_hypothesis(vh)
    assert vh.addressed_to == "verifier" and vq.viewframes == [2, 3]  # the fused ranking's first two
    levels.post(
        bb.user,
        levels.Verification(
            frame=0, query=vh.id, viewframes=[2, 3], correlations=[0.3, 0.6], headings_deg=[0.0, 0.0], renders=2
        ),
        links=(vh.id,),
    )
    bb.run()  # the detectors' questions go unanswered and time out
    (ph,) = bb.hypotheses(levels.POSITION)
    p = levels.Position.from_hypothesis(ph)
    # the better match first; the other 2.8 * 0.3 behind, after the viewframes not verified
    assert [k for k, _ in p.ranking] == [3, 0, 1, 2]
    assert p.ranking[3][1] == pytest.approx(1e-5 + 2.8 * 0.3)
    assert "verified 2 candidates" in p.reason and "(first viewframe 2 -> 3)" in p.reason
    assert levels.verification_id(0) in ph.links


def test_a_missing_verification_leaves_the_ranking_and_says_degraded() -> None:
    bb = _board(verify_candidates=2, verify_margin=1.0, verify_timeout_s=2.0)  # no verifier on the board
    _rank(bb, 0, SHARDS)
    bb.run()
    (ph,) = bb.hypotheses(levels.POSITION)
    p = levels.Position.from_hypothesis(ph)
    assert [k for k, _ in p.ranking[:2]] == [2, 3]
    assert any("verifier: no verification" in d for d in p.degraded)


def test_a_certain_ranking_is_not_verified() -> None:
    bb = _board(verify_candidates=2, verify_margin=1e-6)  # the second is 5e-5 behind: beyond the margin
    _rank(bb, 0, SHARDS)
    bb.run()
    assert not bb.hypotheses(levels.VERIFY_QUERY) and len(bb.hypotheses(levels.POSITION)) == 1
    with pytest.raises(ValueError, match="verify_candidates"):
        Scheduler("scheduler", verify_candidates=1)


@pytest.mark.parametrize("a", [0.0, 0.3])
def test_the_neighbours_visibility_reaches_the_scene_analysis(a: float) -> None:
    """Viewframe 1 does not show H1, its neighbours 0 and 2 do: with ``neighbour_visibility`` the
    answer "H1 present" also lifts 1 (the step says so), without it only the viewframes showing H1."""
    bb = MemoryBlackboard()
    bb.add(Scheduler("scheduler", query_timeout_s=5.0, neighbour_visibility=a))
    levels.post(bb.user, MAP)
    _rank(bb, 0, {0: [(1, 1.0e-5), (2, 1.05e-5), (0, 1.1e-5), (3, 1.2e-5)]})
    bb.run(timeouts=False)
    _answer_each(bb, lambda q: {"present": True, "llr": 2.0} if q.landmark == "H1" else {"present": False, "llr": -2.0})
    (ph,) = bb.hypotheses(levels.POSITION)
    steps = levels.Position.from_hypothesis(ph).steps
    h1 = next(s for s in steps if s["landmark"] == "H1")
    assert ("near" in h1["effect"]) is (a > 0), h1
