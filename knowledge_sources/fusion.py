"""Fusion of ranking sources: one candidate weighting from every ranking on the blackboard.

Several knowledge sources rank all viewframes for a camera frame, each with its own error
measure: the associative memory banks (error variance, comparable across banks, merged by
sorting: :func:`models.associative.merge_rankings`) and the skyline (truncated L1 in degrees,
:mod:`models.skyline`). Their scales have nothing in common, and a source's scale changes from
frame to frame (a hazy frame, a flat horizon). The rule, stated once:

Per-frame robust standardisation
    For source ``s`` with errors ``e_s(k)`` over the viewframes it ranked,
    ``z_s(k) = (e_s(k) - median_k e_s) / (1.4826 * MAD_k e_s)``; when more than half the
    errors are equal (MAD 0: e.g. skylines with no overlap all score the truncation) the
    standard deviation is the spread, and a source whose errors are all equal gives z = 0
    (no evidence) rather than infinities. A viewframe a source did not rank gets that
    source's largest z (the least likely).

Likelihoods
    Each source's evidence that viewframe k is the true one is taken as
    ``p_s(obs | k) ∝ exp(-w_s * z_s(k))``: a likelihood falling exponentially with the
    standardised error, the same form as the scene analysis' candidate weights
    (:func:`knowledge_sources.scene_analysis.ranking_weights`). ``w_s`` is the source's weight,
    calibrated on tuning data (scenario ``skyline.weight``; the associative memory's is 1).

Fused
    Sources are taken as independent given k, so the log-likelihoods add:
    ``F(k) = sum_s w_s z_s(k) / sum_s w_s`` (lower is better; dividing by the weights' sum keeps
    F on the z scale). The fused ranking sorts viewframes by F (ties by label), and F is handed
    to the scene analysis in place of an error variance, where ``ranking_weights`` turns it into
    the candidate weights ``exp(-beta (F - F_best) / spread(F))``.

A single source is passed through unchanged (its own errors, its own order): the fusion of one
source is the identity, so a mission without the skyline decides exactly as before.

Shards
    A source may post its ranking in shards (the associative memory: one per indexer, errors
    comparable across shards); :func:`fuse_shards` merges each source's shards by sorting
    (:func:`models.associative.merge_rankings`) and then fuses the sources. The scheduler (its
    candidate weighting) and the tracker (its observation) both call it, so the two see one
    and the same fused ranking of a frame.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from models.associative import Ranking as MemoryRanking

__all__ = ["standardise", "fuse_rankings", "fuse_shards"]

_MAD_TO_STD = 1.4826


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


def fuse_rankings(
    rankings: Mapping[str, tuple[Sequence[int], Sequence[float]]],
    *,
    weights: Mapping[str, float] | None = None,
) -> list[tuple[int, float]]:
    """Fuse ranking sources into one ranking (module docstring).

    Parameters
    ----------
    rankings : mapping source -> (labels, errors)
        Each source's viewframe labels and errors (lower is better), any order.
    weights : mapping source -> weight, optional
        ``w_s >= 0``; a source not named weighs 1. A source of weight 0 is ignored.

    Returns
    -------
    list of (label, score), best first: the source's own errors for a single source, else F.
    """
    weights = dict(weights or {})
    for s, w in weights.items():
        if not w >= 0:
            raise ValueError(f"weight of source {s!r} must be >= 0, got {w}")
    used = {s: r for s, r in rankings.items() if weights.get(s, 1.0) > 0}
    if not used:
        raise ValueError("fuse_rankings needs at least one source of positive weight")
    if len(used) == 1:
        labels, errors = next(iter(used.values()))
        lab = np.asarray(labels, dtype=np.int64)
        err = np.asarray(errors, dtype=np.float64)
        order = np.lexsort((lab, err))
        return [(int(lab[i]), float(err[i])) for i in order]
    universe = sorted({int(k) for labels, _ in used.values() for k in labels})
    pos = {k: i for i, k in enumerate(universe)}
    total = np.zeros(len(universe))
    wsum = 0.0
    for s, (labels, errors) in used.items():
        w = float(weights.get(s, 1.0))
        z = standardise(errors)
        zs = np.full(len(universe), float(z.max()) if z.size else 0.0)
        for k, v in zip(labels, z):
            zs[pos[int(k)]] = v
        total += w * zs
        wsum += w
    fused = total / wsum
    lab = np.asarray(universe, dtype=np.int64)
    order = np.lexsort((lab, fused))
    return [(int(lab[i]), float(fused[i])) for i in order]


def fuse_shards(
    shards: Mapping[str, Sequence[MemoryRanking]],
    *,
    weights: Mapping[str, float] | None = None,
) -> list[tuple[int, float]]:
    """Merge each source's shards, then fuse the sources (module docstring, "Shards").

    ``shards``: source -> the rankings of its shards (:class:`models.associative.Ranking`, e.g.
    :meth:`knowledge_sources.levels.Ranking.ranking`); ``weights`` as :func:`fuse_rankings`.
    """
    from models.associative import merge_rankings

    per_source = {}
    for src, parts in shards.items():
        merged = merge_rankings(list(parts))
        per_source[src] = (merged.viewframes.tolist(), merged.variances.tolist())
    return fuse_rankings(per_source, weights=weights)
