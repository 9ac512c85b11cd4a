"""Terrains of the evaluation set: other statistics than :func:`models.terrain.procedural_terrain`.

Every generator returns a height grid, ndarray of shape (rows, cols) float64 metres, in the grid
convention of :mod:`models.terrain` (cell (r, c) at x = c * cell, y = r * cell, row 0 south).
All randomness comes from the ``rng`` argument.

* :func:`fbm` -- spectral fractional Brownian surface of Hurst exponent ``hurst`` (amplitude
  ~ f^-(H+1)), no low-pass: rougher (H 0.4) or smoother (H 0.8) than the models' hills, which
  have a fixed spectral slope and a cut-off at 1/24 of the map.
* :func:`ridged` -- Musgrave's ridged multifractal: sharp crests, smooth valleys.
* :func:`mesas` -- an fBm terraced into flat plateaus with steep scarps.
* :func:`valleys` -- gentle fBm with river valleys carved along the zero lines of a second
  field (V/U-shaped, branching).
* :func:`dem_crop` -- a window of a real DEM shipped with matplotlib (``jacksboro`` or
  ``topobathy``), resampled to the requested cells and its heights scaled to keep slopes
  plausible at that cell size (sea floor of ``topobathy`` clipped to a flat sea level).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["fbm", "ridged", "mesas", "valleys", "dem_crop", "FAMILIES"]


def _normalised(z: np.ndarray, relief: float) -> np.ndarray:
    z = z - z.min()
    return z / (np.ptp(z) or 1.0) * relief


def fbm(size: int, *, hurst: float = 0.7, relief: float, rng: np.random.Generator) -> np.ndarray:
    """Spectral fBm of ``size`` x ``size`` cells spanning [0, relief] metres."""
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.rfftfreq(size)[None, :]
    f = np.hypot(fx, fy)
    f[0, 0] = 1.0
    amp = f ** (-(hurst + 1.0))
    amp[0, 0] = 0.0
    spec = amp * np.exp(1j * rng.uniform(0, 2 * np.pi, amp.shape)) * rng.rayleigh(1.0, amp.shape)
    return _normalised(np.fft.irfft2(spec, s=(size, size)), relief)


def _noise(size: int, period: float, rng: np.random.Generator) -> np.ndarray:
    """Smooth value noise in [-1, 1] with features about ``period`` cells apart."""
    n = max(2, int(math.ceil(size / period)) + 2)
    grid = rng.uniform(-1.0, 1.0, (n, n)).astype(np.float32)
    big = cv2.resize(grid, (int(n * period), int(n * period)), interpolation=cv2.INTER_CUBIC)
    off = rng.integers(0, max(1, big.shape[0] - size), 2)
    return np.clip(big[off[0] : off[0] + size, off[1] : off[1] + size].astype(np.float64), -1, 1)


def ridged(
    size: int,
    *,
    relief: float,
    rng: np.random.Generator,
    base_period: float = 96.0,
    octaves: int = 5,
    gain: float = 2.0,
    offset: float = 1.0,
) -> np.ndarray:
    """Ridged multifractal (Musgrave): sum of ``(offset - |noise|)**2`` octaves, each weighted
    by the previous one's signal, so crests are sharp and valleys smooth."""
    z = np.zeros((size, size))
    weight = np.ones((size, size))
    period = base_period
    for o in range(octaves):
        signal = (offset - np.abs(_noise(size, period, rng))) ** 2 * weight
        z += signal * 0.5**o
        weight = np.clip(signal * gain, 0.0, 1.0)
        period /= 2.0
        if period < 2.0:
            break
    return _normalised(z, relief)


def mesas(size: int, *, relief: float, rng: np.random.Generator, steps: int = 4, sharpness: float = 10.0) -> np.ndarray:
    """An fBm (H 0.7) terraced into ``steps`` plateaus joined by steep scarps."""
    z = fbm(size, hurst=0.9, relief=1.0, rng=rng)
    z = cv2.GaussianBlur(z.astype(np.float32), (0, 0), 2.0).astype(np.float64)
    z = (z - z.min()) / (np.ptp(z) or 1.0) * steps
    level = np.floor(z)
    frac = z - level
    rise = 1.0 / (1.0 + np.exp(-sharpness * (frac - 0.5)))
    out = level + rise + 0.04 * fbm(size, hurst=0.5, relief=1.0, rng=rng)
    return _normalised(out, relief)


def valleys(size: int, *, relief: float, rng: np.random.Generator, width: float = 0.12) -> np.ndarray:
    """Gentle fBm (H 0.9) with valleys carved along the zero lines of a smooth field."""
    base = fbm(size, hurst=0.9, relief=1.0, rng=rng)
    field = _noise(size, size / 3.0, rng) + 0.35 * _noise(size, size / 8.0, rng)
    carve = np.exp(-((np.abs(field) / width) ** 1.5))
    return _normalised(base * 0.6 + 0.4 * (1.0 - carve), relief)


def _sample_dem(name: str) -> np.ndarray:
    from matplotlib import cbook

    if name == "jacksboro":
        with cbook.get_sample_data("jacksboro_fault_dem.npz") as dem:
            return np.asarray(dem["elevation"], dtype=np.float64)[::-1].copy()
    if name == "topobathy":
        with cbook.get_sample_data("topobathy.npz") as dem:
            return np.asarray(dem["topo"], dtype=np.float64)[::-1].copy()
    raise ValueError(f"unknown sample DEM {name!r}")


def dem_crop(
    name: str,
    *,
    rows: tuple[int, int],
    cols: tuple[int, int],
    upsample: int,
    height_scale: float,
    sea_level: float | None = None,
) -> np.ndarray:
    """Window ``rows`` x ``cols`` (half-open, source cells, row 0 south) of a sample DEM,
    upsampled ``upsample`` times (bicubic), heights times ``height_scale``; heights below
    ``sea_level`` (source metres) are set to it (a flat sea)."""
    src = _sample_dem(name)[rows[0] : rows[1], cols[0] : cols[1]]
    if sea_level is not None:
        src = np.maximum(src, sea_level)
    if upsample > 1:
        h, w = src.shape
        src = cv2.resize(src.astype(np.float32), (w * upsample, h * upsample), interpolation=cv2.INTER_CUBIC)
        if sea_level is not None:
            src = np.maximum(src, sea_level)
    out = (np.asarray(src, np.float64) - float(np.min(src))) * height_scale
    return out


#: the procedural families by name: ``fn(size, relief=, rng=, **params)``
FAMILIES = {"fbm": fbm, "ridged": ridged, "mesas": mesas, "valleys": valleys}
