"""Holographic (noise-like coding) associative memory: store viewframes, rank a camera image.

Formulas (N x N patterns, ``*`` circular convolution, ``(x)`` circular correlation)::

    write   M := M + K_h * P_h            K_h = make_key(P_h)
    read    R := K_q (x) M                K_q = make_key(Q)
    error   D_h = R^ - P_h,   v_h = var(D_h)

The memory is kept in the frequency domain, ``FM = sum_h rfft2(K_h) rfft2(P_h)``, so a write
is one complex multiply-add and a recall one complex multiply and one ``irfft2``; storage order
does not matter (a sum). Because keys have a flat spectrum, ``K_q (x) K_h`` is a delta for the
same pattern and noise for a different one (see :mod:`models.memory_keys`), so R is the prototype of
Q plus crosstalk from the others.

**Error variance, comparable across banks.** Prototypes are zero mean and unit energy. The
recall is normalised the same way, ``R^ = R / ||R||`` (R is zero mean because keys have no DC),
so with c_h = <R^, P_h> (a cosine)::

    v_h = var(R^ - P_h) = (2 - 2 c_h) / N**2

v_h is bounded (0 .. 4/N**2) and means the same in every bank, so rankings of several banks
merge by sorting (:func:`merge_rankings`). Within one bank the order is that of the
un-normalised error variance var(R - P_h).

**Ranking without a recall image.** By Parseval, with w the weights of the half spectrum and
FK the query key's spectrum::

    <R, P_h> = sum_k w(k) conj(FP_h(k)) conj(FK(k)) FM(k) = Re < w FP_h conj(FM) , conj(FK) >

so each bank precomputes one row per prototype, ``w FP_h conj(FM)``
(:attr:`HolographicMemory.ranking_matrix`, float32, as many bytes as the prototypes), and a
ranking is ONE float32 matrix product of that (H, D) matrix with the query vector
``conj(FK)``, for all banks at once; ``||R||`` per bank is a dot product with the precomputed
power ``w |FM|**2``. The recall R is never formed (:meth:`HolographicMemory.recall` still
gives it, and the tests check the identity against the direct sums).

**Shifts.** The key is shift-equivariant (:mod:`models.memory_keys`): a camera turned by a degree
recalls its viewframe shifted by a few pixels, which the zero-lag error variance punishes.
With ``max_shift = (rows, cols)`` the recall is compared with each prototype at every circular
shift up to that size and v_h is the smallest error variance (``max_shift = 0``: the plain
formula). The similarities at every circular lag are the inverse FFT of the prototype's row
times the query key (see :func:`_search`), so the window costs one N x N inverse FFT per
searched prototype, whatever its size; the default window is the scenario schema's
(:class:`models.scenario.MemorySpec`). To keep the ranking bound by memory bandwidth, every
prototype is scored at zero shift in one pass over the prototype matrix, together with a
low-passed zero-shift score (gaussian of :data:`PRESELECT_SIGMA` pixels, tolerant of the offsets
the search is for); only the :data:`SHIFT_SEARCH_TOP` (32) best by either score are searched
over the shifts. Their variances can only fall; a prototype not among them keeps its zero-shift
variance.

**Reliability** of a ranking: how many robust standard deviations the best stands below the
others, ``(median(rest) - best) / (1.4826 * MAD(rest))`` with ``rest`` all variances but the
best (the spread is floored at 1e-3 of the median, so two equal-looking candidates do not give
infinity). It is scale-free, hence comparable across runs, sizes and bank layouts; about 0..3
means "no clear winner", above ~5 a clear one (with only 3-4 candidates the MAD is unstable and
the number large). A ranking of fewer than two entries has reliability 0.

**Capacity.** Every stored pattern adds crosstalk of the same energy as the signal; the
margin of the true prototype shrinks as sqrt(N_eff / H), N_eff the number of effectively
independent pixels (N**2 / (2 pi sigma**2) with the whitening of :mod:`models.preprocess`). One
bank therefore holds few patterns before its top-1 drops, and fewer still of the views along a
route, which resemble each other so that their crosstalk is structured rather than noise (the
measurements are in BENCHMARKS.md, "Associative memory"). :class:`BankedMemory` therefore splits
the viewframes over banks of ``bank_size`` (default: the scenario schema's). The ranking cost
hardly depends on the bank size (above; a bank adds one power vector of N (N/2 + 1) floats, 1/(2 bank_size) of its
prototype rows). With a bank size of 1 the memory reduces (up to the key normalisation) to the
cross-correlation of the whitened patterns (the NCC baseline) plus the shift search: banking
trades the holographic superposition away for accuracy. Each bank is a
:class:`HolographicMemory` whose :meth:`~HolographicMemory.state` is plain arrays, so banks can
live in other processes and their rankings merge with :func:`merge_rankings`.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Iterable, Mapping, Sequence, Sized
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from models.errors import AssociativeMemoryError
from models.memory_keys import KEY_METHODS, key_phase, key_spectrum, seeded_key
from models.scenario import MAX_SHIFT, MemorySpec

__all__ = [
    "SHIFT_SEARCH_TOP",
    "PRESELECT_SIGMA",
    "Ranking",
    "reliability",
    "HolographicMemory",
    "BankedMemory",
    "merge_rankings",
]

logger = logging.getLogger(__name__)

#: the memory defaults (size, key method, bank size, shift search): the scenario schema's
_DEFAULTS = MemorySpec()
#: the shift search refines this many best zero-shift candidates of a ranking
SHIFT_SEARCH_TOP = 32
#: the shift search also refines the SHIFT_SEARCH_TOP best after a gaussian low-pass of this many
#: memory pixels (of the zero-lag similarity): on 128 pooled viewframes of the evaluation set's
#: tuning split the zero-lag candidates alone missed the truth of 14 % of the frames that a full
#: search finds (BENCHMARKS.md, "Associative ranking defaults")
PRESELECT_SIGMA = 8.0

_MAD_TO_STD = 1.4826
#: dtype a bank keeps its memory spectrum rfft2(M) in: complex64 ranks as complex128 does
#: (``bench/coarse.py``; BENCHMARKS.md "Scale") at half the bytes
SPECTRUM_DTYPE = np.complex64


@lru_cache(maxsize=8)
def _parseval_weights(n: int) -> NDArray[np.float64]:
    """Parseval weights of the (N, N // 2 + 1) half spectrum, read-only, shared by all banks of size N."""
    w = np.full((n, n // 2 + 1), 2.0 / (n * n))
    w[:, 0] /= 2.0
    if n % 2 == 0:
        w[:, n // 2] /= 2.0
    w.setflags(write=False)
    return w


def reliability(variances: ArrayLike) -> float:
    """Robust z-score of the smallest variance against the others (see the module docstring)."""
    v = np.sort(np.asarray(variances, dtype=np.float64).ravel())
    if v.size < 2:
        return 0.0
    best, rest = v[0], v[1:]
    med = float(np.median(rest))
    spread = max(_MAD_TO_STD * float(np.median(np.abs(rest - med))), 1e-3 * abs(med), 1e-300)
    return float((med - best) / spread)


@dataclass(frozen=True)
class Ranking:
    """Stored viewframes ordered by error variance, best (smallest) first.

    ``viewframes`` (H,) int64 viewframe indices; ``variances`` (H,) float64 in the same order;
    ``reliability`` see :func:`reliability`.

    Example::

        >>> r = Ranking(np.array([2, 0]), np.array([1e-5, 1.2e-4]), 3.0)
        >>> r.top(1)
        [(2, 1e-05)]
    """

    viewframes: NDArray[np.int64]
    variances: NDArray[np.float64]
    reliability: float = field(default=0.0)

    def __post_init__(self) -> None:
        viewframes = np.asarray(self.viewframes, dtype=np.int64).ravel()
        variances = np.asarray(self.variances, dtype=np.float64).ravel()
        if viewframes.shape != variances.shape:
            raise AssociativeMemoryError(
                f"ranking: viewframes ({viewframes.size}) and variances ({variances.size}) differ in length"
            )
        object.__setattr__(self, "viewframes", viewframes)
        object.__setattr__(self, "variances", variances)
        object.__setattr__(self, "reliability", float(self.reliability))

    def __len__(self) -> int:
        return int(self.viewframes.size)

    @property
    def best(self) -> int | None:
        """Index of the best viewframe, or None for an empty ranking."""
        return int(self.viewframes[0]) if self.viewframes.size else None

    def top(self, k: int) -> list[tuple[int, float]]:
        """The ``k`` best as ``[(viewframe, variance), ...]``."""
        if k < 0:
            raise ValueError(f"k must be >= 0, got {k!r}")
        return [(int(a), float(b)) for a, b in zip(self.viewframes[:k], self.variances[:k])]

    def to_dict(self) -> dict[str, Any]:
        """Plain data (lists, floats) for msgpack/JSON."""
        return {
            "viewframes": [int(x) for x in self.viewframes],
            "variances": [float(x) for x in self.variances],
            "reliability": float(self.reliability),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Ranking:
        """Inverse of :meth:`to_dict`; raises AssociativeMemoryError on malformed data."""
        try:
            return cls(np.asarray(data["viewframes"]), np.asarray(data["variances"]), float(data["reliability"]))
        except (KeyError, TypeError, ValueError) as err:
            raise AssociativeMemoryError(f"ranking: malformed data: {err}") from err


def _ranking(viewframes: NDArray[np.int64], variances: NDArray[np.float64]) -> Ranking:
    # stable sort on (variance, viewframe) so equal variances come in viewframe order
    order = np.lexsort((viewframes, variances))
    return Ranking(viewframes[order], variances[order], reliability(variances))


def _check_key_method(key_method: str) -> None:
    if key_method not in KEY_METHODS:
        raise AssociativeMemoryError(f"key_method must be one of {', '.join(KEY_METHODS)}, got {key_method!r}")


def _check_shift(max_shift: int | tuple[int, int]) -> tuple[int, int]:
    """``max_shift`` as a (rows, cols) pair of non-negative ints."""
    pair = (max_shift, max_shift) if isinstance(max_shift, (int, np.integer)) else tuple(max_shift)
    if len(pair) != 2 or any(
        isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0 or v > MAX_SHIFT for v in pair
    ):
        raise AssociativeMemoryError(
            f"max_shift must be an int or (rows, cols) of ints in 0..{MAX_SHIFT}, got {max_shift!r}"
        )
    return int(pair[0]), int(pair[1])


def _interleave(spec: NDArray[np.complexfloating]) -> NDArray[np.float32]:
    """A complex array as float32 interleaved (real, imag): (..., N, M) -> (..., 2 N M)."""
    spec = np.ascontiguousarray(spec, dtype=np.complex64)
    return spec.view(np.float32).reshape(*spec.shape[:-2], -1)


def _zero_lag_query(key: NDArray[np.complexfloating]) -> NDArray[np.float32]:
    """(D,) float32: conj(key) interleaved, the query vector of the zero-lag similarities."""
    return _interleave(np.conj(key))


def _search(
    matrix: NDArray[np.float32],
    key: NDArray[np.complexfloating],
    max_shift: tuple[int, int],
    scale: NDArray[np.float64],
) -> NDArray[np.float64]:
    """``scale * max over lags of <shift_lag(R), P_h>`` for every row h of ``matrix``, shape (H,).

    Zero lag for every row: one pass over the matrix, bound by memory bandwidth. The other lags
    only for the candidates that pass: the :data:`SHIFT_SEARCH_TOP` best at zero lag and the as
    many best at zero lag after a low-pass of :data:`PRESELECT_SIGMA` memory pixels (a camera
    frame a few rows or columns off its viewframe keeps its low-passed similarity, while its
    zero-lag one decorrelates; the low-passed query rides along in the same pass). The search
    only raises a similarity, so no other row overtakes a searched one unfairly: a row not
    searched keeps its zero-lag similarity. For each candidate, the similarities at *every*
    circular lag are one inverse FFT of its row times the key (row h is ``w FP_h conj(FM)``; the
    interleaved dot product with a query vector q is ``Re sum row conj(q)``, with q = conj(FK)
    e^(-2 pi i k.d/N) for lag d, so ``<shift_d(R), P_h> = Re sum_half w FP_h conj(FM) FK
    e^(2 pi i k.d/N)``, which is ``irfft2(FP_h conj(FM) FK)`` at d: the weights w are irfft2's
    own), and the maximum is taken over the ``max_shift`` window. The second inverse FFT (over
    the columns) is taken only on the window's rows (the same numbers as irfft2's: numpy
    computes it in that order), so the cost grows a little with the window's rows.
    """
    if max_shift == (0, 0) or matrix.shape[0] <= SHIFT_SEARCH_TOP:
        c = (matrix @ _zero_lag_query(key)).astype(np.float64) * scale
        top: NDArray[np.intp] | None = None  # every row
    else:
        n = key.shape[0]
        both = matrix @ np.stack([_zero_lag_query(key), _zero_lag_query(key * _lowpass(n, PRESELECT_SIGMA))], 1)
        c = both[:, 0].astype(np.float64) * scale
        low = both[:, 1].astype(np.float64) * scale
        k = SHIFT_SEARCH_TOP
        top = np.union1d(np.argpartition(-c, k - 1)[:k], np.argpartition(-low, k - 1)[:k])
    if max_shift != (0, 0) and c.size:
        n = key.shape[0]
        picked = matrix if top is None else matrix[top]  # every row: the matrix itself, not a copy
        rows = np.ascontiguousarray(picked).view(np.complex64).reshape(picked.shape[0], n, n // 2 + 1)
        prod = rows * (key / _parseval_weights(n)).astype(np.complex64)[None]
        rr = np.arange(-max_shift[0], max_shift[0] + 1) % n
        cc = np.arange(-max_shift[1], max_shift[1] + 1) % n
        # irfft2 as numpy computes it (the inverse FFT over the rows, then the real one over the
        # columns), the second only on the window's rows: the same numbers at a third of the cost
        lag = np.fft.irfft(np.fft.ifft(prod, n, axis=-2)[:, rr], n, axis=-1)  # lag[i, c % n]: lag (rr[i], c)
        best = lag[:, :, cc].reshape(rows.shape[0], -1).max(axis=1)
        at = slice(None) if top is None else top
        c[at] = np.maximum(best.astype(np.float64) * scale[at], c[at])
    return c


def _normalised(pattern: ArrayLike, n: int, what: str) -> NDArray[np.float32]:
    """``pattern`` (N, N) checked (``what`` names the operation in the error) and normalised: zero
    mean, unit energy, float32 (zeros when it has no energy)."""
    p = np.asarray(pattern)
    if p.shape != (n, n):
        raise AssociativeMemoryError(f"{what}: pattern must have shape ({n}, {n}), got {p.shape}")
    if not np.issubdtype(p.dtype, np.number) or not np.all(np.isfinite(p)):
        raise AssociativeMemoryError(f"{what}: pattern must hold finite numbers")
    p = p.astype(np.float64)
    p -= p.mean()
    energy = float(np.sqrt(np.sum(p * p)))
    if energy <= 1e-12:
        return np.zeros((n, n), dtype=np.float32)
    return (p / energy).astype(np.float32)


@lru_cache(maxsize=8)
def _lowpass(n: int, sigma: float) -> NDArray[np.float64]:
    """Half-spectrum (N, N // 2 + 1) transfer function of a gaussian blur of ``sigma`` pixels."""
    f2 = np.fft.fftfreq(n)[:, None] ** 2 + np.fft.rfftfreq(n)[None, :] ** 2
    g = np.exp(-2.0 * np.pi**2 * sigma * sigma * f2)
    g.setflags(write=False)
    return g


def _config_state(mem: HolographicMemory | BankedMemory) -> dict[str, Any]:
    """The configuration part of a memory's :meth:`state` (plain data)."""
    return {"size": mem.size, "seed": mem.seed, "key_method": mem.key_method, "max_shift": list(mem.max_shift)}


def _config_from_state(state: dict[str, Any]) -> tuple[int, dict[str, Any]]:
    """``(size, keyword arguments)`` of a memory's constructor from its :meth:`state`."""
    return int(state["size"]), {
        "seed": int(state["seed"]),
        "key_method": str(state["key_method"]),
        "max_shift": tuple(int(v) for v in state["max_shift"]),
    }


class HolographicMemory:
    """One memory bank of size N x N, stored in the frequency domain.

    Parameters
    ----------
    size : int
        Side N of the patterns and of the memory.
    seed : int
        Seed of the keys' random phase (see :func:`models.memory_keys.make_key`).
    key_method : str
        K-GEN method, one of :data:`models.memory_keys.KEY_METHODS`.
    max_shift : int or (rows, cols)
        The recall is compared with each prototype at every circular shift up to this many
        memory pixels (see the module docstring, "Shifts"); 0 compares at zero lag only.
    """

    def __init__(
        self,
        size: int = _DEFAULTS.size,
        *,
        seed: int = 0,
        key_method: str = _DEFAULTS.key,
        max_shift: int | tuple[int, int] = _DEFAULTS.max_shift,
    ) -> None:
        if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 4:
            raise AssociativeMemoryError(f"size must be an integer >= 4, got {size!r}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise AssociativeMemoryError(f"seed must be an integer >= 0, got {seed!r}")
        _check_key_method(key_method)
        self.size = int(size)
        self.seed = int(seed)
        self.key_method = key_method
        self.max_shift = _check_shift(max_shift)
        n = self.size
        self._spectrum = np.zeros((n, n // 2 + 1), dtype=SPECTRUM_DTYPE)
        self._weights = _parseval_weights(n)  # Parseval weights of the half spectrum (shared)
        # w * rfft2(P_h), interleaved float32; a capacity buffer whose first _count rows are used
        self._fprotos = np.zeros((0, 2 * n * (n // 2 + 1)), dtype=np.float32)
        self._viewframes = np.zeros(0, dtype=np.int64)
        self._count = 0
        self._match: NDArray[np.float32] | None = None  # (H, D) ranking matrix, built on demand
        #: finalized (:meth:`finalize`): only the ranking matrix and the recall energy are kept
        self.final = False
        self._energy_sq = 0.0  # sum w |FM|^2, kept when finalized

    def finalize(self) -> None:
        """Keep only what a ranking reads: the ranking matrix and the scalar ``sum w |FM|^2``,
        which gives the recall energy of every query, since every key has the same magnitude on
        every bin but DC (:func:`models.memory_keys.key_spectrum`). The prototype spectra and the
        memory's spectrum (two thirds of a bank's bytes) are dropped: the bank then ranks as
        before (the same order; variances to float32 rounding) but cannot be written, recalled
        nor saved (those raise :class:`AssociativeMemoryError`)."""
        if self.final:
            return
        self.ranking_matrix  # noqa: B018  # built from the spectra before they are dropped
        self._energy_sq = float(np.sum(self._weights * np.abs(self._spectrum.astype(np.complex128)) ** 2))
        n = self.size
        self._fprotos = np.zeros((0, 2 * n * (n // 2 + 1)), dtype=np.float32)
        self._spectrum = np.zeros((0, 0), dtype=SPECTRUM_DTYPE)
        self.final = True

    def _open(self, what: str) -> None:
        if self.final:
            raise AssociativeMemoryError(f"{what}: the bank is finalized (compact): it can only rank")

    # ---------------------------------------------------------------- storage
    def __len__(self) -> int:
        return self._count

    @property
    def viewframes(self) -> NDArray[np.int64]:
        """Viewframe indices in storage order, shape (H,)."""
        return self._viewframes[: self._count]

    @property
    def prototypes(self) -> NDArray[np.float32]:
        """The stored (normalised) patterns, float32 of shape (H, N*N), in storage order."""
        self._open("prototypes")
        n = self.size
        spec = self._fprotos[: self._count].reshape(self._count, n, n // 2 + 1, 2).astype(np.float64)
        spec = (spec[..., 0] + 1j * spec[..., 1]) / self._weights
        return np.fft.irfft2(spec, s=(n, n)).reshape(self._count, n * n).astype(np.float32)

    @property
    def spectrum(self) -> NDArray[np.complexfloating]:
        """The memory ``rfft2(M)``, shape (N, N // 2 + 1), :data:`SPECTRUM_DTYPE` (a view; do not modify)."""
        self._open("spectrum")
        return self._spectrum

    @property
    def ranking_matrix(self) -> NDArray[np.float32]:
        """The C-contiguous float32 matrix a ranking reads, shape (H, 2 * N * (N // 2 + 1)).

        Row h is ``w * rfft2(P_h) * conj(rfft2(M))`` interleaved (real, imag), ``w`` the Parseval
        weights of the half spectrum, so that for a query key spectrum FK
        ``row . interleave(conj(FK)) = <K (x) M, P_h> = <R, P_h>`` (module docstring).
        """
        if self._match is None:
            n = self.size
            pairs = self._fprotos[: self._count].reshape(self._count, n, n // 2 + 1, 2)
            fp = pairs[..., 0].astype(np.complex128) + 1j * pairs[..., 1]
            self._match = np.ascontiguousarray(_interleave(fp * np.conj(self._spectrum)[None]))
        return self._match

    def _pattern(self, pattern: ArrayLike, what: str) -> NDArray[np.float32]:
        return _normalised(pattern, self.size, what)

    def _grow(self, extra: int) -> None:
        need = self._count + extra
        if need > self._fprotos.shape[0]:
            cap = max(need, 2 * self._fprotos.shape[0])
            protos = np.empty((cap, self._fprotos.shape[1]), dtype=np.float32)
            protos[: self._count] = self._fprotos[: self._count]
            viewframes = np.empty(cap, dtype=np.int64)
            viewframes[: self._count] = self._viewframes[: self._count]
            self._fprotos, self._viewframes = protos, viewframes

    def write(self, pattern: ArrayLike, viewframe: int) -> None:
        """Store a pattern of shape (N, N) under ``viewframe``: ``M := M + K(P) * P``.

        The pattern is normalised (zero mean, unit energy) if it is not already; a featureless
        pattern or a viewframe already stored raises :class:`AssociativeMemoryError`.
        """
        self.write_many([pattern], [viewframe])

    def write_many(self, patterns: Iterable[ArrayLike], viewframes: Iterable[int]) -> None:
        """Store several patterns at once (same result as :meth:`write` in a loop)."""
        self._open("write")
        pats = [self._pattern(p, "write") for p in patterns]
        vfs = [int(x) for x in viewframes]
        if len(pats) != len(vfs):
            raise AssociativeMemoryError(f"write: {len(pats)} patterns but {len(vfs)} viewframes")
        existing = set(self.viewframes.tolist())
        for p, vf in zip(pats, vfs):
            if not p.any():
                raise AssociativeMemoryError(f"write: pattern of viewframe {vf} is featureless (constant)")
            if vf in existing:
                raise AssociativeMemoryError(f"write: viewframe {vf} is already stored")
            existing.add(vf)
        if not pats:
            return
        self._grow(len(pats))
        for p, vf in zip(pats, vfs):
            fk = key_spectrum(p, seed=self.seed, method=self.key_method)
            fp = np.fft.rfft2(p.astype(np.float64))
            self._spectrum += fk * fp
            self._fprotos[self._count] = _interleave(self._weights * fp)
            self._viewframes[self._count] = vf
            self._count += 1
        self._match = None

    # ---------------------------------------------------------------- recall
    def query_key(self, pattern: ArrayLike) -> NDArray[np.complex128]:
        """Key spectrum of a query pattern (shape (N, N // 2 + 1)), reusable across banks."""
        return key_spectrum(self._pattern(pattern, "query"), seed=self.seed, method=self.key_method)

    def query_phase(self, pattern: ArrayLike) -> NDArray[np.complex128] | None:
        """The seed-independent part of :meth:`query_key` (:func:`models.memory_keys.key_phase`
        of the normalised pattern): one query's, shared by memories of any seed with this size and
        key method; None for a featureless pattern."""
        return key_phase(self._pattern(pattern, "query"), method=self.key_method)

    def key_of_phase(self, phase: NDArray[np.complexfloating] | None) -> NDArray[np.complex128]:
        """:meth:`query_key` from the pattern's :meth:`query_phase` (the same numbers)."""
        n = self.size
        return np.zeros((n, n // 2 + 1), dtype=np.complex128) if phase is None else seeded_key(phase, seed=self.seed)

    def recall(self, pattern: ArrayLike, *, key: NDArray[np.complex128] | None = None) -> NDArray[np.float64]:
        """``R = K(pattern) (x) M``, shape (N, N), float64 (not normalised).

        ``key`` may pass a precomputed :meth:`query_key` (then ``pattern`` is not used).
        """
        fk = self.query_key(pattern) if key is None else key
        self._open("recall")
        n = self.size
        return np.fft.irfft2(np.conj(fk) * self._spectrum, s=(n, n))

    def recall_energy(self, key: NDArray[np.complexfloating]) -> float:
        """``||R||`` for a query key spectrum, without the inverse FFT (Parseval)."""
        if self.final:  # |FK| is the same on every bin but DC, where FM is 0
            return float(np.sqrt(self._energy_sq)) * float(np.max(np.abs(key), initial=0.0))
        return float(np.sqrt(np.sum(self._weights * np.abs(self._spectrum) ** 2 * np.abs(key) ** 2)))

    def similarities(self, pattern: ArrayLike, *, key: NDArray[np.complex128] | None = None) -> NDArray[np.float64]:
        """Cosines ``c_h = max over shifts d of <shift_d(R) / ||R||, P_h>``, storage order, (H,)."""
        fk = self.query_key(pattern) if key is None else key
        energy = self.recall_energy(fk)
        if self._count == 0 or energy <= 1e-12:
            return np.zeros(self._count, dtype=np.float64)
        c = _search(self.ranking_matrix, fk, self.max_shift, np.ones(self._count))
        return c / energy

    def error_variances(
        self, pattern: ArrayLike, *, key: NDArray[np.complex128] | None = None
    ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """``(viewframes, variances)`` in storage order: ``var(R^ - P_h)`` for every stored P_h
        (minimised over the searched shifts of R^)."""
        c = self.similarities(pattern, key=key)
        n2 = float(self.size * self.size)
        return self.viewframes.copy(), np.maximum(2.0 - 2.0 * c, 0.0) / n2

    def rank(self, pattern: ArrayLike, *, key: NDArray[np.complex128] | None = None) -> Ranking:
        """All stored viewframes ordered by error variance, best first."""
        viewframes, variances = self.error_variances(pattern, key=key)
        return _ranking(viewframes, variances)

    # ---------------------------------------------------------------- transport
    def state(self) -> dict[str, Any]:
        """Plain data (ints, str, numpy arrays) from which :meth:`from_state` rebuilds the bank."""
        self._open("state")
        return {
            **_config_state(self),
            "viewframes": self.viewframes.copy(),
            "prototype_spectra": self._fprotos[: self._count].copy(),
            "spectrum": np.stack([self._spectrum.real, self._spectrum.imag], axis=-1),
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> HolographicMemory:
        """Rebuild a bank from :meth:`state`; raises AssociativeMemoryError on malformed data."""
        try:
            size, config = _config_from_state(state)
            mem = cls(size, **config)
            n = mem.size
            viewframes = np.asarray(state["viewframes"], dtype=np.int64).ravel()
            protos = np.asarray(state["prototype_spectra"], dtype=np.float32)
            protos = protos.reshape(viewframes.size, 2 * n * (n // 2 + 1))
            spec = np.asarray(state["spectrum"], dtype=np.float64)
            if spec.shape != (n, n // 2 + 1, 2):
                raise ValueError(f"spectrum has shape {spec.shape}, expected {(n, n // 2 + 1, 2)}")
        except (KeyError, TypeError, ValueError) as err:
            raise AssociativeMemoryError(f"memory state: malformed: {err}") from err
        if np.unique(viewframes).size != viewframes.size:
            raise AssociativeMemoryError("memory state: duplicate viewframes")
        mem._fprotos, mem._viewframes, mem._count = np.ascontiguousarray(protos), viewframes.copy(), viewframes.size
        mem._spectrum = (spec[..., 0] + 1j * spec[..., 1]).astype(SPECTRUM_DTYPE)
        return mem


def merge_rankings(rankings: Sequence[Ranking]) -> Ranking:
    """Merge the rankings of several banks into one.

    The variances are of the unit-energy recall, so they are comparable across banks and the
    merge is a sort; the reliability is recomputed over the merged variances. Viewframes must be
    distinct across the rankings.
    """
    if not rankings:
        return Ranking(np.zeros(0, np.int64), np.zeros(0, np.float64), 0.0)
    viewframes = np.concatenate([r.viewframes for r in rankings])
    variances = np.concatenate([r.variances for r in rankings])
    if np.unique(viewframes).size != viewframes.size:
        raise AssociativeMemoryError("merge_rankings: a viewframe appears in more than one ranking")
    return _ranking(viewframes, variances)


class BankedMemory:
    """Viewframes split over :class:`HolographicMemory` banks of at most ``bank_size`` each.

    All banks share ``seed``, ``key_method`` and ``max_shift``, so a query's key is computed
    once. ``banks`` is the list of banks (fill order); :meth:`rank` gives the same ranking as
    :func:`merge_rankings` over the banks' own rankings, with one matrix product over the
    banks' ranking matrices packed together.

    ``compact``: each bank is finalized (:meth:`HolographicMemory.finalize`) as soon as it is
    full, its ranking rows written straight into the packed matrix (:meth:`reserve` sizes it
    once), and a ranking finalizes the last, partial bank (a later write opens a new one). A
    compact memory holds a third of the bytes (at N = 128: 66.5 KB per viewframe, the ranking
    row, against about 220 KB) and ranks alike; it cannot recall, give its prototypes, nor save
    its :meth:`state`.
    """

    def __init__(
        self,
        size: int = _DEFAULTS.size,
        *,
        bank_size: int = _DEFAULTS.bank_size,
        seed: int = 0,
        key_method: str = _DEFAULTS.key,
        max_shift: int | tuple[int, int] = _DEFAULTS.max_shift,
        compact: bool = False,
    ) -> None:
        if isinstance(bank_size, bool) or not isinstance(bank_size, (int, np.integer)) or bank_size < 1:
            raise AssociativeMemoryError(f"bank_size must be an integer >= 1, got {bank_size!r}")
        template = HolographicMemory(size, seed=seed, key_method=key_method, max_shift=max_shift)  # validates
        self.size = template.size
        self.seed = template.seed
        self.key_method = template.key_method
        self.max_shift = template.max_shift
        self.bank_size = int(bank_size)
        self.banks: list[HolographicMemory] = []
        self._viewframes: set[int] = set()
        self._packed: NDArray[np.float32] | None = None  # (H, D) all banks' ranking matrices
        self._bank_power: NDArray[np.float64] | None = None  # (B, N * (N // 2 + 1)) w |FM_b|^2
        self._row_bank: NDArray[np.int64] | None = None  # (H,) bank of each packed row
        self.compact = bool(compact)
        d = 2 * self.size * (self.size // 2 + 1)
        self._rows = np.zeros((0, d), dtype=np.float32)  # compact: the packed rows (a capacity buffer)
        self._nrows = 0
        self._row0: list[int] = []  # compact: first packed row of each finalized bank
        self._bank_energy: NDArray[np.float64] | None = None  # compact: (B,) sqrt(sum w |FM_b|^2)
        self._row_vf: tuple[NDArray[np.float32], NDArray[np.int64]] | None = None  # (matrix, its row_viewframes)

    def reserve(self, count: int) -> None:
        """Compact: room for ``count`` viewframes in all (the packed rows are then never copied)."""
        if self.compact and count > self._rows.shape[0]:
            self._regrow(int(count))

    def _regrow(self, cap: int) -> None:
        rows = np.empty((cap, self._rows.shape[1]), dtype=np.float32)
        rows[: self._nrows] = self._rows[: self._nrows]
        self._rows = rows
        for bank, r0 in zip(self.banks, self._row0):  # the finalized banks view the new buffer
            bank._match = rows[r0 : r0 + len(bank)]

    def _finalize(self, bank: HolographicMemory) -> None:
        """Compact: finalize ``bank`` (the next not finalized) into the packed rows."""
        bank.finalize()
        assert bank._match is not None
        if self._nrows + len(bank) > self._rows.shape[0]:
            self._regrow(max(self._nrows + len(bank), 2 * self._rows.shape[0], 64))
        r0 = self._nrows
        self._rows[r0 : r0 + len(bank)] = bank._match
        bank._match = self._rows[r0 : r0 + len(bank)]
        self._row0.append(r0)
        self._nrows += len(bank)
        self._packed = None

    def __len__(self) -> int:
        return sum(len(b) for b in self.banks)

    def _new_bank(self) -> HolographicMemory:
        return HolographicMemory(self.size, seed=self.seed, key_method=self.key_method, max_shift=self.max_shift)

    def write(self, pattern: ArrayLike, viewframe: int) -> None:
        """Store one pattern in the last bank, opening a new bank when it is full."""
        self.write_many([pattern], [viewframe])

    def write_many(self, patterns: Iterable[ArrayLike], viewframes: Iterable[int]) -> None:
        """Store several patterns, filling banks in order. ``patterns`` is consumed one bank at a
        time (an iterator of patterns is never all in memory); when it yields another number of
        patterns than ``viewframes`` has, the error comes after the banks filled so far."""
        vfs = [int(x) for x in viewframes]
        if isinstance(patterns, Sized) and len(patterns) != len(vfs):
            raise AssociativeMemoryError(f"write: {len(patterns)} patterns but {len(vfs)} viewframes")
        dup = self._viewframes.intersection(vfs)
        if dup or len(set(vfs)) != len(vfs):
            raise AssociativeMemoryError(f"write: viewframe {min(dup) if dup else vfs} is already stored")
        source = iter(patterns)
        i = 0
        while i < len(vfs):
            if not self.banks or len(self.banks[-1]) >= self.bank_size or self.banks[-1].final:
                self.banks.append(self._new_bank())
            bank = self.banks[-1]
            take = min(self.bank_size - len(bank), len(vfs) - i)
            pats = list(itertools.islice(source, take))
            if len(pats) < take:
                self._packed = None
                raise AssociativeMemoryError(f"write: {i + len(pats)} patterns but {len(vfs)} viewframes")
            bank.write_many(pats, vfs[i : i + take])
            self._viewframes.update(vfs[i : i + take])
            i += take
            if self.compact and len(bank) >= self.bank_size:
                self._finalize(bank)
        self._packed = None
        if next(source, None) is not None:
            raise AssociativeMemoryError(f"write: more patterns than the {len(vfs)} viewframes")

    @property
    def ranking_matrix(self) -> NDArray[np.float32]:
        """All banks' :attr:`HolographicMemory.ranking_matrix` as one (H, D) array (each bank
        keeps a view of its rows, so nothing is duplicated)."""
        if self.compact:
            for bank in self.banks[len(self._row0) :]:  # the last, partial bank
                if len(bank):
                    self._finalize(bank)
            if self._packed is None:
                self._packed = self._rows[: self._nrows]
                done = self.banks[: len(self._row0)]
                self._bank_energy = np.sqrt(np.array([b._energy_sq for b in done], dtype=np.float64))
                self._row_bank = np.repeat(np.arange(len(done)), [len(b) for b in done])
            return self._packed
        if self._packed is None:
            d = 2 * self.size * (self.size // 2 + 1)
            packed = np.empty((len(self), d), dtype=np.float32)
            row = 0
            for bank in self.banks:
                packed[row : row + len(bank)] = bank.ranking_matrix
                bank._match = packed[row : row + len(bank)]
                row += len(bank)
            self._bank_power = (
                np.stack([(b._weights * np.abs(b.spectrum) ** 2).ravel().astype(np.float32) for b in self.banks])
                if self.banks
                else np.zeros((0, 0), np.float32)
            )
            self._row_bank = np.repeat(np.arange(len(self.banks)), [len(b) for b in self.banks])
            self._packed = packed
        return self._packed

    @property
    def row_viewframes(self) -> NDArray[np.int64]:
        """The viewframe of each row of :attr:`ranking_matrix` ``(H,)``, in storage order (read it
        after the matrix: a compact memory's last, partial bank is finalized there). Made once per
        matrix (one bank per viewframe at the default bank size: 512 arrays a shard); read only."""
        packed = self._packed
        if packed is not None and self._row_vf is not None and self._row_vf[0] is packed:
            return self._row_vf[1]
        banks = self.banks[: len(self._row0)] if self.compact else self.banks
        vf = np.concatenate([b.viewframes for b in banks]) if banks else np.zeros(0, np.int64)
        vf.setflags(write=False)
        if packed is not None:
            self._row_vf = (packed, vf)
        return vf

    def rank(self, pattern: ArrayLike, *, among: ArrayLike | None = None) -> Ranking:
        """Merged ranking of all banks, best first; with ``among`` (viewframe indices), of those
        stored viewframes only (others named are ignored).

        A ranking ``among`` a set is the ranking the memory gives when only those rows are
        searched: each keeps the error variance of its own recall (each bank's recall energy is
        the same), and the shift search's candidates are chosen among them
        (:func:`_search`). So it costs in proportion to the set, and when the full ranking
        shift-searches every row (at most :data:`SHIFT_SEARCH_TOP` rows, or ``max_shift`` 0)
        its order is the full ranking's order restricted to the set.
        """
        return self.rank_many([pattern], among=among)[0]

    def rank_many(
        self,
        patterns: Sequence[ArrayLike],
        *,
        among: ArrayLike | None = None,
        keys: Sequence[NDArray[np.complexfloating]] | None = None,
    ) -> list[Ranking]:
        """:meth:`rank` of each pattern (the same numbers, in order), the rows ``among`` the
        viewframes given picked once for all (the roll search's turned queries of one frame).
        ``keys``: each pattern's :meth:`HolographicMemory.query_key` when the caller has them
        (e.g. from a shared :meth:`HolographicMemory.query_phase`), not made again."""
        if keys is not None and len(keys) != len(patterns):
            raise AssociativeMemoryError(f"rank: {len(keys)} keys for {len(patterns)} patterns")
        if not self.banks:
            return [merge_rankings([]) for _ in patterns]
        matrix = self.ranking_matrix
        assert self._row_bank is not None  # set with the matrix
        viewframes = self.row_viewframes
        row_bank = self._row_bank
        if among is not None:
            rows = np.flatnonzero(np.isin(viewframes, np.asarray(among, dtype=np.int64).ravel()))
            if rows.size == 0:
                return [_ranking(np.zeros(0, np.int64), np.zeros(0, np.float64)) for _ in patterns]
            matrix, viewframes, row_bank = matrix[rows], viewframes[rows], row_bank[rows]
        banks = None if self.compact or among is None else np.unique(row_bank)  # the banks holding a row searched
        out = []
        for i, pattern in enumerate(patterns):
            key = self.banks[0].query_key(pattern) if keys is None else keys[i]
            if self.compact:  # |FK| is the same on every bin but DC: ||R_b|| = sqrt(sum w |FM_b|^2) |FK|
                assert self._bank_energy is not None
                energy = self._bank_energy * float(np.max(np.abs(key), initial=0.0))
            else:
                assert self._bank_power is not None
                power = (np.abs(key) ** 2).ravel().astype(np.float32)
                if banks is None:
                    energy = np.sqrt(np.maximum(self._bank_power @ power, 0.0).astype(np.float64))  # ||R_b|| per bank
                else:
                    energy = np.zeros(len(self.banks))
                    energy[banks] = np.sqrt(np.maximum(self._bank_power[banks] @ power, 0.0).astype(np.float64))
            scale = np.where(energy > 1e-12, 1.0 / np.maximum(energy, 1e-300), 0.0)
            c = _search(matrix, key, self.max_shift, scale[row_bank])
            out.append(_ranking(viewframes, np.maximum(2.0 - 2.0 * c, 0.0) / float(self.size * self.size)))
        return out

    def compact_arrays(self) -> dict[str, NDArray[Any]]:
        """Compact: everything a ranking reads, as four arrays (what :mod:`models.index_store`
        writes to disk; :meth:`from_compact_arrays` is the inverse). The last, partial bank is
        finalized first. ``rows`` (H, D) float32: the packed ranking rows (a view, not a copy);
        ``viewframes`` (H,) int64 in storage order; ``bank_rows`` (B,) int64: the rows of each
        bank, in order; ``bank_energy_sq`` (B,) float64: each bank's ``sum w |FM|^2``."""
        if not self.compact:
            raise AssociativeMemoryError("compact_arrays: only a compact memory (compact=True) gives them")
        rows = self.ranking_matrix
        done = self.banks[: len(self._row0)]
        return {
            "rows": rows,
            "viewframes": self.row_viewframes,
            "bank_rows": np.array([len(b) for b in done], dtype=np.int64),
            "bank_energy_sq": np.array([b._energy_sq for b in done], dtype=np.float64),
        }

    @classmethod
    def from_compact_arrays(
        cls,
        arrays: Mapping[str, ArrayLike],
        *,
        size: int = _DEFAULTS.size,
        bank_size: int = _DEFAULTS.bank_size,
        seed: int = 0,
        key_method: str = _DEFAULTS.key,
        max_shift: int | tuple[int, int] = _DEFAULTS.max_shift,
    ) -> BankedMemory:
        """A compact memory from :meth:`compact_arrays` (with the configuration it was built
        with). ``rows`` is used as given, not copied: a read-only memory map of a stored index
        stays one (its pages are read as a ranking needs them; a later write copies the rows into
        memory first). It ranks exactly as the memory the arrays came from. Raises
        :class:`AssociativeMemoryError` naming what is malformed."""
        mem = cls(size, bank_size=bank_size, seed=seed, key_method=key_method, max_shift=max_shift, compact=True)
        d = 2 * mem.size * (mem.size // 2 + 1)
        try:
            rows = arrays["rows"]
            viewframes = np.asarray(arrays["viewframes"])
            bank_rows = np.asarray(arrays["bank_rows"])
            energy_sq = np.asarray(arrays["bank_energy_sq"])
        except KeyError as err:
            raise AssociativeMemoryError(f"compact memory: no {err.args[0]!r} array") from None
        if not isinstance(rows, np.ndarray) or rows.dtype != np.float32 or rows.ndim != 2 or rows.shape[1] != d:
            what = f"{rows.dtype} {rows.shape}" if isinstance(rows, np.ndarray) else type(rows).__name__
            raise AssociativeMemoryError(f"compact memory: rows must be float32 of shape (H, {d}), got {what}")
        if not rows.flags.c_contiguous:
            raise AssociativeMemoryError("compact memory: rows must be C-contiguous")
        h = rows.shape[0]
        if viewframes.dtype != np.int64 or viewframes.shape != (h,):
            raise AssociativeMemoryError(f"compact memory: viewframes must be int64 of shape ({h},)")
        if bank_rows.dtype != np.int64 or bank_rows.ndim != 1 or energy_sq.shape != bank_rows.shape:
            raise AssociativeMemoryError("compact memory: bank_rows (int64) and bank_energy_sq differ in shape")
        if int(bank_rows.sum()) != h or np.any(bank_rows < 1) or np.any(bank_rows > mem.bank_size):
            raise AssociativeMemoryError(f"compact memory: bank_rows must be in 1..{mem.bank_size} and sum to {h}")
        if energy_sq.dtype != np.float64 or not np.all(np.isfinite(energy_sq)) or np.any(energy_sq < 0):
            raise AssociativeMemoryError("compact memory: bank_energy_sq must be finite float64 >= 0")
        if np.unique(viewframes).size != h:
            raise AssociativeMemoryError("compact memory: duplicate viewframes")
        r0 = 0
        for count, e2 in zip(bank_rows.tolist(), energy_sq.tolist()):
            bank = mem._new_bank()
            bank._spectrum = np.zeros((0, 0), dtype=SPECTRUM_DTYPE)  # finalized: only the rows and energy
            bank._viewframes = viewframes[r0 : r0 + count].copy()
            bank._count = count
            bank._match = rows[r0 : r0 + count]
            bank._energy_sq = float(e2)
            bank.final = True
            mem.banks.append(bank)
            mem._row0.append(r0)
            r0 += count
        mem._rows, mem._nrows = rows, h
        mem._viewframes.update(viewframes.tolist())
        return mem

    def state(self) -> dict[str, Any]:
        """Plain data: the configuration and each bank's :meth:`HolographicMemory.state`."""
        if self.compact:
            raise AssociativeMemoryError("state: a compact memory cannot be saved (its banks keep only their rows)")
        return {
            **_config_state(self),
            "bank_size": self.bank_size,
            "banks": [b.state() for b in self.banks],
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> BankedMemory:
        """Rebuild from :meth:`state`."""
        try:
            size, config = _config_from_state(state)
            mem = cls(size, bank_size=int(state["bank_size"]), **config)
            banks = [HolographicMemory.from_state(b) for b in state["banks"]]
        except (KeyError, TypeError, ValueError) as err:
            raise AssociativeMemoryError(f"memory state: malformed: {err}") from err
        for b in banks:
            if (b.size, b.seed, b.key_method, b.max_shift) != (mem.size, mem.seed, mem.key_method, mem.max_shift):
                raise AssociativeMemoryError("memory state: a bank differs in size, seed, key_method or max_shift")
            mem._viewframes.update(b.viewframes.tolist())
        mem.banks = banks
        if len(mem._viewframes) != len(mem):
            raise AssociativeMemoryError("memory state: duplicate viewframes across banks")
        return mem
