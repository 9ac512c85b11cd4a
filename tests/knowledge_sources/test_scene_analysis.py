from __future__ import annotations

import numpy as np
import pytest

from knowledge_sources.scene_analysis import Question, SceneAnalysis, information_gain, ranking_weights

from . import seed_scene_analysis as seed

#: the seed paper's rule (the first version's)
HARD = {"backtracking": "hard", "questions": "probability"}

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
    sa = SceneAnalysis(
        _ranking(truth), VISIBLE, strategy=strategy, priors={"H1": 0.25, "T1": 0.25, "H2": 0.25, "H3": 0.25}
    )
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
    sa = SceneAnalysis(ranking, VISIBLE, candidates=3, **HARD)
    decision, asked = _run(sa, 2)
    assert decision.viewframe == 2
    assert decision.backtracks >= 1
    assert any(s["landmark"] == "H1" and s["present"] is False for s in decision.steps)


def test_most_probable_landmark_asked_first():
    sa = SceneAnalysis(_ranking(5, sharp=False), VISIBLE, questions="probability")
    probs = sa.landmark_probabilities()
    q = sa.next_question()
    assert q.landmark == max(probs, key=probs.get)
    assert q.probability == pytest.approx(probs[q.landmark])


def test_associative_asks_fewer_questions_than_prior():
    totals = {}
    for strategy in ("associative", "prior"):
        n = 0
        for truth in VISIBLE:
            sa = SceneAnalysis(
                _ranking(truth), VISIBLE, strategy=strategy, priors={"H1": 0.25, "T1": 0.25, "H2": 0.25, "H3": 0.25}
            )
            decision, _ = _run(sa, truth)
            n += decision.queries
        totals[strategy] = n
    assert totals["associative"] < totals["prior"]


def test_all_candidates_discarded_is_a_result_not_an_error():
    visible = {0: {"A"}, 1: {"A"}}
    sa = SceneAnalysis([(0, 1.0), (1, 1.1)], visible, **HARD)
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
        ({"backtracking": "firm"}, "backtracking"),
        ({"questions": "random"}, "questions"),
        ({"floor": 1.0}, "floor"),
        ({"max_llr": 0.0}, "max_llr"),
        ({"neighbour_visibility": -0.1}, "neighbour_visibility"),
        ({"neighbour_visibility": 0.6}, "neighbour_visibility"),
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


# -- hard backtracking is the seed paper's rule, exactly ------------------------------------------


def _random_case(rng: np.random.Generator) -> tuple[list[tuple[int, float]], dict[int, set[str]], dict]:
    n = int(rng.integers(2, 14))
    names = [f"L{i}" for i in range(int(rng.integers(1, 7)))]
    visible = {k: {lm for lm in names if rng.random() < 0.35} for k in range(n)}
    variances = rng.normal(1.0, 0.05, n)
    if rng.random() < 0.3:
        variances[: n // 2] = 1.0  # ties
    order = np.argsort(variances, kind="stable")
    ranking = [(int(k), float(variances[k])) for k in order]
    options = {
        "strategy": str(rng.choice(["associative", "prior"])),
        "candidates": int(rng.integers(1, 9)),
        "accept": float(rng.choice([0.5, 0.6, 0.75, 0.9, 1.0])),
        "reliability": float(rng.uniform(0.55, 0.95)),
        "beta": float(rng.uniform(0.5, 5.0)),
        "priors": {lm: float(rng.random()) for lm in names},
    }
    return ranking, visible, options


def _drive(sa, rng: np.random.Generator, truth: int, visible, lie: float) -> tuple:
    """Answer as a detector that lies with probability ``lie`` and sometimes cannot tell."""
    asked = []
    while (q := sa.next_question()) is not None:
        u = rng.random()
        present = None if u < 0.1 else ((q.landmark in visible[truth]) != (u < 0.1 + lie))
        asked.append((q.landmark, q.viewframe, q.probability, present))
        sa.answer(q, present)
    d = sa.decision
    return d.viewframe, d.confidence, d.queries, d.backtracks, d.reason, d.steps, asked


def test_hard_backtracking_equals_the_seed_rule_exactly():
    """600 random cases (rankings with ties, both strategies, random options, lying and undecided
    detectors): every question, answer effect and decision is the first version's."""
    rng = np.random.default_rng(11)
    differing_from_soft = 0
    for case in range(600):
        ranking, visible, options = _random_case(rng)
        truth = int(rng.integers(0, len(ranking)))
        lie = float(rng.choice([0.0, 0.2, 0.5]))
        answers_seed = np.random.default_rng(case)
        answers_new = np.random.default_rng(case)
        want = _drive(seed.SceneAnalysis(ranking, visible, **options), answers_seed, truth, visible, lie)
        got = _drive(SceneAnalysis(ranking, visible, **options, **HARD), answers_new, truth, visible, lie)
        assert got == want, (case, options)
        soft = _drive(SceneAnalysis(ranking, visible, **options), np.random.default_rng(case), truth, visible, lie)
        differing_from_soft += soft[:4] != want[:4]
    assert differing_from_soft > 30  # the comparison can fail: soft is another rule


# -- soft backtracking ---------------------------------------------------------------------------

SOFT_VISIBLE = {0: {"A", "B"}, 1: {"C"}, 2: {"A"}, 3: {"D"}}


def test_one_wrong_absent_does_not_discard_the_right_viewframe():
    ranking = [(0, 1.0), (1, 1.004), (2, 1.01), (3, 1.05)]
    hard = SceneAnalysis(ranking, SOFT_VISIBLE, **HARD)
    q = hard.next_question()
    assert q.landmark == "A"
    hard.answer(q, False)  # the detector wrongly says A is absent: the truth is 0
    assert 0 not in hard.posterior()  # the seed rule loses the right viewframe for good

    soft = SceneAnalysis(ranking, SOFT_VISIBLE, questions="probability")
    q = soft.next_question()
    soft.answer(q, False, llr=-2.5)
    assert 0 in soft.posterior()
    # B (only in 0) is then found present, strongly: 0 comes back and is accepted
    while (q := soft.next_question()) is not None:
        truth_says = q.landmark in SOFT_VISIBLE[0]
        soft.answer(q, truth_says, llr=3.0 if truth_says else -3.0)
    assert soft.decision.viewframe == 0


def test_consistent_evidence_discards_a_candidate():
    # the ranking prefers 0 (landmarks A, B, E); the camera is at 1 (no landmark)
    ranking = [(0, 1.0), (1, 1.0), (2, 1.3), (3, 1.3)]
    visible = {0: {"A", "B", "E"}, 1: set(), 2: set(), 3: set()}
    sa = SceneAnalysis(ranking, visible, questions="probability", floor=1e-3, max_llr=3.0, accept=1.0)
    kept = []
    while (q := sa.next_question()) is not None:
        sa.answer(q, False, llr=-3.0)
        kept.append(0 in sa.posterior())
    assert kept[0] is True  # one answer against it: lowered, kept
    assert kept[-1] is False  # consistent answers against it: discarded
    assert sa.decision.viewframe == 1
    assert sa.decision.backtracks == 1


def test_soft_answers_move_the_posterior_by_the_likelihood_ratio():
    ranking = [(0, 1.0), (1, 1.0), (2, 1.0), (3, 1.0)]  # uniform weights
    sa = SceneAnalysis(ranking, SOFT_VISIBLE, questions="probability", max_llr=10.0, floor=0.0)
    prior = sa.posterior()
    q = sa.next_question()
    assert q.landmark == "A"  # in 0 and 2
    sa.answer(q, True, llr=1.5)
    post = sa.posterior()
    odds = (post[0] / post[1]) / (prior[0] / prior[1])
    assert odds == pytest.approx(np.exp(1.5))
    assert post[2] / post[0] == pytest.approx(prior[2] / prior[0])  # both hold A


def test_soft_llr_is_clipped_and_never_discards_the_best():
    ranking = [(0, 1.0), (1, 1.0)]
    visible = {0: {"A"}, 1: set()}
    sa = SceneAnalysis(ranking, visible, max_llr=2.0, floor=0.05, questions="probability")
    q = sa.next_question()
    sa.answer(q, False, llr=-50.0)
    post = sa.posterior()
    assert post[0] / post[1] == pytest.approx(np.exp(-2.0))
    sa2 = SceneAnalysis([(0, 1.0)], {0: {"A"}}, floor=0.5, questions="probability")
    q = sa2.next_question()
    sa2.answer(q, False, llr=-50.0)
    assert list(sa2.posterior()) == [0]  # the only candidate is kept: the best is never discarded


# -- visibility near a viewframe ----------------------------------------------------------------

# a route of five viewframes: landmark L comes into view at viewframe 2, M is seen from 1 only
ROUTE_VISIBLE = {0: set(), 1: {"M"}, 2: {"L"}, 3: {"L"}, 4: {"L"}}


@pytest.mark.parametrize("a", [0.1, 0.25, 0.5])
def test_visibility_is_the_visible_sets_blurred_along_the_route(a):
    sa = SceneAnalysis(_ranking(1, n=5), ROUTE_VISIBLE, neighbour_visibility=a)
    assert [sa.visibility(k, "L") for k in range(5)] == pytest.approx([0.0, a, 1 - a, 1.0, 1.0])  # 4: its end
    assert [sa.visibility(k, "M") for k in range(5)] == pytest.approx([a, 1 - 2 * a, a, 0.0, 0.0])
    # without the blur, or under the hard rule, the visible sets exactly
    for kwargs in ({"neighbour_visibility": 0.0}, {"neighbour_visibility": a, **HARD}):
        sharp = SceneAnalysis(_ranking(1, n=5), ROUTE_VISIBLE, **kwargs)
        assert [sharp.visibility(k, "L") for k in range(5)] == [0.0, 0.0, 1.0, 1.0, 1.0]


@pytest.mark.parametrize("llr", [2.5, -2.5])
def test_an_answer_moves_each_candidate_by_its_visibility(llr):
    a = 0.25
    ranking = [(k, 1.0) for k in range(5)]  # uniform weights
    sa = SceneAnalysis(ranking, ROUTE_VISIBLE, neighbour_visibility=a, max_llr=10.0, floor=0.0)
    prior = sa.posterior()
    sa._pending = q = Question("L", 2, 0.5)
    sa.answer(q, llr > 0, llr=llr)
    post = sa.posterior()
    for k in range(5):
        v = sa.visibility(k, "L")
        want = v * np.exp(llr) + 1 - v  # the likelihood ratio against viewframe 0 (v = 0)
        assert (post[k] / post[0]) / (prior[k] / prior[0]) == pytest.approx(want)


def test_probability_of_a_landmark_counts_the_neighbours_share():
    a = 0.25
    ranking = [(k, 1.0) for k in range(5)]
    sa = SceneAnalysis(ranking, ROUTE_VISIBLE, neighbour_visibility=a)
    probs = sa.landmark_probabilities()
    assert probs["L"] == pytest.approx((a + (1 - a) + 1 + 1) / 5)
    assert probs["M"] == pytest.approx((a + (1 - 2 * a) + a) / 5)
    sharp = SceneAnalysis(ranking, ROUTE_VISIBLE, neighbour_visibility=0.0).landmark_probabilities()
    assert sharp["L"] == pytest.approx(3 / 5) and sharp["M"] == pytest.approx(1 / 5)


def test_a_landmark_coming_into_view_next_does_not_move_the_answer_to_the_neighbour():
    # the camera frame near viewframe 1 (ranked first) already sees L, which viewframe 1 does not
    # show and viewframes 2-4 do: with the visible sets exactly, "L present" moves the answer to 2;
    # with the neighbours' share, viewframe 1 keeps it
    visible = {0: set(), 1: set(), 2: {"L"}, 3: {"L"}, 4: {"L"}}
    ranking = [(1, 1.0), (2, 1.2), (0, 1.5), (3, 1.6), (4, 1.7)]  # weights of 1 and 2 about 7.6 : 1

    def decide(a):
        sa = SceneAnalysis(ranking, visible, neighbour_visibility=a, questions="probability", accept=0.95)
        while (q := sa.next_question()) is not None:
            sa.answer(q, True, llr=3.0)
        return sa.decision.viewframe

    assert decide(0.0) == 2
    assert decide(0.3) == 1


# -- question choice -----------------------------------------------------------------------------


def test_information_gain_is_largest_for_an_even_split():
    gains = [information_gain(p, reliability=0.8) for p in (0.05, 0.3, 0.5, 0.7, 0.99)]
    assert max(gains) == gains[2]
    assert information_gain(1.0, reliability=0.8) == pytest.approx(0.0)
    assert information_gain(0.5, reliability=0.99) > information_gain(0.5, reliability=0.7)


def test_information_gain_picks_the_discriminating_landmark():
    # two leading candidates 0 and 1; "S" is seen by both (and a far one), "D" only by 1:
    # P(S|A) is highest, but only D tells 0 from 1
    ranking = [(0, 1.0), (1, 1.001), (2, 1.2), (3, 1.3)]
    visible = {0: {"S"}, 1: {"S", "D"}, 2: {"E"}, 3: set()}
    by_p = SceneAnalysis(ranking, visible, questions="probability").next_question()
    by_ig = SceneAnalysis(ranking, visible, questions="information").next_question()
    assert by_p.landmark == "S"
    assert by_ig.landmark == "D"


@pytest.mark.parametrize("strategy", ["associative", "prior"])
def test_a_track_prior_per_route_point_is_the_same_prior_as_a_mapping(strategy):
    """The scheduler passes the track's prediction as an array over route points: the candidates,
    their weights and the first question are those of the same prior as a mapping."""
    import numpy as np

    rng = np.random.default_rng(5)
    n = 400
    ranking = sorted(
        ((int(k), float(v)) for k, v in zip(rng.permutation(n), rng.gamma(2.0, 1.0, n))), key=lambda t: t[1]
    )
    prior = rng.dirichlet(np.full(n, 0.3)).astype(np.float32)
    prior[:50] = 0.0
    visible = {k: frozenset({f"L{k % 7}"}) for k in range(n)}
    a = SceneAnalysis(ranking, visible, strategy=strategy, track_prior={k: float(p) for k, p in enumerate(prior)})
    b = SceneAnalysis(ranking, visible, strategy=strategy, track_prior=np.asarray(prior, dtype=np.float64)[: n - 10])
    c = SceneAnalysis(
        ranking, visible, strategy=strategy, track_prior={k: float(p) for k, p in enumerate(prior[: n - 10])}
    )
    assert b._weights == c._weights and list(b._weights) == list(c._weights)  # a prior shorter than the route
    b = SceneAnalysis(ranking, visible, strategy=strategy, track_prior=np.asarray(prior, dtype=np.float64))
    assert b._weights == a._weights and list(b._weights) == list(a._weights)
    assert b.next_question() == a.next_question()


# -- position evidence ---------------------------------------------------------------------------

# two neighbouring route points that show the same landmark L (and one that does not): from the
# nearer one (1) L looks larger and further to the right, as a whole route spacing would make it
PLACEMENTS = {0: {"L": (1.0, 2.0, 3.0)}, 1: {"L": (1.2, 6.0, 4.2)}, 2: {}}
SAME_L = {0: {"L"}, 1: {"L"}, 2: set()}
NO_TURN = {0: (0.0, 0.0), 1: (0.0, 0.0), 2: (0.0, 0.0)}


def _position(**kw) -> SceneAnalysis:
    opts = {
        "placements": PLACEMENTS,
        "turns": NO_TURN,
        "position_evidence": True,
        "position_spread": (1.6, 1.6, 0.21),
        "max_position_llr": 3.0,
    }
    return SceneAnalysis([(0, 1.0), (1, 1.1), (2, 5.0)], SAME_L, **{**opts, **kw})


@pytest.mark.parametrize(
    "where, better, worse",
    [
        ((1.0, 2.0, 3.0), 0, 1),  # exactly where 0 shows it
        ((1.1, 5.5, 4.0), 1, 0),  # near where 1 shows it
        ((1.0, 2.5, 3.2), 0, 1),  # near 0, a little off
    ],
)
def test_the_candidate_whose_place_matches_beats_the_one_a_route_spacing_away(where, better, worse):
    moved = _position().position_llr("L", where, [0, 1, 2])
    assert set(moved) == {0, 1}  # 2 does not show L: no position evidence for it
    assert moved[better] == 0.0 and -3.0 <= moved[worse] < -0.5, moved


def test_the_position_evidence_is_capped():
    far = (10.0, -30.0, 0.5)  # a wrong match, far from both predictions
    moved = _position(max_position_llr=2.0).position_llr("L", far, [0, 1])
    assert min(moved.values()) >= -2.0 and max(moved.values()) == 0.0
    assert _position(max_position_llr=2.0).position_llr("L", (1.0, 2.0, 3.0), [0, 1])[1] == -2.0


def test_the_turn_against_each_viewframe_carries_its_prediction_into_the_camera_frame():
    where = (1.0, 6.0, (3.0 * 4.2) ** 0.5)  # azimuth of 1's place, size half way in log between both
    # the camera turned 4 degrees ccw from viewframe 0: 0 predicts L at azimuth 6, not 2
    turned = _position(turns={0: (4.0, 0.0), 1: (0.0, 0.0)}).position_llr("L", where, [0, 1])
    still = _position().position_llr("L", where, [0, 1])
    assert still[0] < -1.0 and still[1] == 0.0
    assert turned[0] > still[0]
    # without the turns only the sizes are compared, and those fit both alike
    sizes = _position(turns=None).position_llr("L", where, [0, 1])
    assert sizes[0] == pytest.approx(sizes[1])


@pytest.mark.parametrize("position, decided", [(True, 1), (False, 0)])
def test_the_soft_rule_with_position_picks_the_right_of_two_candidates_showing_the_same_landmark(position, decided):
    """The ranking prefers 0; the detector finds L present where 1 shows it. Presence alone cannot
    tell 0 from 1 (both show L): the ranking's first stays; with the position evidence, 1."""
    sa = _position(position_evidence=position)
    q = sa.next_question()
    assert q is not None and q.landmark == "L" and q.viewframe == 0
    sa.answer(q, True, llr=2.0, where=(1.2, 6.3, 4.1))
    assert sa.next_question() is None
    assert sa.decision.viewframe == decided
    assert ("position" in sa.decision.steps[0]) is position


def test_a_negative_answer_gives_no_position_evidence():
    sa = _position()
    q = sa.next_question()
    sa.answer(q, None, llr=-1.0, where=(1.2, 6.0, 4.2))
    while (q := sa.next_question()) is not None:
        sa.answer(q, None)
    assert sa.decision is not None and "position" not in sa.decision.steps[0]


def test_the_hard_rule_ignores_where():
    """The seed paper's rule takes present/absent only: the place changes nothing."""
    results = []
    for where in (None, (1.2, 6.0, 4.2), (1.0, 2.0, 3.0)):
        sa = _position(**HARD)
        while (q := sa.next_question()) is not None:
            sa.answer(q, True, llr=2.0, where=where)
        results.append(sa.decision)
    assert results[0] == results[1] == results[2]


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"position_spread": (1.0, 0.0, 1.0)}, "position_spread"),
        ({"position_spread": (1.0, 1.0)}, "position_spread"),
        ({"position_dof": 0.0}, "position_dof"),
        ({"max_position_llr": 0.0}, "max_position_llr"),
    ],
)
def test_invalid_position_parameters(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SceneAnalysis(_ranking(0), VISIBLE, **kwargs)
