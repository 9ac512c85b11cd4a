"""Fusion of ranking sources: one candidate weighting from every ranking on the blackboard.

Several knowledge sources rank all viewframes for a camera frame, each with its own error
measure: the associative memory banks (error variance, comparable across banks, merged by
sorting: :func:`models.associative.merge_rankings`) and the skyline (mean truncated L1 residual
in degrees of elevation, :mod:`models.skyline`). The rule, stated once: a product of per-source
likelihoods, each calibrated on the evaluation set's tuning split.

Evidence of a source
    A source's errors ``e_s(k)`` over the viewframes k it ranked become its evidence
    ``u_s(k) >= 0`` (lower: more likely the true viewframe) in one of two ways, by the kind of
    its error measure (:data:`ABSOLUTE_SOURCES`):

    * *robust* (the associative memory, whose error variances have no fixed scale: they move
      with the frame's contrast, haze and texture): per-frame robust z-scores,
      ``u_s(k) = (e_s(k) - median_k e_s) / (1.4826 * MAD_k e_s)`` (:func:`standardise`; when
      more than half the errors are equal the standard deviation is the spread, and errors all
      equal give u = 0: no evidence). The frame's own spread sets the scale.
    * *absolute* (the skyline, whose error is in degrees whatever the frame):
      ``u_s(k) = e_s(k) - min_k e_s``. The scale is fixed, so the source's reliability in this
      frame stays in the evidence: a frame whose horizon was found badly has every viewframe's
      error high and close together, and its skyline hardly moves the fusion, while a clean
      horizon that fits one viewframe to 0.3 degrees and the others to 1 degree or more
      decides. (Standardising the skyline per frame, as in the first version of this rule,
      blew a failed horizon's noise up to the spread of a good one's: the fusion was
      over-confident in the skyline exactly where it failed.)

    A viewframe a source did not rank gets that source's largest evidence (the least likely).

Trust of an absolute source
    An absolute source's best error in a frame says how well it worked there: a skyline that
    fits its best viewframe to 0.5 degrees or better is right first for 60-77 % of the tuning
    frames, one whose best fit is worse than 0.7 degrees for 0-33 % (a horizon found wrongly:
    JPEG blocks, a gray image, clouds; ``bench/perturb.py``), and its errors' differences are
    then noise that the fixed scale does not damp enough. So its weight is scaled by
    ``t_s = clip((hi - min_k e_s) / (hi - lo), 0, 1)``: full up to a best error of ``lo``, none
    from ``hi`` (:data:`ABSOLUTE_TRUST`, degrees for the skyline: 0.5 and 1.0, chosen on the
    tuning split, its frames as rendered and under the perturbations of ``bench/perturb.py``;
    BENCHMARKS.md, "Perturbed camera images"). A frame whose skyline is not trusted at all is
    ranked by the other sources alone.

Likelihoods
    ``p_s(obs | k) ∝ exp(-w_s * t_s * u_s(k))`` (``t_s = 1`` for a robust source), ``w_s`` in nats per unit of evidence (per robust z
    for the memory, per degree for the skyline): the scenario's ``memory.weight`` and
    ``skyline.weight``. The weights are calibrated, not tuned for top-1: they maximise the
    likelihood of the true viewframe (a conditional logit, ``bench/fusion_sweep.py --fit``) over
    the tuning split's frames, so ``exp(-w_s u_s)`` is each source's likelihood on the scale its
    errors really carry.

Fused
    Sources are taken as independent given k, so the log-likelihoods add:
    ``F(k) = sum_s w_s u_s(k) - min_k (...)`` (nats, lower is better; ``exp(-F(k))`` is the
    likelihood ratio of k against the best viewframe, and :func:`fused_log_posterior` normalises
    it over the viewframes, a uniform prior). The fused ranking sorts viewframes by F (ties by
    label), and F is handed to the scene analysis in place of an error variance, where
    ``ranking_weights`` turns it into the candidate weights ``exp(-beta (F - F_best) / spread(F))``.

A single source is passed through unchanged (its own errors, its own order): the fusion of one
source is the identity, so a mission without the skyline decides exactly as before.

Shards
    A source may post its ranking in shards (the associative memory: one per indexer, errors
    comparable across shards); :func:`fuse_shards` merges each source's shards by sorting
    (:func:`models.associative.merge_rankings`) and then fuses the sources. The scheduler (its
    candidate weighting) calls it, and the tracker (its observation) takes
    :func:`shards_log_posterior` of the same shards, so the two see one and the same fused
    ranking of a frame, the tracker with its calibrated scale.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from models.skyline import TRUST_DEG as SKYLINE_TRUST_DEG

if TYPE_CHECKING:
    from models.associative import Ranking as MemoryRanking

__all__ = [
    "ABSOLUTE_SOURCES",
    "ABSOLUTE_TRUST",
    "trust",
    "standardise",
    "evidence",
    "fuse_rankings",
    "fused_log_posterior",
    "fuse_shards",
    "shards_log_posterior",
]

_MAD_TO_STD = 1.4826

#: ranking sources whose errors have a fixed scale across frames (module docstring); the others
#: are standardised per frame
ABSOLUTE_SOURCES: frozenset[str] = frozenset({"skyline"})
#: an absolute source's trust (module docstring): full up to a best error of ``lo``, none from
#: ``hi``, in the source's units (the skyline's degrees)
ABSOLUTE_TRUST: Mapping[str, tuple[float, float]] = {"skyline": SKYLINE_TRUST_DEG}

Rankings = Mapping[str, tuple[Sequence[int], Sequence[float]]]


def standardise(errors: Sequence[float] | np.ndarray) -> np.ndarray:
    """Robust z-scores (module docstring) of one source's errors, shape (H,)."""
    e = np.asarray(errors, dtype=np.float64).ravel()
    if e.size == 0:
        return e
    if not np.all(np.isfinite(e)):
        raise ValueError("errors must be finite")
    med = float(np.median(e))
    spread = _MAD_TO_STD * float(np.median(np.abs(e - med)))
    if not spread > 1e-9 * abs(med):  # more than half the errors equal: the standard deviation
        spread = float(np.std(e))
    if not spread > 1e-9 * abs(med) or spread == 0.0:  # all equal: no evidence
        return np.zeros_like(e)
    return (e - med) / spread


def evidence(errors: Sequence[float] | np.ndarray, *, absolute: bool) -> np.ndarray:
    """One source's evidence ``u_s`` (module docstring) from its errors, shape (H,)."""
    if not absolute:
        return standardise(errors)
    e = np.asarray(errors, dtype=np.float64).ravel()
    if e.size and not np.all(np.isfinite(e)):
        raise ValueError("errors must be finite")
    return e - e.min() if e.size else e


def trust(errors: Sequence[float] | np.ndarray, bounds: tuple[float, float] | None) -> float:
    """An absolute source's trust ``t_s`` in one frame from its errors (module docstring), in [0, 1];
    1 without ``bounds`` ``(lo, hi)`` or errors."""
    e = np.asarray(errors, dtype=np.float64).ravel()
    if bounds is None or e.size == 0:
        return 1.0
    lo, hi = bounds
    if not hi > lo:
        raise ValueError(f"trust bounds must be lo < hi, got {bounds!r}")
    return float(np.clip((hi - float(e.min())) / (hi - lo), 0.0, 1.0))


def _check(rankings: Rankings, weights: Mapping[str, float] | None) -> dict[str, float]:
    weights = dict(weights or {})
    for s, w in weights.items():
        if not w >= 0:
            raise ValueError(f"weight of source {s!r} must be >= 0, got {w}")
    used = {s: float(weights.get(s, 1.0)) for s in rankings if weights.get(s, 1.0) > 0}
    if not used:
        raise ValueError("fusion needs at least one source of positive weight")
    return used


def _fused(
    rankings: Rankings,
    used: Mapping[str, float],
    absolute: Collection[str],
    trusts: Mapping[str, tuple[float, float]],
) -> tuple[np.ndarray, np.ndarray]:
    """(labels (H,), F (H,)) over the union of the viewframes the sources ranked."""
    labels = {s: np.asarray(rankings[s][0], dtype=np.int64).ravel() for s in used}
    universe = np.unique(np.concatenate([labels[s] for s in used]))  # sorted, in numpy: O(H log H), no loop
    total = np.zeros(len(universe))
    for s, w in used.items():
        if s in absolute:
            w *= trust(rankings[s][1], trusts.get(s))
            if w <= 0:
                continue
        u = evidence(rankings[s][1], absolute=s in absolute)
        us = np.full(len(universe), float(u.max()) if u.size else 0.0)
        us[np.searchsorted(universe, labels[s])] = u  # a label ranked twice: its last error, as before
        total += w * us
    return universe, total - (total.min() if total.size else 0.0)


def fuse_rankings(
    rankings: Rankings,
    *,
    weights: Mapping[str, float] | None = None,
    absolute: Collection[str] = ABSOLUTE_SOURCES,
    trusts: Mapping[str, tuple[float, float]] = ABSOLUTE_TRUST,
) -> list[tuple[int, float]]:
    """Fuse ranking sources into one ranking (module docstring).

    Parameters
    ----------
    rankings : mapping source -> (labels, errors)
        Each source's viewframe labels and errors (lower is better), any order.
    weights : mapping source -> weight, optional
        ``w_s >= 0`` in nats per unit of the source's evidence; a source not named weighs 1. A
        source of weight 0 is ignored.
    absolute : collection of source names
        Sources whose errors have a fixed scale (default :data:`ABSOLUTE_SOURCES`).
    trusts : mapping source -> (lo, hi)
        The absolute sources' trust bounds (default :data:`ABSOLUTE_TRUST`; a source not named
        is always trusted).

    Returns
    -------
    list of (label, score), best first: the source's own errors for a single source, else F.
    """
    used = _check(rankings, weights)
    if len(used) == 1:
        labels, errors = rankings[next(iter(used))]
        lab = np.asarray(labels, dtype=np.int64)
        err = np.asarray(errors, dtype=np.float64)
        order = np.lexsort((lab, err))
        return [(int(lab[i]), float(err[i])) for i in order]
    lab, fused = _fused(rankings, used, absolute, trusts)
    order = np.lexsort((lab, fused))
    return [(int(lab[i]), float(fused[i])) for i in order]


def fused_log_posterior(
    rankings: Rankings,
    *,
    weights: Mapping[str, float] | None = None,
    absolute: Collection[str] = ABSOLUTE_SOURCES,
    trusts: Mapping[str, tuple[float, float]] = ABSOLUTE_TRUST,
) -> tuple[np.ndarray, np.ndarray]:
    """The calibrated belief over the viewframes from every source (module docstring).

    Returns ``(labels, log_p)``, both (H,) over the union of the viewframes ranked, labels
    ascending: ``log_p(k) = -F(k) - log sum_j exp(-F(j))``, the log posterior of each viewframe
    under a uniform prior (also for a single source, whose evidence is then its ``w_s u_s``).
    This is the per-viewframe likelihood an observer of the fused ranking (the tracker) takes.
    """
    used = _check(rankings, weights)
    lab, fused = _fused(rankings, used, absolute, trusts)
    ll = -fused
    return lab, ll - float(np.log(np.exp(ll - ll.max()).sum()) + ll.max())


def _merged(shards: Mapping[str, Sequence[MemoryRanking]]) -> dict[str, tuple[list[int], list[float]]]:
    from models.associative import merge_rankings

    per_source = {}
    for src, parts in shards.items():
        merged = merge_rankings(list(parts))
        per_source[src] = (merged.viewframes.tolist(), merged.variances.tolist())
    return per_source


def fuse_shards(
    shards: Mapping[str, Sequence[MemoryRanking]],
    *,
    weights: Mapping[str, float] | None = None,
    absolute: Collection[str] = ABSOLUTE_SOURCES,
    trusts: Mapping[str, tuple[float, float]] = ABSOLUTE_TRUST,
) -> list[tuple[int, float]]:
    """Merge each source's shards, then fuse the sources (module docstring, "Shards").

    ``shards``: source -> the rankings of its shards (:class:`models.associative.Ranking`, e.g.
    :meth:`knowledge_sources.levels.Ranking.ranking`); ``weights``, ``absolute``, ``trusts`` as
    :func:`fuse_rankings`.
    """
    return fuse_rankings(_merged(shards), weights=weights, absolute=absolute, trusts=trusts)


def shards_log_posterior(
    shards: Mapping[str, Sequence[MemoryRanking]],
    *,
    weights: Mapping[str, float] | None = None,
    absolute: Collection[str] = ABSOLUTE_SOURCES,
    trusts: Mapping[str, tuple[float, float]] = ABSOLUTE_TRUST,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fused_log_posterior` of each source's shards merged as :func:`fuse_shards` merges them
    (the same order of viewframes for two or more sources; for one source the order of its errors)."""
    return fused_log_posterior(_merged(shards), weights=weights, absolute=absolute, trusts=trusts)
