from __future__ import annotations

import numpy as np
import pytest

from knowledge_sources.scene_analysis import Question, SceneAnalysis, ranking_weights

# viewframe -> visible landmarks, a small route
VISIBLE = {
    0: {"H1"},
    1: {"H1", "T1"},
    2: {"T1"},
    3: set(),
    4: {"H2"},
    5: {"H2", "H3"},
    6: set(),
    7: {"H3"},
}


def _ranking(best: int, *, sharp: bool = True, n: int = 8) -> list[tuple[int, float]]:
    """A ranking with ``best`` first; sharp: the best stands far from the rest."""
    others = [k for k in range(n) if k != best]
    gap = 0.5 if sharp else 0.002
    return [(best, 1.0)] + [(k, 1.0 + gap + 0.001 * i) for i, k in enumerate(others)]


def _run(sa: SceneAnalysis, truth: int, *, visible=VISIBLE, liar: set[str] = frozenset()):
    """Answer every question as a perfect detector would for camera position ``truth``."""
    asked = []
    while (q := sa.next_question()) is not None:
        asked.append(q)
        present = q.landmark in visible[truth]
        if q.landmark in liar:
            present = not present
        sa.answer(q, present)
    return sa.decision, asked


def test_weights_favour_low_variance():
    w = ranking_weights([3.0, 1.0, 2.0, 2.5])
    assert w[1] == pytest.approx(1.0)
    assert list(np.argsort(-w)) == [1, 2, 3, 0]


@pytest.mark.parametrize("bad", [[], [[1.0]]])
def test_weights_reject_bad_input(bad):
    with pytest.raises(ValueError, match="variances"):
        ranking_weights(bad)


@pytest.mark.parametrize("truth", sorted(VISIBLE))
@pytest.mark.parametrize("strategy", ["associative", "prior"])
def test_perfect_detectors_find_truth_when_ranked_first(truth, strategy):
    sa = SceneAnalysis(_ranking(truth), VISIBLE, strategy=strategy,
                       priors={"H1": 0.25, "T1": 0.25, "H2": 0.25, "H3": 0.25})
    decision, _ = _run(sa, truth)
    assert decision.viewframe == truth
    assert 0.0 < decision.confidence <= 1.0


def test_landmark_free_viewframe_decided_by_ranking_alone():
    sa = SceneAnalysis(_ranking(3), VISIBLE)
    decision, asked = _run(sa, 3)
    assert decision.viewframe == 3
    assert asked == []
    assert "ranking alone" in decision.reason


def test_absent_landmark_backtracks_to_next_candidate():
    # the ranking puts 1 first, but the camera is at 2: H1 is absent, so 0 and 1 are discarded
    ranking = [(1, 1.0), (2, 1.01), (0, 1.02)] + [(k, 2.0 + k) for k in (3, 4, 5, 6, 7)]
    sa = SceneAnalysis(ranking, VISIBLE, candidates=3)
    decision, asked = _run(sa, 2)
    assert decision.viewframe == 2
    assert decision.backtracks >= 1
    assert any(s["landmark"] == "H1" and s["present"] is False for s in decision.steps)


def test_most_probable_landmark_asked_first():
    sa = SceneAnalysis(_ranking(5, sharp=False), VISIBLE)
    probs = sa.landmark_probabilities()
    q = sa.next_question()
    assert q.landmark == max(probs, key=probs.get)
    assert q.probability == pytest.approx(probs[q.landmark])


def test_associative_asks_fewer_questions_than_prior():
    totals = {}
    for strategy in ("associative", "prior"):
        n = 0
        for truth in VISIBLE:
            sa = SceneAnalysis(_ranking(truth), VISIBLE, strategy=strategy,
                               priors={"H1": 0.25, "T1": 0.25, "H2": 0.25, "H3": 0.25})
            decision, _ = _run(sa, truth)
            n += decision.queries
        totals[strategy] = n
    assert totals["associative"] < totals["prior"]


def test_all_candidates_discarded_is_a_result_not_an_error():
    visible = {0: {"A"}, 1: {"A"}}
    sa = SceneAnalysis([(0, 1.0), (1, 1.1)], visible)
    decision, _ = _run(sa, 0, visible=visible, liar={"A"})
    assert decision.viewframe is None
    assert "discarded" in decision.reason


def test_unanswered_question_changes_nothing_and_moves_on():
    sa = SceneAnalysis(_ranking(1, sharp=False), VISIBLE, candidates=4)
    before = sa.posterior()
    q = sa.next_question()
    sa.answer(q, None)
    assert sa.posterior() == before
    q2 = sa.next_question()
    assert q2 is None or q2.landmark != q.landmark


def test_answer_must_match_pending_question():
    sa = SceneAnalysis(_ranking(1, sharp=False), VISIBLE)
    sa.next_question()
    with pytest.raises(ValueError, match="pending question"):
        sa.answer(Question("nope", 0, 0.5), True)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"strategy": "greedy"}, "strategy"),
        ({"candidates": 0}, "candidates"),
        ({"accept": 0.0}, "accept"),
        ({"reliability": 0.5}, "reliability"),
    ],
)
def test_invalid_parameters(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SceneAnalysis(_ranking(0), VISIBLE, **kwargs)


def test_every_question_counts_as_a_query_even_unanswered():
    sa = SceneAnalysis(_ranking(5, sharp=False), VISIBLE)
    q = sa.next_question()
    sa.answer(q, None)
    q = sa.next_question()
    sa.answer(q, True)
    while (q := sa.next_question()) is not None:
        sa.answer(q, q.landmark in VISIBLE[5])
    assert sa.decision.queries == len(sa.decision.steps) >= 2


def test_track_prior_conditions_candidates_and_questions():
    # a flat ranking that prefers viewframe 0; the track says the vehicle is at 5 (or 4)
    ranking = _ranking(0, sharp=False)
    prior = {k: 0.01 for k in range(8)}
    prior.update({4: 0.3, 5: 0.6})
    blind = SceneAnalysis(ranking, VISIBLE, candidates=3, accept=0.6, reliability=0.8)
    tracked = SceneAnalysis(ranking, VISIBLE, candidates=3, accept=0.6, reliability=0.8, track_prior=prior)
    assert 5 in tracked.posterior() and 5 not in blind.posterior()
    d_tracked, asked = _run(tracked, 5)
    assert d_tracked.viewframe == 5
    assert {q.landmark for q in asked} & {"H2", "H3"}  # questions about the tracked place
    d_blind, _ = _run(blind, 5)
    assert d_blind.viewframe != 5  # blind, the right place is not even a candidate


def test_no_track_prior_is_the_blind_rule():
    ranking = _ranking(2)
    a = SceneAnalysis(ranking, VISIBLE, candidates=4)
    b = SceneAnalysis(ranking, VISIBLE, candidates=4, track_prior=None)
    assert a.posterior() == b.posterior()
