"""Scene analysis: symbolic verification of the associative ranking by landmark questions.

This is the pure decision procedure of the scene-analysis scheduler, free of any middleware: the
:class:`~knowledge_sources.scheduler.Scheduler` agent feeds it rankings and detector answers from
the blackboard and posts what it decides. One :class:`SceneAnalysis` handles one camera frame.

The rule, stated once
---------------------
Candidates and their weights
    ``associative`` (default): the ``candidates`` best viewframes of the associative ranking, with
    weights ``w_k = exp(-beta * (v_k - v_best) / s)`` where ``v`` are the error variances and ``s``
    is a robust spread of the variances over the whole ranking (median absolute deviation about the
    median). A sharp ranking gives one dominant weight; a flat one, near-uniform weights.
    ``prior`` (the seed's original): every viewframe is a candidate, with uniform weights; the
    ranking plays no part in the questions, and is used only to break ties between viewframes the
    landmark answers cannot tell apart.
    With a ``track_prior`` (the tracker's predicted probability of each route point for this
    frame, from the frames before it, see :mod:`knowledge_sources.tracker`), the weights are
    ``w_k * prior_k`` over the whole ranking and the candidates are the ``candidates`` best by
    that product: the questions are conditioned on where the vehicle can be. Without one (no
    tracker, or the tracker is lost), the blind rule above.

Posterior
    ``pi_k ∝ w_k * prod_q lik(answer_q | k)`` over the surviving candidates. How an answer about
    landmark L enters depends on ``backtracking``:

    ``hard`` (the seed paper's rule): for L reported *present* the likelihood is ``q`` if L is
    visible in viewframe k and ``1 - q`` otherwise (``q`` is the detectors' assumed
    reliability); an *absent* L discards every candidate that contains it (the backtrack).

    ``soft`` (default): the detector reports the log-likelihood ratio ``λ = log p(image | L
    there) / p(image | L not there)`` (calibrated on labelled frames, see
    :mod:`models.detectors`), clipped to ``[-max_llr, max_llr]`` so that no single answer is
    trusted beyond what the calibration can vouch for. Candidates containing L multiply their
    likelihood by ``e**λ``, the others by 1 (it is the ratio that matters). An answer without a
    likelihood ratio counts as ``λ = ±log(q / (1 - q))`` for present/absent. After each answer
    a candidate whose posterior falls below ``floor`` is discarded (a backtrack): one wrong
    "absent" lowers the right viewframe, consistent evidence against it removes it.

    Position evidence (``soft`` only, with ``position_evidence``, off by default): an answer with
    ``λ > 0`` (after clipping) that also says *where* the detector found L in the camera frame,
    the placement ``o = (elevation, azimuth, size)`` of :mod:`models.placement` (angles from
    the optical axis, degrees), enters every surviving candidate k that shows L and has a
    placement ``p_k`` of it (from its viewframe). With the camera's turn ``(h_k, t_k)`` (heading
    ccw, pitch up, degrees) against viewframe k known (the skyline's alignment), k predicts
    ``(el_k - t_k, az_k + h_k, size_k)``; without it, only the size is compared (a heading error
    moves every landmark alike, and would swamp the parallax). The residual ``r_k = (d_el, d_az,
    log(size_o / size_k))`` scores ``ℓ_k = position_log_likelihood(r_k)`` (independent
    Student-t terms of scales ``position_spread`` and ``position_dof`` degrees of freedom,
    :func:`models.placement.position_log_likelihood`), and each such candidate's log-likelihood
    gains ``max(ℓ_k - max_j ℓ_j, -max_position_llr)``: the best-fitting holder 0, the others
    less, by at most ``max_position_llr`` (one wrong match cannot kill the truth). The position
    evidence only moves belief between the candidates that show L by where they put it: that L
    is there at all is the presence ratio's ``λ``. A neighbouring route point is a whole route
    spacing off along the route, a camera frame at most a fraction of it, so a near landmark's
    size and bearing tell them apart where its presence cannot. An answer with ``λ <= 0`` has
    no trustworthy place and gives no position evidence.
    ``position_spread`` is calibrated on the evaluation set's tuning split only
    (bench/tuning/calibrate_position.py): the robust spread (1.4826 x median absolute residual,
    about zero) of the detectors' found place, in answers with ``λ > 0`` about landmarks truly
    there, against the frame's true viewframe's prediction carried by the skyline's turn.

    In both, an unanswered question (detector dead or late, or undecided) changes nothing.

Visibility near a viewframe (``soft`` only, ``neighbour_visibility`` = ``a`` > 0)
    A camera frame is taken near a viewframe, not at it: a landmark that comes into view (or
    behind a ridge) between viewframe k and its neighbour along the route may be in the frame
    although k does not show it, or missing although k does. With ``I_j(L)`` = 1 when viewframe j
    shows L, the probability that a frame near k shows L is taken as
    ``v_k(L) = (1 - 2a) I_k(L) + a (I_{k-1}(L) + I_{k+1}(L))`` (a missing neighbour at the route's
    ends counts as k itself), and an answer of ratio ``λ`` multiplies candidate k's likelihood by
    ``v_k e**λ + (1 - v_k)`` (exactly ``e**λ`` and 1 at ``v_k`` = 1 and 0: ``a`` = 0 is the rule
    above). ``P(L|A) = sum_k pi_k v_k(L)``. Questions are still about landmarks some surviving
    candidate shows, asked as seen from one that shows them.

Which question next
    Among landmarks visible in at least one surviving candidate and not yet asked, with
    ``p_L = P(L|A) = sum_{k ∋ L} pi_k``:

    ``questions: probability`` (the seed's order): the highest ``p_L`` first (most probable
    first).

    ``questions: information`` (default): the highest expected information gain about which
    candidate is right, ``IG(L) = H(p_L q + (1 - p_L)(1 - q)) - H(q)`` bits (``H`` the binary
    entropy, the detector a binary channel of reliability ``q``): it favours the landmark that
    splits the posterior mass most evenly, the one that discriminates between the leading
    candidates; ``p_L`` breaks ties.

    Further ties go to the landmark of the better-ranked candidate, then to the id. A landmark
    visible in every surviving candidate cannot discriminate; it is asked only when it belongs
    to the best candidate (it confirms it). The detector is asked about L as seen from the most
    probable surviving candidate containing L.

Acceptance
    The best candidate ``b`` (highest ``pi``) is accepted when ``pi_b >= accept`` and its own
    landmarks have been checked: at least one of them confirmed present (``hard``: answered
    present; ``soft``: ``λ > 0``), or it has none (a viewframe without visible landmarks is
    decided by the ranking alone). When no useful question is left, ``b`` is accepted whatever
    ``pi_b`` is. The confidence reported is ``pi_b``. When every candidate has been discarded
    (``hard`` only: ``soft`` always keeps the best), the frame is not localized
    (``viewframe=None``).

``backtracking: hard`` with ``questions: probability`` is the seed paper's rule exactly, the
rule of the first version of mapinterp.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from models.placement import position_log_likelihood
from models.scenario import SchedulerSpec

__all__ = ["Question", "Decision", "SceneAnalysis", "ranking_weights", "information_gain"]

Strategy = Literal["associative", "prior"]
Backtracking = Literal["hard", "soft"]
QuestionOrder = Literal["information", "probability"]

#: the defaults (strategy, candidates, accept, reliability, beta, backtracking, questions, floor,
#: max_llr): the scenario schema's
_DEFAULTS = SchedulerSpec()


def _entropy(p: float) -> float:
    """Binary entropy in bits."""
    if p <= 0.0 or p >= 1.0:
        return 0.0
    return -(p * math.log2(p) + (1.0 - p) * math.log2(1.0 - p))


def information_gain(p: float, *, reliability: float) -> float:
    """Expected information (bits) a yes/no answer about a landmark of probability ``p`` gives
    about the candidate, the detector being right with probability ``reliability``."""
    q = reliability
    return _entropy(p * q + (1.0 - p) * (1.0 - q)) - _entropy(q)


def ranking_weights(variances: Sequence[float] | np.ndarray, *, beta: float = _DEFAULTS.beta) -> np.ndarray:
    """Candidate weights from error variances (lower variance, higher weight).

    Parameters
    ----------
    variances : sequence of float, shape (H,)
        Error variances of the whole ranking, any order.
    beta : float
        Sharpness; the weight falls by ``e**-beta`` per robust spread of the variances.

    Returns
    -------
    ndarray of shape (H,)
        Weights in (0, 1], 1 at the best viewframe; not normalised.
    """
    v = np.asarray(variances, dtype=np.float64)
    if v.ndim != 1 or v.size == 0:
        raise ValueError("variances must be a non-empty 1-D sequence")
    if beta <= 0:
        raise ValueError("beta must be > 0")
    med = float(np.median(v))
    spread = float(np.median(np.abs(v - med))) * 1.4826
    if not math.isfinite(spread) or spread <= 0:
        spread = float(np.std(v)) or 1.0
    return np.exp(-beta * (v - v.min()) / spread)


@dataclass(frozen=True)
class Question:
    """Ask whether ``landmark`` is present in the camera frame, as seen from ``viewframe``."""

    landmark: str
    viewframe: int
    probability: float  # P(L|A) when asked


@dataclass(frozen=True)
class Decision:
    """The outcome of one frame's scene analysis."""

    viewframe: int | None
    confidence: float
    queries: int
    backtracks: int
    reason: str
    steps: tuple[dict, ...] = ()


@dataclass
class SceneAnalysis:
    """The scene-analysis state of one camera frame.

    Parameters
    ----------
    ranking : sequence of (viewframe, variance)
        The associative ranking, best first (all viewframes, or at least ``candidates`` of them).
    visible : mapping viewframe -> set of landmark ids
        The symbolic descriptions' visible landmarks of every viewframe.
    strategy : "associative" or "prior"
    candidates : int
        How many of the ranking's best viewframes are candidates (associative strategy only).
    accept : float
        Posterior probability at which the best candidate is accepted.
    reliability : float
        Assumed probability ``q`` that a detector's "present" is right, in (0.5, 1).
    priors : mapping landmark -> P(L), optional
        A-priori landmark probabilities; the ``prior`` strategy's question order follows them.
    backtracking : "hard" or "soft"
        How answers enter (module docstring).
    questions : "information" or "probability"
        The question order (module docstring).
    floor : float
        ``soft``: a candidate whose posterior falls below it is discarded.
    max_llr : float
        ``soft``: answers' log-likelihood ratios are clipped to ``[-max_llr, max_llr]``.
    neighbour_visibility : float
        ``soft``: a neighbouring viewframe's share of a viewframe's landmark visibility, in
        [0, 0.5] (module docstring, "Visibility near a viewframe"); 0: the visible sets exactly.
    beta : float
        Sharpness of the ranking weights (:func:`ranking_weights`).
    track_prior : mapping viewframe -> probability, or array (N,) of each route point's, optional
        The tracker's prior over route points for this frame (see "Candidates and their weights").
    placements : mapping viewframe -> {landmark: (elevation_deg, azimuth_deg, size_deg)}, optional
        Where each viewframe shows each landmark (:mod:`models.placement`): the position
        evidence's predictions; without one, no position evidence.
    turns : mapping viewframe -> (heading_deg, pitch_deg), optional
        The camera's turn (ccw) and tilt (up) against each viewframe (the skyline's alignment);
        without a viewframe's, its position evidence compares sizes only.
    position_evidence : bool
        ``soft``: whether answers' places enter the posterior (module docstring).
    position_spread : (elevation_deg, azimuth_deg, log_size)
        The position evidence's Student-t scales.
    position_dof : float
        Its degrees of freedom.
    max_position_llr : float
        The most one answer's position evidence lowers a candidate's log-likelihood.

    Every default is the scenario schema's (:class:`models.scenario.SchedulerSpec`).

    Use: call :meth:`next_question`; when it returns a :class:`Question`, answer it with
    :meth:`answer`; when it returns ``None``, :meth:`decision` holds the result.
    """

    ranking: Sequence[tuple[int, float]]
    visible: Mapping[int, frozenset[str] | set[str]]
    strategy: Strategy = _DEFAULTS.strategy
    candidates: int = _DEFAULTS.candidates
    accept: float = _DEFAULTS.accept
    reliability: float = _DEFAULTS.reliability
    priors: Mapping[str, float] | None = None
    beta: float = _DEFAULTS.beta
    track_prior: Mapping[int, float] | np.ndarray | None = None
    backtracking: Backtracking = _DEFAULTS.backtracking
    questions: QuestionOrder = _DEFAULTS.questions
    floor: float = _DEFAULTS.floor
    max_llr: float = _DEFAULTS.max_llr
    neighbour_visibility: float = _DEFAULTS.neighbour_visibility
    placements: Mapping[int, Mapping[str, Sequence[float]]] | None = None
    turns: Mapping[int, Sequence[float]] | None = None
    position_evidence: bool = _DEFAULTS.position_evidence
    position_spread: tuple[float, float, float] = _DEFAULTS.position_spread
    position_dof: float = _DEFAULTS.position_dof
    max_position_llr: float = _DEFAULTS.max_position_llr
    _weights: dict[int, float] = field(init=False, repr=False)
    _rank: dict[int, int] = field(init=False, repr=False)
    _likelihood: dict[int, float] = field(init=False, repr=False)
    _asked: set[str] = field(init=False, repr=False)
    _present: set[str] = field(init=False, repr=False)
    _steps: list[dict] = field(init=False, repr=False)
    _queries: int = field(init=False, default=0)
    _backtracks: int = field(init=False, default=0)
    _pending: Question | None = field(init=False, default=None)
    _decision: Decision | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        if self.strategy not in ("associative", "prior"):
            raise ValueError(f"strategy must be 'associative' or 'prior', not {self.strategy!r}")
        if not self.ranking:
            raise ValueError("ranking must not be empty")
        if self.candidates < 1:
            raise ValueError("candidates must be >= 1")
        if not 0.0 < self.accept <= 1.0:
            raise ValueError("accept must be in (0, 1]")
        if not 0.5 < self.reliability < 1.0:
            raise ValueError("reliability must be in (0.5, 1)")
        if self.backtracking not in ("hard", "soft"):
            raise ValueError(f"backtracking must be 'hard' or 'soft', not {self.backtracking!r}")
        if self.questions not in ("information", "probability"):
            raise ValueError(f"questions must be 'information' or 'probability', not {self.questions!r}")
        if not 0.0 <= self.floor < 1.0:
            raise ValueError("floor must be in [0, 1)")
        if not self.max_llr > 0:
            raise ValueError("max_llr must be > 0")
        if not 0.0 <= self.neighbour_visibility <= 0.5:
            raise ValueError(f"neighbour_visibility must be in [0, 0.5], not {self.neighbour_visibility}")
        if len(self.position_spread) != 3 or not all(float(v) > 0 for v in self.position_spread):
            raise ValueError("position_spread must be three values > 0: (elevation_deg, azimuth_deg, log_size)")
        if not self.position_dof > 0:
            raise ValueError("position_dof must be > 0")
        if not self.max_position_llr > 0:
            raise ValueError("max_position_llr must be > 0")
        ranked = [int(k) for k, _ in self.ranking]
        self._rank = {k: i for i, k in enumerate(ranked)}
        if self.track_prior is not None:
            tp = self.track_prior
            w = (
                ranking_weights([v for _, v in self.ranking], beta=self.beta)
                if self.strategy == "associative"
                else np.ones(len(ranked))
            )
            at = np.asarray(ranked, dtype=np.int64)
            if isinstance(tp, np.ndarray):  # per route point: looked up in numpy, not per viewframe in Python
                flat = np.asarray(tp, dtype=np.float64).ravel()
                tpv = np.zeros(len(at))
                inside = (at >= 0) & (at < flat.size)
                tpv[inside] = flat[at[inside]]
            else:
                tpv = np.array([float(tp.get(k, 0.0)) for k in ranked], dtype=np.float64)
            prod = np.asarray(w, dtype=np.float64) * tpv
            keep = np.lexsort((np.arange(len(ranked)), -prod))  # by weight, ties in ranking order
            if self.strategy == "associative":
                keep = keep[: self.candidates]
            self._weights = {ranked[i]: float(prod[i]) for i in keep.tolist() if prod[i] > 0}
            if not self._weights:  # a prior that excludes every ranked viewframe: ignore it
                self._weights = {k: float(w[i]) for i, k in enumerate(ranked[: self.candidates])}
        elif self.strategy == "associative":
            w = ranking_weights([v for _, v in self.ranking], beta=self.beta)
            self._weights = {k: float(w[i]) for i, k in enumerate(ranked[: self.candidates])}
        else:
            self._weights = {k: 1.0 for k in ranked}
        # hard: likelihood products; soft: log-likelihoods
        self._likelihood = {k: (0.0 if self.backtracking == "soft" else 1.0) for k in self._weights}
        self._asked = set()
        self._present = set()
        self._steps = []

    # -- state -----------------------------------------------------------------------------
    def _landmarks(self, k: int) -> frozenset[str]:
        return frozenset(self.visible.get(k, ()))

    def posterior(self) -> dict[int, float]:
        """Posterior probability of each surviving candidate (sums to 1; empty when none left)."""
        if self.backtracking == "soft":
            # log space: many strong answers must not underflow
            logs = {
                k: (math.log(w) if (w := self._weights[k]) > 0 else -math.inf) + self._likelihood[k]
                for k in self._weights
            }
            if not logs:
                return {}
            top = max(logs.values())
            raw = {k: math.exp(v - top) for k, v in logs.items()}
        else:
            raw = {k: self._weights[k] * self._likelihood[k] for k in self._weights}
        total = sum(raw.values())
        if total <= 0:
            return {}
        return {k: p / total for k, p in raw.items()}

    def _blurred(self) -> bool:
        return self.backtracking == "soft" and self.neighbour_visibility > 0

    def visibility(self, k: int, landmark: str) -> float:
        """``v_k(L)``: how likely a camera frame near viewframe ``k`` shows ``landmark`` (module
        docstring, "Visibility near a viewframe"); 0 or 1 without ``neighbour_visibility``."""
        here = float(landmark in self._landmarks(k))
        if not self._blurred():
            return here
        a = self.neighbour_visibility
        near = sum(float(landmark in self._landmarks(j)) if j in self.visible else here for j in (k - 1, k + 1))
        return (1.0 - 2.0 * a) * here + a * near

    def landmark_probabilities(self) -> dict[str, float]:
        """``P(L|A)`` of every landmark visible in a surviving candidate (answered ones included)."""
        post = self.posterior()
        probs: dict[str, float] = {}
        for k, p in post.items():
            for lm in self._landmarks(k):
                probs[lm] = probs.get(lm, 0.0) + p
        if self._blurred():
            probs = {lm: sum(p * self.visibility(k, lm) for k, p in post.items()) for lm in probs}
        return probs

    def _best(self, post: Mapping[int, float]) -> int:
        return max(post, key=lambda k: (post[k], -self._rank.get(k, len(self._rank))))

    @property
    def decision(self) -> Decision | None:
        """The result, once :meth:`next_question` has returned ``None``."""
        return self._decision

    # -- the loop --------------------------------------------------------------------------
    def next_question(self) -> Question | None:
        """The next landmark question, or ``None`` when the frame is decided."""
        if self._decision is not None:
            return None
        if self._pending is not None:
            return self._pending
        post = self.posterior()
        if not post:
            self._decide(None, 0.0, "every candidate viewframe was discarded by absent landmarks")
            return None
        best = self._best(post)
        own = self._landmarks(best)
        checked = not own or bool(own & self._present)
        if post[best] >= self.accept and checked:
            why = "ranking alone (no landmark visible)" if not own else "landmarks confirmed"
            self._decide(best, post[best], f"accepted: posterior {post[best]:.3f} >= {self.accept}, {why}")
            return None
        probs = self.landmark_probabilities()
        open_ = {lm: p for lm, p in probs.items() if lm not in self._asked}
        if self.strategy == "prior":
            # the seed's order: a-priori P(L), most probable first, then P(L|A) to break ties
            priors = self.priors or {}
            order = sorted(open_, key=lambda lm: (-priors.get(lm, 0.0), -open_[lm], lm))
        elif self.questions == "information":
            gain = {lm: information_gain(p, reliability=self.reliability) for lm, p in open_.items()}
            order = sorted(open_, key=lambda lm: (-round(gain[lm], 12), -open_[lm], self._first_rank(lm, post), lm))
        else:
            order = sorted(open_, key=lambda lm: (-open_[lm], self._first_rank(lm, post), lm))
        # A landmark visible in every surviving candidate cannot discriminate; it is still worth
        # asking when it belongs to the best candidate (it confirms it) and nothing else is left.
        useful = [lm for lm in order if open_[lm] < 1.0 - 1e-12 or lm in own]
        if not useful:
            self._decide(best, post[best], f"no question left; best posterior {post[best]:.3f}")
            return None
        lm = useful[0]
        holders = [k for k in post if lm in self._landmarks(k)]
        self._pending = Question(lm, self._best({k: post[k] for k in holders}), float(open_[lm]))
        return self._pending

    def _first_rank(self, lm: str, post: Mapping[int, float]) -> int:
        return min(self._rank.get(k, len(self._rank)) for k in post if lm in self._landmarks(k))

    def answer(
        self,
        question: Question,
        present: bool | None,
        *,
        score: float | None = None,
        llr: float | None = None,
        where: Sequence[float] | None = None,
    ) -> None:
        """Record the detector's answer to ``question``.

        ``present`` is ``True``/``False``, or ``None`` when the detector could not tell or no answer
        came (detector dead or late): the landmark is then marked as asked and nothing else changes.
        ``llr`` is the detector's log-likelihood ratio (``soft`` backtracking uses it; ``hard``
        uses ``present`` only). ``where`` is where the detector found the landmark in the camera
        frame, ``(elevation_deg, azimuth_deg, size_deg)`` (:mod:`models.placement`): the
        position evidence (``soft`` only). Every call counts as one query.
        """
        if self._pending is None or question != self._pending:
            raise ValueError(f"answer to {question} does not match the pending question {self._pending}")
        self._pending = None
        self._asked.add(question.landmark)
        step = {
            "landmark": question.landmark,
            "viewframe": question.viewframe,
            "p": round(question.probability, 6),
            "present": present,
            "score": score,
        }
        self._queries += 1  # every question asked counts, answered or not
        if self.backtracking == "soft":
            self._answer_soft(question, present, llr, step, where)
        elif present is None:
            step["effect"] = "no evidence"
        else:
            holders = [k for k in self._weights if question.landmark in self._landmarks(k)]
            if present:
                self._present.add(question.landmark)
                q = self.reliability
                for k in self._weights:
                    self._likelihood[k] *= q if k in holders else (1.0 - q)
                step["effect"] = f"support +{len(holders)}"
            else:
                for k in holders:
                    del self._weights[k]
                    del self._likelihood[k]
                self._backtracks += 1
                step["effect"] = f"discarded {sorted(holders)}"
        self._steps.append(step)

    def _answer_soft(
        self, question: Question, present: bool | None, llr: float | None, step: dict, where: Sequence[float] | None
    ) -> None:
        if llr is None or not math.isfinite(float(llr)):
            if present is None:
                step["effect"] = "no evidence"
                return
            implied = math.log(self.reliability / (1.0 - self.reliability))
            llr = implied if present else -implied
        llr = max(-self.max_llr, min(self.max_llr, float(llr)))
        step["llr"] = round(llr, 4)
        holders = [k for k in self._weights if question.landmark in self._landmarks(k)]
        near = 0
        if self._blurred():
            for k in self._weights:
                v = self.visibility(k, question.landmark)
                if v >= 1.0:
                    self._likelihood[k] += llr
                elif v > 0.0:  # log(v e**llr + 1 - v)
                    self._likelihood[k] += float(np.logaddexp(math.log(v) + llr, math.log1p(-v)))
                    near += k not in holders
        else:
            for k in holders:
                self._likelihood[k] += llr
        if llr > 0:
            self._present.add(question.landmark)
            if self.position_evidence and where is not None:
                moved = self.position_llr(question.landmark, where, holders)
                for k, v in moved.items():
                    self._likelihood[k] += v
                if moved:
                    step["position"] = {str(k): round(v, 4) for k, v in moved.items()}
        post = self.posterior()
        best = self._best(post)
        low = sorted(k for k, p in post.items() if p < self.floor and k != best)
        for k in low:
            del self._weights[k]
            del self._likelihood[k]
        if low:
            self._backtracks += 1
        step["effect"] = (
            f"llr {llr:+.2f} on {len(holders)}"
            + (f" (+{near} near)" if near else "")
            + (f", discarded {low}" if low else "")
        )

    def position_llr(self, landmark: str, where: Sequence[float], holders: Sequence[int]) -> dict[int, float]:
        """The position evidence of ``where`` (the observed placement of ``landmark``) for each of
        ``holders`` that has a placement of it: ``max(ℓ_k - max_j ℓ_j, -max_position_llr)``
        (module docstring); empty when fewer than two holders can be compared."""
        if self.placements is None or len(where) != 3 or not all(math.isfinite(float(v)) for v in where):
            return {}
        el, az, size = (float(v) for v in where)
        if size <= 0:
            return {}
        scores: dict[int, float] = {}
        for k in holders:
            p = (self.placements.get(k) or {}).get(landmark)
            if p is None or float(p[2]) <= 0:
                continue
            turn = None if self.turns is None else self.turns.get(k)
            d_size = math.log(size / float(p[2]))
            if turn is None:
                residual: tuple[float | None, ...] = (None, None, d_size)
            else:
                residual = (el - (float(p[0]) - float(turn[1])), az - (float(p[1]) + float(turn[0])), d_size)
            scores[k] = position_log_likelihood(residual, spread=self.position_spread, dof=self.position_dof)
        if len(scores) < 2:
            return {}
        top = max(scores.values())
        return {k: max(v - top, -self.max_position_llr) for k, v in scores.items()}

    def _decide(self, viewframe: int | None, confidence: float, reason: str) -> None:
        self._decision = Decision(
            viewframe, float(confidence), self._queries, self._backtracks, reason, tuple(self._steps)
        )
        return None
