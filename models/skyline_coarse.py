"""The skyline ranking's coarse first stage: a cheap comparison of every reference profile that
picks the candidates the full (robust, shift-searched) match ranks.

The full match (:func:`models.skyline.match_skylines`) costs a median per reference and heading
shift over every bin: at 10,000 viewframes it is most of the skyline ranker's time. This stage
compares the camera profile with every reference in the same robust model on profiles a quarter
the length and at half the shifts, vectorised over all references, and keeps the
``count`` best; only those are matched in full (:func:`ranked_references`).

The comparison (the full match's model, :mod:`models.skyline`, on a coarser grid):

* Profiles are **low-passed and subsampled**: the mean of each block of ``factor`` consecutive
  bins (:data:`COARSE_FACTOR`; blocks centred on the profile), a block valid when all its bins
  are. The references' blocks are fixed (:class:`CoarseSkylines`, prepared once); the camera
  profile's are taken at every ``stride``-th whole-bin heading shift (:data:`COARSE_STRIDE`) up
  to the full match's ``max_heading_deg``, so its heading resolution is ``stride * step_deg``
  (1 degree at the defaults, half a block).
* For each reference and shift, ``d_j = r_j - q_j`` over the blocks ``j`` valid in both: the
  pitch offset is the median of ``d``, clipped to ``max_pitch_deg``, and the error the mean over
  the camera profile's valid blocks of the residuals truncated at ``truncate_deg`` (a block the
  reference does not cover counts ``truncate_deg``; an overlap under ``min_overlap`` scores
  ``truncate_deg``), as in the full match. The best shift's error is the reference's coarse
  error. (The median is the upper median of the blocks valid in both, taken over all ``B`` with
  the invalid ones filled with +inf at even and -inf at odd block positions: exact when as many
  invalid blocks sit at even as at odd positions, as for a contiguous run of even length, and
  off by half the difference in ranks otherwise.)
* No roll: the stage does not fit the tilt the full match fits (``max_roll_deg``).

The work per frame is O(V * (S / stride) * (n / factor)) elementwise and partition operations
in numpy (blocks of :data:`_BLOCK` references at a time, so the temporaries stay bounded), against
the full match's O(V * S * n) with a median per shift.

Chosen on the evaluation set's tuning split padded to 10,000 references (``bench/skyline_coarse.py``;
BENCHMARKS.md, "Skyline coarse stage"): a least-squares comparison (pitch and tilt fitted in
closed form, every sum from three BLAS products, 22 ms a frame) lost the full ranking's first
on 6.5 % of the frames at 300 candidates, where a stretch of the camera horizon's columns was
wrong (squared errors let them decide); the robust one with the tilt fitted from the medians of
the two halves kept it within the first 222, without the tilt within the first 86 (stride 2)
and 95 (stride 4, 40 % cheaper; but on rough synthetic profiles, tests/models/test_skyline.py,
a heading error of half a block cost up to 100 ranks); blocks of 8 bins lost it on one frame.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from models.scenario import SkylineSpec
from models.skyline import SkylineMatch, match_skylines

__all__ = [
    "COARSE_FACTOR",
    "COARSE_STRIDE",
    "CoarseSkylines",
    "coarse_errors",
    "coarse_candidates",
    "ranked_references",
]

#: bins averaged into one block of the coarse profiles (2 degrees at the default 0.5-degree step)
COARSE_FACTOR = 4
#: the coarse stage's heading shifts are every this many bins (1 degree at the default step)
COARSE_STRIDE = 2

_DEFAULTS = SkylineSpec()
_MIN_OVERLAP = 0.5  # the full match's (models.skyline)
_BLOCK = 1024  # references compared at once: each (block, shifts, blocks) temporary about 3 MB
_SHARED = ("step_deg", "max_heading_deg", "max_pitch_deg", "truncate_deg", "min_overlap")  # with the full match
_FILL = np.float32(1e9)  # invalid blocks in a median: alternately +_FILL and -_FILL


def _blocks(profiles: NDArray, factor: int) -> tuple[NDArray[np.float64], NDArray[np.bool_], int]:
    """Block means (R, B) of profiles (R, n), their validity, and the first block's first bin."""
    p = np.asarray(profiles, dtype=np.float64)
    n = p.shape[1]
    b = n // factor
    offset = (n - b * factor) // 2
    x = p[:, offset : offset + b * factor].reshape(len(p), b, factor)
    valid: NDArray[np.bool_] = np.asarray(np.isfinite(x).all(axis=2))
    return np.where(valid, np.nan_to_num(x).mean(axis=2), 0.0), valid, int(offset)


@dataclass(frozen=True)
class CoarseSkylines:
    """Reference profiles prepared for the coarse stage (module docstring).

    ``values`` (V, B) float32 block means (0 where invalid), ``valid`` (V, B) bool; ``bins`` the
    profiles' n, ``factor`` bins per block, ``offset`` the first block's first bin.
    """

    values: NDArray[np.float32]
    valid: NDArray[np.bool_]
    bins: int
    factor: int
    offset: int

    @classmethod
    def prepare(cls, references: NDArray, *, factor: int = COARSE_FACTOR) -> CoarseSkylines:
        """Prepare ``references`` (V, n) (NaN: invalid bins, as :func:`models.skyline.match_skylines`)."""
        r = np.asarray(references, dtype=np.float64)
        if r.ndim != 2:
            raise ValueError(f"references must have shape (V, n), not {r.shape}")
        if not 1 <= int(factor) <= r.shape[1] // 4:
            raise ValueError(f"factor must be in [1, n / 4] = [1, {r.shape[1] // 4}], got {factor}")
        values, valid, offset = _blocks(r, int(factor))
        return cls(values.astype(np.float32), valid, int(r.shape[1]), int(factor), offset)

    def __len__(self) -> int:
        return len(self.values)

    def rows(self, lo: int, hi: int) -> CoarseSkylines:
        """The references ``lo:hi`` (views, no copy)."""
        return CoarseSkylines(self.values[lo:hi], self.valid[lo:hi], self.bins, self.factor, self.offset)


def _query_blocks(
    q: NDArray[np.float64], coarse: CoarseSkylines, shifts: NDArray[np.int64]
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """The camera profile's block means (S, B) facing the references' blocks at each shift and
    their validity (S, B).

    At shift ``s`` the camera bin ``i`` faces the reference bin ``i - s`` (the full match's
    convention), so the reference block starting at bin ``o`` faces the camera bins ``o + s``
    onwards; bins outside the profile are invalid."""
    k = coarse.factor
    nb = coarse.values.shape[1]
    ok = np.isfinite(q)
    pad = int(np.abs(shifts).max(initial=0)) + 2 * k
    qv = np.concatenate([np.zeros(pad), np.where(ok, q, 0.0), np.zeros(pad)])
    qo = np.concatenate([np.zeros(pad), ok.astype(np.float64), np.zeros(pad)])
    csum = np.concatenate([[0.0], np.cumsum(qv)])
    cnt = np.concatenate([[0.0], np.cumsum(qo)])
    start = coarse.offset + k * np.arange(nb)[None, :] + shifts[:, None] + pad  # (S, B), in padded bins
    valid = (cnt[start + k] - cnt[start]) == k
    values = np.where(valid, (csum[start + k] - csum[start]) / k, 0.0)
    return values.astype(np.float32), valid


def _median(d: NDArray[np.float32], both: NDArray[np.bool_]) -> NDArray[np.float32]:
    """Median over the last axis of the entries where ``both`` (module docstring)."""
    b = d.shape[-1]
    fill = np.where(np.arange(b) % 2 == 0, _FILL, -_FILL).astype(np.float32)
    x = np.where(both, d, fill)
    x.partition(b // 2, axis=-1)  # in place: x is a fresh array
    return x[..., b // 2]


def coarse_errors(
    query: NDArray,
    coarse: CoarseSkylines,
    *,
    step_deg: float = _DEFAULTS.step_deg,
    max_heading_deg: float = _DEFAULTS.max_heading_deg,
    max_pitch_deg: float = _DEFAULTS.max_pitch_deg,
    truncate_deg: float = _DEFAULTS.truncate_deg,
    min_overlap: float = _MIN_OVERLAP,
    stride: int = COARSE_STRIDE,
) -> NDArray[np.float64]:
    """The coarse error (degrees, lower is better; module docstring) of the camera profile
    ``query`` (n,) against each prepared reference, shape (V,)."""
    q = np.asarray(query, dtype=np.float64).ravel()
    if q.size != coarse.bins:
        raise ValueError(f"query has {q.size} bins, the references {coarse.bins}")
    if not truncate_deg > 0 or max_heading_deg < 0 or max_pitch_deg < 0:
        raise ValueError("truncate_deg must be > 0, max_heading_deg and max_pitch_deg >= 0")
    if int(stride) < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    v = len(coarse)
    trunc = np.float32(truncate_deg)
    qn = float(np.isfinite(q).sum()) / coarse.factor  # the camera profile's valid bins, in blocks
    out = np.full(v, float(truncate_deg))
    if v == 0 or qn <= 0:
        return out
    smax = min(int(round(max_heading_deg / step_deg)), coarse.bins - 1)
    shifts = np.arange(-smax, smax + 1)
    shifts = shifts[shifts % int(stride) == 0]
    qb, qok = _query_blocks(q, coarse, shifts)
    need = max(2.0, min_overlap * qn)
    qok_t = qok.T.astype(np.float32)
    for i in range(0, v, _BLOCK):
        d = coarse.values[i : i + _BLOCK, None, :] - qb[None]  # (R, S, B)
        both = coarse.valid[i : i + _BLOCK, None, :] & qok[None]
        # blocks valid in both, (R, S): a product of 0/1 matrices (exact) costs less than a sum over the short last axis
        m = (coarse.valid[i : i + _BLOCK].astype(np.float32) @ qok_t).astype(np.int64)
        d -= np.clip(_median(d, both), -max_pitch_deg, max_pitch_deg)[..., None]
        np.abs(d, out=d)
        np.minimum(d, trunc, out=d)
        np.multiply(d, both, out=d)  # 0 where not both (d >= 0 here: the same +0.0 as an assignment)
        err = (d.sum(axis=2) + trunc * np.maximum(np.float32(qn) - m, 0.0)) / np.float32(qn)
        err[m < need] = trunc
        out[i : i + _BLOCK] = np.minimum(err.min(axis=1), trunc)
    return out


def coarse_candidates(query: NDArray, coarse: CoarseSkylines, count: int, **match: Any) -> NDArray[np.int64]:
    """Indices (ascending) of the ``count`` references of the lowest coarse error (all of them
    when ``count >= V``); ties at the cut: the first references. ``match``: the keywords of
    :func:`coarse_errors`."""
    if int(count) < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    v = len(coarse)
    if count >= v:
        return np.arange(v, dtype=np.int64)
    e = coarse_errors(query, coarse, **match)
    best = np.argsort(e, kind="stable")[: int(count)]
    return np.sort(best).astype(np.int64)


def coarse_options(match: Mapping[str, Any]) -> dict[str, Any]:
    """The keywords of :func:`coarse_errors` among the full match's ``match`` (the scenario's
    :meth:`models.scenario.SkylineSpec.match_options`): all but the roll's."""
    return {k: v for k, v in match.items() if k in _SHARED}


def ranked_references(
    query: NDArray,
    references: NDArray,
    coarse: CoarseSkylines | None,
    *,
    candidates: int | None,
    roll_candidates: int | None = _DEFAULTS.roll_candidates,
    **match: Any,
) -> tuple[NDArray[np.int64], SkylineMatch]:
    """The skyline ranking of ``query`` (n,) against ``references`` (V, n) with its coarse stage.

    The ``candidates`` references of the lowest coarse error (:func:`coarse_candidates` on
    ``coarse``, the same references prepared) are matched in full
    (:func:`models.skyline.match_skylines`); with ``candidates`` None or >= V, or ``coarse``
    None, every reference is (the exact full ranking). ``match``: the keywords the two
    stages share (``step_deg``, ``max_heading_deg``, ``max_pitch_deg``, ``truncate_deg``,
    ``max_roll_deg``). Returns the indices (ascending) of the references matched and their match.
    """
    r = np.asarray(references)
    if candidates is None or coarse is None or candidates >= len(r):
        return np.arange(len(r), dtype=np.int64), match_skylines(query, r, roll_candidates=roll_candidates, **match)
    if len(coarse) != len(r):
        raise ValueError(f"coarse holds {len(coarse)} references, not the {len(r)} given")
    idx = coarse_candidates(query, coarse, candidates, **coarse_options(match))
    return idx, match_skylines(query, r[idx], roll_candidates=roll_candidates, **match)
