"""The scene-analysis rule of the first version of mapinterp (commit 11d7ded), frozen verbatim: the
reference that ``backtracking: hard`` with ``questions: probability`` must equal exactly
(tests/knowledge_sources/test_scene_analysis.py). Not used by the product."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

__all__ = ["Question", "Decision", "SceneAnalysis", "ranking_weights"]

Strategy = Literal["associative", "prior"]


def ranking_weights(variances: Sequence[float] | np.ndarray, *, beta: float = 3.0) -> np.ndarray:
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

    Use: call :meth:`next_question`; when it returns a :class:`Question`, answer it with
    :meth:`answer`; when it returns ``None``, :meth:`decision` holds the result.
    """

    ranking: Sequence[tuple[int, float]]
    visible: Mapping[int, frozenset[str] | set[str]]
    strategy: Strategy = "associative"
    candidates: int = 8
    accept: float = 0.75
    reliability: float = 0.9
    priors: Mapping[str, float] | None = None
    beta: float = 3.0
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
        labels = [int(k) for k, _ in self.ranking]
        self._rank = {k: i for i, k in enumerate(labels)}
        if self.strategy == "associative":
            w = ranking_weights([v for _, v in self.ranking], beta=self.beta)
            self._weights = {k: float(w[i]) for i, k in enumerate(labels[: self.candidates])}
        else:
            self._weights = {k: 1.0 for k in labels}
        self._likelihood = {k: 1.0 for k in self._weights}
        self._asked = set()
        self._present = set()
        self._steps = []

    # -- state -----------------------------------------------------------------------------
    def _landmarks(self, k: int) -> frozenset[str]:
        return frozenset(self.visible.get(k, ()))

    def posterior(self) -> dict[int, float]:
        """Posterior probability of each surviving candidate (sums to 1; empty when none left)."""
        raw = {k: self._weights[k] * self._likelihood[k] for k in self._weights}
        total = sum(raw.values())
        if total <= 0:
            return {}
        return {k: p / total for k, p in raw.items()}

    def landmark_probabilities(self) -> dict[str, float]:
        """``P(L|A)`` of every landmark visible in a surviving candidate (answered ones included)."""
        post = self.posterior()
        probs: dict[str, float] = {}
        for k, p in post.items():
            for lm in self._landmarks(k):
                probs[lm] = probs.get(lm, 0.0) + p
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
            return self._decide(None, 0.0, "every candidate viewframe was discarded by absent landmarks")
        best = self._best(post)
        own = self._landmarks(best)
        checked = not own or bool(own & self._present)
        if post[best] >= self.accept and checked:
            why = "ranking alone (no landmark visible)" if not own else "landmarks confirmed"
            return self._decide(best, post[best], f"accepted: posterior {post[best]:.3f} >= {self.accept}, {why}")
        probs = self.landmark_probabilities()
        open_ = {lm: p for lm, p in probs.items() if lm not in self._asked}
        if self.strategy == "prior":
            # the seed's order: a-priori P(L), most probable first, then P(L|A) to break ties
            priors = self.priors or {}
            order = sorted(open_, key=lambda lm: (-priors.get(lm, 0.0), -open_[lm], lm))
        else:
            order = sorted(open_, key=lambda lm: (-open_[lm], self._first_rank(lm, post), lm))
        # A landmark visible in every surviving candidate cannot discriminate; it is still worth
        # asking when it belongs to the best candidate (it confirms it) and nothing else is left.
        useful = [lm for lm in order if open_[lm] < 1.0 - 1e-12 or lm in own]
        if not useful:
            return self._decide(best, post[best], f"no question left; best posterior {post[best]:.3f}")
        lm = useful[0]
        holders = [k for k in post if lm in self._landmarks(k)]
        self._pending = Question(lm, self._best({k: post[k] for k in holders}), float(open_[lm]))
        return self._pending

    def _first_rank(self, lm: str, post: Mapping[int, float]) -> int:
        return min(self._rank.get(k, len(self._rank)) for k in post if lm in self._landmarks(k))

    def answer(self, question: Question, present: bool | None, *, score: float | None = None) -> None:
        """Record the detector's answer to ``question``.

        ``present`` is ``True``/``False``, or ``None`` when the detector could not tell or no answer
        came (detector dead or late): the landmark is then marked as asked and nothing else changes.
        Every call counts as one query.
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
        if present is None:
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

    def _decide(self, viewframe: int | None, confidence: float, reason: str) -> None:
        self._decision = Decision(
            viewframe, float(confidence), self._queries, self._backtracks, reason, tuple(self._steps)
        )
        return None
