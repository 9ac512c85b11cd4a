"""Contour lines (GeoJSON, Shapefile, GeoPackage, any vector OGR reads) turned into a DEM.

A contour file holds ``LineString`` (or ``MultiLineString``) features with a numeric height
attribute in metres (``elevation`` unless the scenario's ``terrain.elevation_attribute`` names
another). The DEM follows the grid convention of :mod:`models.terrain`.

* A file with a CRS (a Shapefile's ``.prj``, a GeoPackage's SRS, a GeoJSON ``crs`` member) is
  georeferenced: its lines are projected into the working CRS of :func:`models.georef.working_crs`
  and the local origin (0, 0) is the south-west corner of their extent; the map frame is returned.
* A file without a CRS, and a GeoJSON without a ``crs`` member, holds local metres (x, y >= 0)
  as before.

Vector files are read with pyogrio; plain GeoJSON without a CRS is parsed directly.
"""

from __future__ import annotations

import json
import logging
import math
import struct
from pathlib import Path

import numpy as np
from scipy.interpolate import griddata
from scipy.ndimage import gaussian_filter

from models.errors import InputError
from models.georef import MapFrame, parse_crs, working_crs
from models.terrain import Terrain

__all__ = ["ContourLine", "read_contours", "load_contours", "contours_to_dem", "dem_to_contours", "save_contours"]

log = logging.getLogger(__name__)

#: one contour: (points ndarray of shape (n, 2) as (x, y) metres, elevation metres)
ContourLine = tuple[np.ndarray, float]


def _plain_geojson(path: Path) -> dict | None:
    """The parsed file when it is GeoJSON without a ``crs`` member (local metres), else None."""
    if path.suffix.lower() not in (".geojson", ".json"):
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(path, f"not valid GeoJSON: {exc}") from None
    return None if isinstance(data, dict) and "crs" in data else data


def _geojson_lines(path: Path, data: object, attribute: str) -> list[ContourLine]:
    features = data.get("features") if isinstance(data, dict) else None
    if not isinstance(features, list) or not features:
        raise InputError(path, "expected a GeoJSON FeatureCollection with at least one feature")
    lines: list[ContourLine] = []
    for i, feat in enumerate(features):
        where = f"features[{i}]"
        try:
            geom = feat["geometry"]
            elevation = float(feat["properties"][attribute])
        except (KeyError, TypeError, ValueError):
            raise InputError(path, f"{where}: needs a geometry and a numeric properties.{attribute}") from None
        kind = geom.get("type") if isinstance(geom, dict) else None
        if kind == "LineString":
            parts = [geom.get("coordinates")]
        elif kind == "MultiLineString":
            parts = geom.get("coordinates") or []
        else:
            raise InputError(path, f"{where}: geometry must be a LineString or MultiLineString, not {kind}")
        lines.extend(_checked(path, where, parts, elevation))
    return lines


def _checked(path: Path, where: str, parts: list, elevation: float) -> list[ContourLine]:
    if not math.isfinite(elevation):
        raise InputError(path, f"{where}: elevation must be finite")
    out = []
    for part in parts:
        try:
            pts = np.asarray(part, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(path, f"{where}: coordinates must be numbers") from None
        if pts.ndim != 2 or pts.shape[0] < 2 or pts.shape[1] < 2 or not np.all(np.isfinite(pts)):
            raise InputError(path, f"{where}: a line needs at least 2 finite [x, y] points")
        out.append((pts[:, :2].copy(), elevation))
    return out


def _wkb_lines(blob: bytes) -> tuple[str, list[np.ndarray]]:
    """(geometry type, parts) of a 2-D WKB LineString or MultiLineString."""
    order = "<" if blob[0] == 1 else ">"
    kind = struct.unpack_from(order + "I", blob, 1)[0] % 1000
    if kind == 2:
        n = struct.unpack_from(order + "I", blob, 5)[0]
        return "LineString", [np.frombuffer(blob, dtype=order + "f8", count=2 * n, offset=9).reshape(n, 2)]
    if kind == 5:
        count, off, parts = struct.unpack_from(order + "I", blob, 5)[0], 9, []
        for _ in range(count):
            sub = "<" if blob[off] == 1 else ">"
            n = struct.unpack_from(sub + "I", blob, off + 5)[0]
            parts.append(np.frombuffer(blob, dtype=sub + "f8", count=2 * n, offset=off + 9).reshape(n, 2))
            off += 9 + 16 * n
        return "MultiLineString", parts
    names = {1: "Point", 3: "Polygon", 4: "MultiPoint", 6: "MultiPolygon", 7: "GeometryCollection"}
    return names.get(kind, f"WKB type {kind}"), []


def _ogr_lines(path: Path, attribute: str) -> tuple[list[ContourLine], str | None]:
    import pyogrio
    from pyogrio.errors import DataLayerError, DataSourceError, FieldError, GeometryError

    try:
        meta, _, geometry, field_data = pyogrio.raw.read(path, force_2d=True)
    except (DataSourceError, DataLayerError, FieldError, GeometryError, OSError) as exc:
        raise InputError(path, f"cannot read contour lines (OGR): {exc}") from None
    fields = list(meta.get("fields", []))
    if attribute not in fields:
        known = ", ".join(map(str, fields)) or "none"
        raise InputError(
            path,
            f"no attribute {attribute!r} with the contour heights (terrain.elevation_attribute); the file has: {known}",
        )
    values = field_data[fields.index(attribute)]
    if geometry is None or len(geometry) == 0:
        raise InputError(path, "no contour line features")
    lines: list[ContourLine] = []
    for i, (blob, value) in enumerate(zip(geometry, values)):
        where = f"feature {i}"
        try:
            elevation = float(value)
        except (TypeError, ValueError):
            raise InputError(path, f"{where}: {attribute} must be a number, not {value!r}") from None
        if blob is None:
            raise InputError(path, f"{where}: has no geometry")
        kind, parts = _wkb_lines(bytes(blob))
        if not parts:
            raise InputError(path, f"{where}: geometry must be a LineString or MultiLineString, not {kind}")
        lines.extend(_checked(path, where, parts, elevation))
    return lines, meta.get("crs")


def read_contours(path: str | Path, *, attribute: str = "elevation") -> tuple[list[ContourLine], MapFrame | None]:
    """Contour lines in local metres and, for a file with a CRS, their map frame.

    ``attribute`` names the height field. Raises :class:`InputError` naming the file and feature.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(path, "contour file not found")
    plain = _plain_geojson(path)
    if plain is not None:
        return _geojson_lines(path, plain, attribute), None
    lines, crs_text = _ogr_lines(path, attribute)
    if not crs_text:
        return lines, None
    from pyproj import Transformer

    crs = parse_crs(crs_text)
    xy = np.concatenate([p for p, _ in lines])
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    lon, lat = Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(*((lo + hi) / 2))
    work = working_crs(crs, lon=float(lon), lat=float(lat))
    fwd = Transformer.from_crs(crs, work, always_xy=True)
    projected = [(np.column_stack(fwd.transform(p[:, 0], p[:, 1])), e) for p, e in lines]
    origin = np.concatenate([p for p, _ in projected]).min(axis=0)
    if not np.all(np.isfinite(origin)):
        raise InputError(path, f"contour coordinates cannot be projected from {crs_text}")
    frame = MapFrame(crs, work, (float(origin[0]), float(origin[1])))
    return [(p - origin, e) for p, e in projected], frame


def load_contours(path: str | Path, *, attribute: str = "elevation") -> list[ContourLine]:
    """Contour lines in local metres (see :func:`read_contours`, which also gives the map frame)."""
    return read_contours(path, attribute=attribute)[0]


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
