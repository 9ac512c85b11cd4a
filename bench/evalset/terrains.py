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
* :func:`dunes` -- transverse sand dunes across a wind direction: long gentle windward slopes,
  short steep slip faces, sinuous crests of varying height, wind ripples on top.
* :func:`canyon` -- a plateau ending at an escarpment above a lower plain, cut by a meandering
  canyon (and a side canyon) with stepped, cliffed walls and a flat floor.
* :func:`lakes` -- smooth rolling hills whose basins are filled by flat lakes (the lowest
  ``water`` fraction of the ground set to one level).
* :func:`volcano` -- a concave stratovolcano cone with a summit crater and radial gullies
  incised into its flanks, on a gently undulating plain.
* :func:`alpine` -- ridged mountains with a U-shaped glacial valley winding through them, at
  large relief (the valley floor is the gentle ground a road takes).
* :func:`dem_crop` -- a window of a real DEM shipped with matplotlib (``jacksboro`` or
  ``topobathy``), resampled to the requested cells and its heights scaled to keep slopes
  plausible at that cell size (sea floor of ``topobathy`` clipped to a flat sea level).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["fbm", "ridged", "mesas", "valleys", "dunes", "canyon", "lakes", "volcano", "alpine", "dem_crop", "FAMILIES"]


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


def _smoothstep(a: float, b: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _grid(size: int) -> tuple[np.ndarray, np.ndarray]:
    """(row, col) float grids of ``size`` x ``size`` cells."""
    rr, cc = np.mgrid[0:size, 0:size]
    return rr.astype(np.float64), cc.astype(np.float64)


def _meander(size: int, rng: np.random.Generator, *, swing: float = 0.15) -> tuple[np.ndarray, float]:
    """A winding line across the map: points (n, 2) as (col, row) in cells (running a little past
    the border), and the direction of its axis (radians, ccw from +col)."""
    axis = rng.uniform(0.0, 2.0 * math.pi)
    u = np.linspace(-0.15 * size, 1.15 * size, 4 * size)
    a1, a2 = rng.uniform(0.6, 1.0) * swing * size, rng.uniform(0.2, 0.4) * swing * size
    p1, p2 = rng.uniform(0.0, 2.0 * math.pi, 2)
    v = a1 * np.sin(2.0 * math.pi * u / (0.7 * size) + p1) + a2 * np.sin(2.0 * math.pi * u / (0.23 * size) + p2)
    v += rng.uniform(-0.1, 0.1) * size
    du, dv = u - size / 2.0, v
    ca, sa = math.cos(axis), math.sin(axis)
    pts = np.stack([size / 2.0 + ca * du - sa * dv, size / 2.0 + sa * du + ca * dv], 1)
    return pts, axis


def _distance_to(pts: np.ndarray, size: int) -> np.ndarray:
    """Distance in cells from every cell to the polyline ``pts`` ((col, row) points), (size, size)."""
    mask = np.full((size, size), 255, np.uint8)
    cv2.polylines(mask, [np.round(pts * 16).astype(np.int32)], False, 0, 1, cv2.LINE_8, shift=4)
    return cv2.distanceTransform(mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE).astype(np.float64)


def dunes(
    size: int,
    *,
    relief: float,
    rng: np.random.Generator,
    wavelength: float | None = None,
    slip: float = 0.22,
    ripple: float = 0.03,
) -> np.ndarray:
    """Transverse dunes: crests ``wavelength`` cells apart (default size / 7) across a random wind
    direction, a windward slope over ``1 - slip`` of each wave and a steep slip face over ``slip``;
    crests sinuous and of varying height (amplitude 0.1-1 of the tallest), on a gentle swell,
    with wind ripples of ``ripple`` of the relief."""
    lam = float(wavelength) if wavelength is not None else max(6.0, size / 7.0)
    wind = rng.uniform(0.0, 2.0 * math.pi)
    rr, cc = _grid(size)
    along = cc * math.cos(wind) + rr * math.sin(wind)
    warp = 0.8 * lam * _noise(size, size / 2.5, rng) + 0.25 * lam * _noise(size, size / 6.0, rng)
    phase = (along + warp) / lam
    s = phase - np.floor(phase)
    profile = np.where(s < 1.0 - slip, s / (1.0 - slip), (1.0 - s) / slip)
    amp = 0.55 + 0.45 * _noise(size, size / 3.0, rng)
    ripples = 0.5 * (1.0 + np.sin(2.0 * math.pi * (along + 0.3 * warp) / max(2.5, lam / 9.0)))
    swell = fbm(size, hurst=0.95, relief=0.3, rng=rng)
    z = amp * profile + swell + ripple * ripples
    z = cv2.GaussianBlur(z.astype(np.float32), (0, 0), 0.8).astype(np.float64)
    return _normalised(z, relief)


def canyon(
    size: int,
    *,
    relief: float,
    rng: np.random.Generator,
    depth: float = 0.55,
    width: float = 0.08,
    escarpment: float = 0.35,
) -> np.ndarray:
    """A plateau that drops by ``escarpment`` (of its height) at a cliffed escarpment to a lower
    plain, cut by a meandering canyon ``depth`` deep, about ``2 * width * size`` cells across at
    the rim, with a bench half-way down its cliffed walls and a flat floor, and a shallower side
    canyon joining it."""
    rr, cc = _grid(size)
    a = rng.uniform(0.0, 2.0 * math.pi)
    side = ((cc - size / 2.0) * math.cos(a) + (rr - size / 2.0) * math.sin(a)) / size
    side += 0.3 + 0.08 * _noise(size, size / 4.0, rng)
    plateau = 1.0 - escarpment / (1.0 + np.exp(np.clip(side * size / 1.5, -50, 50)))
    pts, _ = _meander(size, rng, swing=0.1)
    halfw = width * size * (1.0 + 0.3 * _noise(size, size / 3.0, rng))
    d = _distance_to(pts, size) / halfw
    carve = depth * (1.0 - 0.5 * _smoothstep(0.30, 0.40, d) - 0.5 * _smoothstep(0.75, 0.85, d))
    i = int(rng.integers(len(pts) // 3, 2 * len(pts) // 3))
    tang = pts[min(i + 1, len(pts) - 1)] - pts[max(i - 1, 0)]
    ang = math.atan2(tang[1], tang[0]) + rng.choice([-1.0, 1.0]) * rng.uniform(0.9, 1.4)
    t = np.linspace(0.0, 0.4 * size, 2 * size)[:, None]
    bend = 0.06 * size * np.sin(2.0 * math.pi * t / (0.3 * size) + rng.uniform(0, 2 * math.pi))
    branch = pts[i] + t * np.array([math.cos(ang), math.sin(ang)]) + bend * np.array([-math.sin(ang), math.cos(ang)])
    db = _distance_to(branch, size) / (0.6 * halfw)
    carve_b = 0.6 * depth * (1.0 - _smoothstep(0.35, 0.8, db))
    z = plateau - np.maximum(carve, carve_b) + fbm(size, hurst=0.6, relief=0.03, rng=rng)
    return _normalised(z, relief)


def lakes(size: int, *, relief: float, rng: np.random.Generator, water: float = 0.2, hurst: float = 1.0) -> np.ndarray:
    """Smooth rolling hills (fBm of Hurst ``hurst``, blurred) whose lowest ``water`` fraction of
    the ground is one flat lake level (height 0: every lake is at the map's lowest height)."""
    z = fbm(size, hurst=hurst, relief=1.0, rng=rng)
    z = cv2.GaussianBlur(z.astype(np.float32), (0, 0), 1.0 + size / 96.0).astype(np.float64)
    z = np.maximum(z, np.quantile(z, water))
    return _normalised(z, relief)


def volcano(
    size: int,
    *,
    relief: float,
    rng: np.random.Generator,
    gullies: int = 18,
    radius: float = 0.42,
    crater: float = 0.06,
) -> np.ndarray:
    """A concave cone of base radius ``radius * size`` (a little irregular) with a summit crater
    of radius ``crater * size``, ``gullies`` radial gullies deepest half-way down its flanks, a
    parasitic cone on one flank, on an undulating plain."""
    rr, cc = _grid(size)
    cx, cy = size * (0.5 + rng.uniform(-0.08, 0.08, 2))
    r = np.hypot(cc - cx, rr - cy) / size
    th = np.arctan2(rr - cy, cc - cx)
    base = radius * (1.0 + 0.1 * _noise(size, size / 4.0, rng))
    t = np.clip(r / base, 0.0, 1.0)
    cone = (1.0 - t) ** 1.8
    pit = 0.14 * np.exp(-((r / crater) ** 4))
    phase = gullies * th + 0.5 * math.pi * _noise(size, size / 5.0, rng)
    groove = (0.5 * (1.0 + np.cos(phase))) ** 6
    incision = 0.07 * np.sin(math.pi * np.clip((t - 0.08) / 0.85, 0.0, 1.0))
    pa = rng.uniform(0.0, 2.0 * math.pi)
    px, py = cx + 0.55 * radius * size * math.cos(pa), cy + 0.55 * radius * size * math.sin(pa)
    parasite = 0.12 * np.clip(1.0 - np.hypot(cc - px, rr - py) / (0.09 * size), 0.0, 1.0) ** 1.5
    plain = fbm(size, hurst=0.8, relief=0.06, rng=rng)
    z = np.minimum(cone, 0.95) - pit - incision * groove + parasite + plain
    return _normalised(z, relief)


def alpine(
    size: int, *, relief: float, rng: np.random.Generator, valley_width: float = 0.08, fall: float = 0.1
) -> np.ndarray:
    """Ridged mountains with a U-shaped glacial valley winding across the map: a flat floor about
    ``valley_width * size`` cells wide whose height falls by ``fall`` of the relief along the
    valley, walls steepening into the mountains."""
    mtn = 0.2 + 0.8 * ridged(size, relief=1.0, rng=rng, base_period=size / 2.2, octaves=6)
    pts, axis = _meander(size, rng, swing=0.1)
    w = valley_width * size * (1.0 + 0.25 * _noise(size, size / 3.0, rng))
    d = _distance_to(pts, size) / w
    rr, cc = _grid(size)
    along = ((cc - size / 2.0) * math.cos(axis) + (rr - size / 2.0) * math.sin(axis)) / size
    floor = 0.08 + fall * (along + 0.5)
    k = np.clip((d - 0.5) / 2.5, 0.0, 1.0) ** 1.5
    z = floor * (1.0 - k) + np.maximum(mtn, floor) * k + fbm(size, hurst=0.7, relief=0.01, rng=rng)
    return _normalised(z, relief)


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
FAMILIES = {
    "fbm": fbm,
    "ridged": ridged,
    "mesas": mesas,
    "valleys": valleys,
    "dunes": dunes,
    "canyon": canyon,
    "lakes": lakes,
    "volcano": volcano,
    "alpine": alpine,
}
