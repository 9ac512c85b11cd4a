"""K-GEN: the noise-like key of a pattern.

Construction (``method="phase"``, the default)
----------------------------------------------
For a pattern P of shape (N, N) with spectrum F = rfft2(P)::

    FK(k) = exp(i * (angle F(k) + theta(k)))      (unit magnitude, DC set to 0)
    K     = irfft2(FK) / ||.||                    (unit energy)

``theta`` is the phase spectrum of a seeded white-noise image (so K is real). The map is
nonlinear (the magnitude of F is thrown away: spectral whitening), which is what the memory
needs. Its properties, all tested:

* **zero mean** (DC is 0) and **unit energy**; the spectrum is flat, so K is white noise-like
  and ``K (x) K`` (circular autocorrelation) is a delta of height 1.
* **cross-correlation of keys of different patterns** is the *phase-only correlation* of the
  patterns, ``irfft2(exp(i (angle F_P - angle F_Q)))``: noise-like (every value about 1/N)
  for unrelated patterns, a sharp peak for similar ones. ``theta`` cancels there; it only makes
  the key itself look like noise (and gives different banks different keys).
* **shift-equivariance, not shift-invariance**: a circular shift of P by d shifts K by d
  exactly (a shift is a linear phase ramp, which the phase keeps). Keys of shifted patterns
  are therefore *not* close at zero lag, but their cross-correlation has its full peak at d;
  in the memory this recalls the stored prototype shifted by d, and the blur of the
  preprocessing makes a shift of a few pixels cost little in the error variance. This is the
  trade-off chosen: a shift-*invariant* key (built from |F| only) is symmetric and its
  cross-correlations are not noise-like (huge crosstalk), a zero-lag-close key cannot be
  noise-like under shifts. Non-circular shifts of real images (content entering the frame)
  lower the peak in proportion to the content lost.

``method="quantized"``: the phase of F is quantised to 4 levels before adding ``theta`` (a
phase hash). Exact recall of identical patterns, but small phase changes of a perturbed input
jump between levels, so it is less robust; kept for the capacity and robustness benchmark.

A linear key (a fixed all-pass filter, ``FK = F * exp(i theta)``) is deliberately not
offered: ``K(Q) (x) K(P)`` then reduces to ``Q (x) P``, the images' own cross-correlation,
which is not noise-like.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from models.scenario import MemorySpec

__all__ = ["KEY_METHODS", "make_key", "key_spectrum", "key_phase", "seeded_key"]

#: accepted values of ``method``
KEY_METHODS: tuple[str, ...] = ("phase", "quantized")

_QUANT_LEVELS = 4
#: the default method: the scenario schema's ``memory.key``
_METHOD = MemorySpec().key


@lru_cache(maxsize=32)
def _random_phase(n: int, seed: int) -> NDArray[np.complex128]:
    """exp(i theta) of shape (n, n // 2 + 1): the phase spectrum of seeded white noise."""
    rng = np.random.default_rng(np.random.SeedSequence([0x4B47454E, seed]))
    f = np.fft.rfft2(rng.standard_normal((n, n)))
    mag = np.abs(f)
    mag[mag == 0] = 1.0
    out = f / mag
    out.setflags(write=False)
    return out


def _check(pattern: ArrayLike, seed: int, method: str) -> NDArray[np.float64]:
    p = np.asarray(pattern, dtype=np.float64)
    if p.ndim != 2 or p.shape[0] != p.shape[1] or p.shape[0] < 2:
        raise ValueError(f"pattern must be a square array of shape (N, N), got shape {p.shape}")
    if method not in KEY_METHODS:
        raise ValueError(f"method must be one of {', '.join(KEY_METHODS)}, got {method!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    return p


def key_phase(pattern: ArrayLike, *, method: str = _METHOD) -> NDArray[np.complex128] | None:
    """The part of :func:`key_spectrum` that does not depend on the seed: the unit phase spectrum
    of the pattern (quantised with ``method="quantized"``), shape (N, N // 2 + 1); None for an
    all-zero pattern. ``seeded_key(key_phase(p, method=m), seed=s)`` is ``key_spectrum(p, seed=s,
    method=m)``, the same numbers: one pattern's phase serves memories of every seed."""
    p = _check(pattern, 0, method)
    f = np.fft.rfft2(p)
    mag = np.abs(f)
    if not np.any(mag > 0):
        return None
    tiny = mag <= 1e-12 * mag.max()
    phase = np.where(tiny, 1.0, f / np.where(tiny, 1.0, mag))
    if method == "quantized":
        step = 2 * np.pi / _QUANT_LEVELS
        phase = np.exp(1j * step * np.round(np.angle(phase) / step))
    return phase


def seeded_key(phase: NDArray[np.complexfloating], *, seed: int = 0) -> NDArray[np.complex128]:
    """:func:`key_spectrum` from the pattern's :func:`key_phase` (N, N // 2 + 1) and the seed."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    n = phase.shape[0]
    fk = phase * _random_phase(n, int(seed))
    # keep the spectrum of a real image: bins that are their own mirror must be real
    self_mirror_rows = [0] + ([n // 2] if n % 2 == 0 else [])
    self_mirror_cols = [0] + ([n // 2] if n % 2 == 0 else [])
    for r in self_mirror_rows:
        for c in self_mirror_cols:
            fk[r, c] = np.sign(fk[r, c].real) or 1.0
    fk[0, 0] = 0.0
    return fk * (n / np.sqrt(n * n - 1.0))


def key_spectrum(pattern: ArrayLike, *, seed: int = 0, method: str = _METHOD) -> NDArray[np.complex128]:
    """The key's spectrum ``rfft2(make_key(pattern))``, of shape (N, N // 2 + 1).

    Magnitude ``N / sqrt(N*N - 1)`` on every bin but DC (0), so that the key has unit energy and
    ``conj(FK) * FK`` recalls a zero-mean pattern with gain ``N*N / (N*N - 1)``. Bins where the
    pattern's spectrum vanishes get the random phase alone; an all-zero pattern gives a zero key.
    (:func:`key_phase` then :func:`seeded_key`.)
    """
    p = _check(pattern, seed, method)
    phase = key_phase(p, method=method)
    if phase is None:
        return np.zeros((p.shape[0], p.shape[1] // 2 + 1), dtype=np.complex128)
    return seeded_key(phase, seed=seed)


def make_key(pattern: ArrayLike, *, seed: int = 0, method: str = _METHOD) -> NDArray[np.float32]:
    """K-GEN: the noise-like key of a pattern (see the module docstring for the construction).

    Parameters
    ----------
    pattern : array of shape (N, N)
        Usually a preprocessed image (:func:`models.preprocess.preprocess`).
    seed : int
        Seed of the random phase; memories that must recall each other's keys share it.
    method : str
        One of :data:`KEY_METHODS`.

    Returns
    -------
    ndarray of shape (N, N), float32, zero mean and unit energy (all zeros for a zero pattern).
    """
    fk = key_spectrum(pattern, seed=seed, method=method)
    n = fk.shape[0]
    return np.fft.irfft2(fk, s=(n, n)).astype(np.float32)
