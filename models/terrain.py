"""Terrain: a DEM grid and the ground height F(x, y).

Grid convention (a contract other tools render against): DEM cell (r, c) has its centre at
``x = c * cell_size``, ``y = r * cell_size``; x east, y north, z up, metres. Row 0 is the
southern edge (y = 0), so the array is *not* image-oriented: show it with ``origin="lower"``.
F(x, y) is the bilinear interpolation of the bare DEM, clamped at the border.

Building the terrain a scenario names (a DEM file, contours, ...) is :mod:`models.terrain_sources`.
A georeferenced map (``terrain.dem`` a GeoTIFF or other GDAL raster, or contours with a CRS)
carries a :class:`~models.georef.MapFrame` in :attr:`Terrain.frame` that ties these local
metres to its CRS; the grid is made from the raster by :mod:`models.georaster`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from models.georef import MapFrame

__all__ = ["Terrain", "procedural_terrain", "sample_terrain"]


@dataclass(frozen=True, eq=False)
class Terrain:
    """A DEM: ``heights`` ndarray of shape (rows, cols), float64 metres; ``cell_size`` metres.

    ``frame`` places the local metres on the Earth for a georeferenced map, else None.
    """

    heights: np.ndarray
    cell_size: float
    frame: MapFrame | None = None

    def __post_init__(self) -> None:
        h = np.asarray(self.heights, dtype=np.float64)
        if h.ndim != 2 or min(h.shape) < 2:
            raise ValueError(f"heights must be a 2-D array of at least 2x2 cells, got shape {h.shape}")
        if not np.all(np.isfinite(h)):
            raise ValueError("heights must be finite everywhere")
        if not self.cell_size > 0:
            raise ValueError(f"cell_size must be > 0, got {self.cell_size}")
        h.setflags(write=False)
        object.__setattr__(self, "heights", h)

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of the grid."""
        rows, cols = self.heights.shape
        return int(rows), int(cols)

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) in metres: the cell centres at the borders."""
        rows, cols = self.heights.shape
        return 0.0, (cols - 1) * self.cell_size, 0.0, (rows - 1) * self.cell_size

    def contains(self, x: float, y: float) -> bool:
        """True when (x, y) lies inside :attr:`extent`."""
        x0, x1, y0, y1 = self.extent
        return bool(x0 <= x <= x1 and y0 <= y <= y1)

    def height_at(self, x: float | np.ndarray, y: float | np.ndarray) -> float | np.ndarray:
        """Bilinear ground height F(x, y) in metres; vectorised over broadcastable x, y.

        Points outside the grid take the height at the nearest border point.
        """
        scalar = np.ndim(x) == 0 and np.ndim(y) == 0
        rows, cols = self.heights.shape
        u = np.clip(np.asarray(x, dtype=np.float64) / self.cell_size, 0.0, cols - 1.0)
        v = np.clip(np.asarray(y, dtype=np.float64) / self.cell_size, 0.0, rows - 1.0)
        c0 = np.minimum(np.floor(u).astype(np.intp), cols - 2)
        r0 = np.minimum(np.floor(v).astype(np.intp), rows - 2)
        fu, fv = u - c0, v - r0
        h = self.heights
        z = (
            h[r0, c0] * (1 - fu) * (1 - fv)
            + h[r0, c0 + 1] * fu * (1 - fv)
            + h[r0 + 1, c0] * (1 - fu) * fv
            + h[r0 + 1, c0 + 1] * fu * fv
        )
        return float(z) if scalar else z

    def hillshade(self, *, azimuth_deg: float = 315.0, altitude_deg: float = 45.0) -> np.ndarray:
        """Lambertian shading in [0, 1], ndarray of shape (rows, cols) (row 0 = south)."""
        dzdy, dzdx = np.gradient(self.heights, self.cell_size)
        az, alt = np.radians(azimuth_deg), np.radians(altitude_deg)
        light = np.array([np.sin(az) * np.cos(alt), np.cos(az) * np.cos(alt), np.sin(alt)])
        n = np.stack([-dzdx, -dzdy, np.ones_like(dzdx)])
        n /= np.linalg.norm(n, axis=0)
        return np.clip(np.tensordot(light, n, axes=1), 0.0, 1.0)


def procedural_terrain(
    *, size: int, relief: float, cell_size: float, rng: np.random.Generator | int | None = None
) -> Terrain:
    """Hills and valleys: fractal (1/f^beta) noise of ``size`` x ``size`` cells.

    Heights span [0, relief] metres. The spectrum falls off steeply (beta = 3.2) with a
    low-frequency emphasis, which gives rounded hills separated by valleys rather than spiky
    noise; a faint second octave adds small bumps.
    """
    if size < 8:
        raise ValueError(f"size must be >= 8, got {size}")
    if not relief > 0:
        raise ValueError(f"relief must be > 0, got {relief}")
    rng = np.random.default_rng(rng)
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.rfftfreq(size)[None, :]
    f = np.hypot(fx, fy)
    f[0, 0] = 1.0
    amplitude = f ** (-3.2 / 2.0)
    amplitude[f < 1.5 / size] *= 0.35  # damp the very longest waves: keep several hills in view
    amplitude *= np.exp(-((f * size / 24.0) ** 2))  # no bumps smaller than ~1/24 of the map
    amplitude[0, 0] = 0.0
    phase = rng.uniform(0, 2 * np.pi, amplitude.shape)
    spectrum = amplitude * np.exp(1j * phase)
    z = np.fft.irfft2(spectrum, s=(size, size))
    z = (z - z.min()) / (np.ptp(z) or 1.0)
    z = z**1.3  # broader valley floors, sharper crests
    return Terrain(heights=z * relief, cell_size=float(cell_size))


def sample_terrain(name: str, *, cell_size: float) -> Terrain:
    """A real DEM shipped with matplotlib; ``jacksboro`` is 344 x 403 cells, 236..1076 m.

    The file stores the northern row first; it is flipped so that row 0 is the south (y = 0).
    Its cells are 3 arc-seconds (about 75 m east-west, 93 m north-south): ``cell_size`` sets
    the square cell this project uses.
    """
    if name != "jacksboro":
        raise ValueError(f"unknown sample DEM {name!r}")
    from matplotlib import cbook

    sample: Any = cbook.get_sample_data("jacksboro_fault_dem.npz")  # an NpzFile
    with sample as dem:
        heights = np.asarray(dem["elevation"], dtype=np.float64)[::-1].copy()
    return Terrain(heights=heights, cell_size=float(cell_size))
