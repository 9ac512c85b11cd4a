"""Contour lines (GeoJSON) turned into a DEM by interpolation.

A contour file is a GeoJSON FeatureCollection of ``LineString`` (or ``MultiLineString``)
features whose coordinates are map (x, y) in metres and whose ``properties.elevation`` is the
height in metres. The DEM follows the grid convention of :mod:`models.terrain`.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
from scipy.interpolate import griddata
from scipy.ndimage import gaussian_filter

from models.errors import InputError
from models.terrain import Terrain

__all__ = ["ContourLine", "load_contours", "contours_to_dem", "dem_to_contours", "save_contours"]

log = logging.getLogger(__name__)

#: one contour: (points ndarray of shape (n, 2) as (x, y) metres, elevation metres)
ContourLine = tuple[np.ndarray, float]


def load_contours(path: str | Path) -> list[ContourLine]:
    """Read a GeoJSON contour file; raises :class:`InputError` naming the file and feature."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(path, "contour file not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(path, f"not valid GeoJSON: {exc}") from None
    features = data.get("features") if isinstance(data, dict) else None
    if not isinstance(features, list) or not features:
        raise InputError(path, "expected a GeoJSON FeatureCollection with at least one feature")
    lines: list[ContourLine] = []
    for i, feat in enumerate(features):
        where = f"features[{i}]"
        try:
            geom = feat["geometry"]
            elevation = float(feat["properties"]["elevation"])
        except (KeyError, TypeError, ValueError):
            raise InputError(path, f"{where}: needs a geometry and a numeric properties.elevation") from None
        if not math.isfinite(elevation):
            raise InputError(path, f"{where}: elevation must be finite")
        kind = geom.get("type") if isinstance(geom, dict) else None
        if kind == "LineString":
            parts = [geom.get("coordinates")]
        elif kind == "MultiLineString":
            parts = geom.get("coordinates") or []
        else:
            raise InputError(path, f"{where}: geometry must be a LineString or MultiLineString, not {kind}")
        for part in parts:
            try:
                pts = np.asarray(part, dtype=np.float64)
            except (TypeError, ValueError):
                raise InputError(path, f"{where}: coordinates must be numbers") from None
            if pts.ndim != 2 or pts.shape[0] < 2 or pts.shape[1] < 2 or not np.all(np.isfinite(pts)):
                raise InputError(path, f"{where}: a line needs at least 2 finite [x, y] points")
            lines.append((pts[:, :2].copy(), elevation))
    return lines


def _densify(points: np.ndarray, step: float) -> np.ndarray:
    """Resample a polyline, ndarray of shape (n, 2), so that no gap exceeds ``step``."""
    out = [points[:1]]
    for a, b in zip(points[:-1], points[1:]):
        n = max(1, int(math.ceil(np.hypot(*(b - a)) / step)))
        t = np.arange(1, n + 1)[:, None] / n
        out.append(a + (b - a) * t)
    return np.concatenate(out)


def contours_to_dem(
    lines: list[ContourLine], *, cell_size: float, shape: tuple[int, int] | None = None, smooth: float = 0.5
) -> Terrain:
    """Interpolate contour lines into a DEM.

    Contour points (densified to half a cell) are triangulated and interpolated linearly
    (``scipy.interpolate.griddata``); cells outside their convex hull take the nearest
    contour's height. A light Gaussian (``smooth`` cells) removes the facets of the
    triangulation. ``shape`` (rows, cols) defaults to the grid covering all lines from (0, 0).
    """
    if not lines:
        raise ValueError("no contour lines")
    if not cell_size > 0:
        raise ValueError(f"cell_size must be > 0, got {cell_size}")
    pts = [_densify(np.asarray(p, dtype=np.float64), cell_size / 2) for p, _ in lines]
    xy = np.concatenate(pts)
    z = np.concatenate([np.full(len(p), e) for p, (_, e) in zip(pts, lines)])
    if xy.min() < -1e-6 * cell_size:
        raise ValueError("contour coordinates must be >= 0 (the DEM grid starts at x = y = 0)")
    if len(np.unique(z)) < 2:
        raise ValueError("need contours at two or more elevations")
    if shape is None:
        shape = (int(math.floor(xy[:, 1].max() / cell_size)) + 1, int(math.floor(xy[:, 0].max() / cell_size)) + 1)
    rows, cols = shape
    gy, gx = np.mgrid[0:rows, 0:cols].astype(np.float64) * cell_size
    dem = griddata(xy, z, (gx, gy), method="linear")
    holes = np.isnan(dem)
    if holes.any():
        dem[holes] = griddata(xy, z, (gx[holes], gy[holes]), method="nearest")
    if smooth > 0:
        dem = gaussian_filter(dem, smooth, mode="nearest")
    log.debug("contours -> DEM %s x %s from %d points", rows, cols, len(xy))
    return Terrain(heights=dem, cell_size=float(cell_size))


def dem_to_contours(terrain: Terrain, *, interval: float) -> list[ContourLine]:
    """Contour lines of a DEM every ``interval`` metres (matplotlib's contour generator)."""
    import contourpy

    h = terrain.heights
    rows, cols = h.shape
    gen = contourpy.contour_generator(
        np.arange(cols) * terrain.cell_size, np.arange(rows) * terrain.cell_size, h, line_type="Separate"
    )
    levels = np.arange(math.ceil(h.min() / interval) * interval, h.max(), interval)
    out: list[ContourLine] = []
    for level in levels:
        for line in gen.lines(level):
            if len(line) >= 2:
                out.append((np.asarray(line, dtype=np.float64), float(level)))
    return out


def save_contours(lines: list[ContourLine], path: str | Path, *, decimals: int = 2) -> None:
    """Write contour lines as a GeoJSON FeatureCollection (``properties.elevation``)."""
    features = [
        {
            "type": "Feature",
            "properties": {"elevation": float(e)},
            "geometry": {"type": "LineString", "coordinates": np.round(p, decimals).tolist()},
        }
        for p, e in lines
    ]
    Path(path).write_text(json.dumps({"type": "FeatureCollection", "features": features}), encoding="utf-8")
