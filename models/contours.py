"""Contour lines (GeoJSON, Shapefile, GeoPackage, any vector OGR reads) turned into a DEM.

A contour file holds ``LineString`` (or ``MultiLineString``) features with a numeric height
attribute in metres: the one the scenario's ``terrain.elevation_attribute`` names, else the
first of :data:`ELEVATION_NAMES` (``elevation``, ``elev``, ``ELEVATION``, ``contour``, ``height``,
``z`` ...: any case) the file has, else the lines' own z coordinates (3-D lines, one level
each). ``terrain.z_scale`` converts other units. The DEM follows the grid convention of
:mod:`models.terrain`.

* A file with a CRS (a Shapefile's ``.prj``, a GeoPackage's SRS, a GeoJSON ``crs`` member) is
  georeferenced: its lines are projected into the working CRS of :func:`models.georef.working_crs`
  and the local origin (0, 0) is the south-west corner of their extent; the map frame is returned.
* A file without a CRS, and a GeoJSON without a ``crs`` member, holds local metres (x, y >= 0)
  as before; but a GeoJSON without a ``crs`` member whose coordinates all lie within lon/lat
  bounds and span less than :data:`LONLAT_MAX_SPAN` is lon/lat degrees (RFC 7946 GeoJSON, as
  many tools write it), with a warning.

Vector files are read with pyogrio; plain GeoJSON without a CRS is parsed directly.
"""

from __future__ import annotations

import json
import logging
import math
import struct
from pathlib import Path

import numpy as np
from scipy import sparse
from scipy.interpolate import griddata
from scipy.ndimage import gaussian_filter, map_coordinates
from scipy.sparse.linalg import cg, spsolve

from models.errors import InputError
from models.georef import MapFrame, parse_crs, working_crs
from models.terrain import Terrain

__all__ = [
    "ContourLine",
    "ELEVATION_NAMES",
    "read_contours",
    "load_contours",
    "contours_to_dem",
    "contours_to_tin",
    "dem_to_contours",
    "save_contours",
]

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


#: height attribute names tried, in this order and in any case, when the scenario names none
ELEVATION_NAMES = ("elevation", "elev", "ele", "height", "z", "contour", "level", "alt", "altitude")


def _pick_attribute(path: Path, fields: list[str], attribute: str | None) -> str | None:
    """The height attribute among ``fields``: ``attribute`` (exactly, else in another case),
    or by default the first of :data:`ELEVATION_NAMES` there; None: none (the lines' z then)."""
    by_lower: dict[str, list[str]] = {}
    for f in fields:
        by_lower.setdefault(f.lower(), []).append(f)
    if attribute is not None:
        if attribute in fields:
            return attribute
        near = by_lower.get(attribute.lower(), [])
        if len(near) == 1:
            return near[0]
        known = ", ".join(map(str, fields)) or "none"
        raise InputError(
            path,
            f"no attribute {attribute!r} with the contour heights (terrain.elevation_attribute); the file has: {known}",
        )
    for name in ELEVATION_NAMES:
        found = by_lower.get(name, [])
        if found:
            if found[0] != "elevation":
                log.info("%s: contour heights from the attribute %r", path, found[0])
            return found[0]
    return None


def _no_heights(path: Path, fields: list[str]) -> InputError:
    known = ", ".join(map(str, fields)) or "none"
    return InputError(
        path,
        "no contour heights: no attribute named like an elevation (" + ", ".join(ELEVATION_NAMES[:6]) + ", ...) "
        f"and no z coordinates; name it with terrain.elevation_attribute (the file has: {known})",
    )


def _line_z(path: Path, where: str, parts: list[np.ndarray]) -> float:
    """The height of a 3-D contour line: its points' z, which must be one level."""
    z = np.concatenate([np.asarray(p, dtype=np.float64)[:, 2] for p in parts])
    if not np.all(np.isfinite(z)):
        raise InputError(path, f"{where}: z coordinates must be finite")
    lo, hi = float(z.min()), float(z.max())
    if hi - lo > 1e-3 * max(1.0, abs(hi)):
        raise InputError(
            path,
            f"{where}: its z varies along the line ({lo:g}..{hi:g}): not a contour line; "
            "name the height attribute with terrain.elevation_attribute",
        )
    return float(np.median(z))


def _geojson_lines(path: Path, data: object, attribute: str | None) -> list[ContourLine]:
    features = data.get("features") if isinstance(data, dict) else None
    if not isinstance(features, list) or not features:
        raise InputError(path, "expected a GeoJSON FeatureCollection with at least one feature")
    first = features[0].get("properties") if isinstance(features[0], dict) else None
    fields = list(first) if isinstance(first, dict) else []
    name = _pick_attribute(path, fields, attribute) if fields or attribute else None
    lines: list[ContourLine] = []
    for i, feat in enumerate(features):
        where = f"features[{i}]"
        geom = feat.get("geometry") if isinstance(feat, dict) else None
        kind = geom.get("type") if isinstance(geom, dict) else None
        if kind == "LineString" and isinstance(geom, dict):
            parts = [geom.get("coordinates")]
        elif kind == "MultiLineString" and isinstance(geom, dict):
            parts = geom.get("coordinates") or []
        elif geom is None:
            raise InputError(path, f"{where}: has no geometry")
        else:
            raise InputError(path, f"{where}: geometry must be a LineString or MultiLineString, not {kind}")
        if name is not None:
            props = feat.get("properties") if isinstance(feat, dict) else None
            value = props.get(name) if isinstance(props, dict) else None
            try:
                elevation = float(value)  # type: ignore[arg-type]
            except (TypeError, ValueError):
                raise InputError(path, f"{where}: needs a numeric properties.{name}, not {value!r}") from None
        else:
            try:
                arrays = [np.asarray(p, dtype=np.float64) for p in parts]
            except (TypeError, ValueError):
                raise InputError(path, f"{where}: coordinates must be numbers") from None
            if not arrays or any(a.ndim != 2 or a.shape[1] < 3 for a in arrays):
                raise _no_heights(path, fields)
            elevation = _line_z(path, where, arrays)
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
        if pts.ndim != 2 or pts.shape[0] < 2 or pts.shape[1] < 2 or not np.all(np.isfinite(pts[:, :2])):
            raise InputError(path, f"{where}: a line needs at least 2 finite [x, y] points")
        out.append((pts[:, :2].copy(), elevation))
    return out


def _wkb_lines(blob: bytes) -> tuple[str, list[np.ndarray]]:
    """(geometry type, parts) of a WKB (ISO or extended) LineString or MultiLineString; each
    part ndarray of shape (n, 2), or (n, 3) with z when the geometry has z."""
    order = "<" if blob[0] == 1 else ">"
    code = struct.unpack_from(order + "I", blob, 1)[0]
    off = 5
    if code & 0x20000000:  # EWKB with an SRID
        off += 4
    has_z = bool(code & 0x80000000) or (code & 0xFFFF) // 1000 in (1, 3)
    has_m = bool(code & 0x40000000) or (code & 0xFFFF) // 1000 in (2, 3)
    kind = (code & 0xFFFF) % 1000
    dims = 2 + has_z + has_m

    def line(at: int, o: str) -> tuple[np.ndarray, int]:
        n = struct.unpack_from(o + "I", blob, at)[0]
        pts = np.frombuffer(blob, dtype=o + "f8", count=dims * n, offset=at + 4).reshape(n, dims)
        return (pts[:, :3] if has_z else pts[:, :2]), at + 4 + 8 * dims * n

    if kind == 2:
        return "LineString", [line(off, order)[0]]
    if kind == 5:
        count, parts = struct.unpack_from(order + "I", blob, off)[0], []
        at = off + 4
        for _ in range(count):
            sub = "<" if blob[at] == 1 else ">"
            sub_code = struct.unpack_from(sub + "I", blob, at + 1)[0]
            pts, at = line(at + 5 + (4 if sub_code & 0x20000000 else 0), sub)
            parts.append(pts)
        return "MultiLineString", parts
    names = {1: "Point", 3: "Polygon", 4: "MultiPoint", 6: "MultiPolygon", 7: "GeometryCollection"}
    return names.get(kind, f"WKB type {kind}"), []


def _ogr_lines(path: Path, attribute: str | None) -> tuple[list[ContourLine], str | None]:
    import pyogrio
    from pyogrio.errors import DataLayerError, DataSourceError, FieldError, GeometryError

    try:
        meta, _, geometry, field_data = pyogrio.raw.read(path)
    except (DataSourceError, DataLayerError, FieldError, GeometryError, OSError) as exc:
        raise InputError(path, f"cannot read contour lines (OGR): {exc}") from None
    fields = [str(f) for f in meta.get("fields", [])]
    name = _pick_attribute(path, fields, attribute)
    values = field_data[fields.index(name)] if name is not None else None
    if geometry is None or len(geometry) == 0:
        raise InputError(path, "no contour line features")
    lines: list[ContourLine] = []
    for i, blob in enumerate(geometry):
        where = f"feature {i}"
        if blob is None:
            raise InputError(path, f"{where}: has no geometry")
        try:
            kind, parts = _wkb_lines(bytes(blob))
        except (struct.error, ValueError, IndexError):
            raise InputError(path, f"{where}: its geometry cannot be decoded") from None
        if not parts:
            raise InputError(path, f"{where}: geometry must be a LineString or MultiLineString, not {kind}")
        if values is not None:
            value = values[i]
            try:
                elevation = float(value)
            except (TypeError, ValueError):
                raise InputError(path, f"{where}: {name} must be a number, not {value!r}") from None
        elif all(p.shape[1] == 3 for p in parts):
            elevation = _line_z(path, where, parts)
        else:
            raise _no_heights(path, fields)
        lines.extend(_checked(path, where, parts, elevation))
    return lines, meta.get("crs")


def read_contours(
    path: str | Path, *, attribute: str | None = None, z_scale: float = 1.0
) -> tuple[list[ContourLine], MapFrame | None]:
    """Contour lines in local metres and, for a file with a CRS, their map frame.

    ``attribute`` names the height field (None: the first of :data:`ELEVATION_NAMES` the file
    has, in any case, else the lines' z coordinates); ``z_scale`` converts the heights to metres.
    Raises :class:`InputError` naming the file and feature.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(path, "contour file not found")
    plain = _plain_geojson(path)
    if plain is not None:
        lines = _geojson_lines(path, plain, attribute)
        if not _looks_lonlat(lines):
            return [(p, e * z_scale) for p, e in lines], None
        log.warning(
            "%s: a GeoJSON without a crs member whose coordinates all lie within a few degrees of "
            "lon/lat: read as lon/lat (RFC 7946), not as local metres; give it a crs member to say otherwise",
            path,
        )
    lines, crs_text = _ogr_lines(path, attribute)
    lines = [(p, e * z_scale) for p, e in lines]
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


#: a GeoJSON without a crs member spanning less than this in x and in y, within lon/lat bounds, is
#: read as lon/lat degrees (RFC 7946 GeoJSON is), not as a map of a few metres
LONLAT_MAX_SPAN = 10.0


def _looks_lonlat(lines: list[ContourLine]) -> bool:
    xy = np.concatenate([p for p, _ in lines])
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    inside = lo[0] >= -180 and hi[0] <= 180 and lo[1] >= -90 and hi[1] <= 90
    return bool(inside and np.all(hi - lo < LONLAT_MAX_SPAN))


def load_contours(path: str | Path, *, attribute: str | None = None) -> list[ContourLine]:
    """Contour lines in local metres (see :func:`read_contours`, which also gives the map frame)."""
    return read_contours(path, attribute=attribute)[0]


def _densify(points: np.ndarray, step: float) -> np.ndarray:
    """Resample a polyline, ndarray of shape (n, 2), so that no gap exceeds ``step``."""
    a, b = points[:-1], points[1:]
    n = np.maximum(1, np.ceil(np.hypot(*(b - a).T) / step).astype(np.intp))
    seg = np.repeat(np.arange(len(n)), n)
    t = (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + 1) / np.repeat(n, n)
    return np.concatenate([points[:1], a[seg] + (b - a)[seg] * t[:, None]])


def _points(lines: list[ContourLine], cell_size: float) -> tuple[np.ndarray, np.ndarray]:
    """Contour points densified to half a cell, (x, y) metres of shape (n, 2), and their heights (n,)."""
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
    return xy, z


def _grid_shape(xy: np.ndarray, cell_size: float, shape: tuple[int, int] | None) -> tuple[int, int]:
    if shape is not None:
        return int(shape[0]), int(shape[1])
    return int(math.floor(xy[:, 1].max() / cell_size)) + 1, int(math.floor(xy[:, 0].max() / cell_size)) + 1


def contours_to_tin(
    lines: list[ContourLine], *, cell_size: float, shape: tuple[int, int] | None = None, smooth: float = 0.5
) -> Terrain:
    """The former interpolation, kept for comparison (``bench/contours.py``): a linear TIN.

    Contour points (densified to half a cell) are triangulated and interpolated linearly
    (``scipy.interpolate.griddata``); cells outside their convex hull take the nearest
    contour's height; a Gaussian of ``smooth`` cells. Triangles with all three corners on one
    contour are flat: crests, hilltops and valley floors become terraces.
    """
    xy, z = _points(lines, cell_size)
    rows, cols = _grid_shape(xy, cell_size, shape)
    gy, gx = np.mgrid[0:rows, 0:cols].astype(np.float64) * cell_size
    dem = griddata(xy, z, (gx, gy), method="linear")
    holes = np.isnan(dem)
    if holes.any():
        dem[holes] = griddata(xy, z, (gx[holes], gy[holes]), method="nearest")
    if smooth > 0:
        dem = gaussian_filter(dem, smooth, mode="nearest")
    return Terrain(heights=dem, cell_size=float(cell_size))


def _diff(n: int, order: int) -> sparse.spmatrix:
    """Forward differences of ``order`` 1 or 2 along a line of ``n`` nodes, ((n - order), n)."""
    if order == 1:
        return sparse.diags([-np.ones(n - 1), np.ones(n - 1)], [0, 1], shape=(n - 1, n))
    return sparse.diags([np.ones(n - 2), -2 * np.ones(n - 2), np.ones(n - 2)], [0, 1, 2], shape=(n - 2, n))


def _bounds(
    xy: np.ndarray, z: np.ndarray, rows: int, cols: int, cell_size: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per cell, the heights it must lie between, (lo, hi) each of shape (rows, cols), and the
    cells of *bands* (bool, (rows, cols)): regions bordered by two consecutive levels only.

    The straight segment from a cell to its nearest contour point crosses no other contour, so
    the cell lies between the levels next below and above that contour's (beyond the lowest and
    highest level, one interval further). Tighter where the lines say more: the contours,
    rasterised (8-connected), cut the grid into regions (4-connected); a region that borders
    two consecutive levels only, and no other, lies between them.
    """
    from scipy.ndimage import binary_dilation, label
    from scipy.spatial import cKDTree

    levels = np.unique(z)
    gaps = np.diff(levels)
    gy, gx = np.mgrid[0:rows, 0:cols].astype(np.float64) * cell_size
    _, k = cKDTree(xy).query(np.column_stack([gx.ravel(), gy.ravel()]))
    near = z[k]
    i = np.searchsorted(levels, near)
    lo = (near - np.concatenate([gaps[:1], gaps])[i]).reshape(rows, cols)
    hi = (near + np.concatenate([gaps, gaps[-1:]])[i]).reshape(rows, cols)
    # regions between the rasterised lines, and the levels each one borders
    r = np.clip(np.rint(xy[:, 1] / cell_size).astype(np.intp), 0, rows - 1)
    c = np.clip(np.rint(xy[:, 0] / cell_size).astype(np.intp), 0, cols - 1)
    on_line = np.zeros((rows, cols), bool)
    on_line[r, c] = True
    regions, count = label(~on_line)
    if count == 0:
        return lo, hi, np.zeros((rows, cols), bool)
    level_of = np.full((rows, cols), -1, np.intp)
    level_of[r, c] = np.searchsorted(levels, z)
    low = np.full(count + 1, len(levels), np.intp)
    high = np.full(count + 1, -1, np.intp)
    cross = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], bool)
    for j in range(len(levels)):
        touched = regions[binary_dilation(level_of == j, cross) & ~on_line]
        low[touched] = np.minimum(low[touched], j)
        high[touched] = np.maximum(high[touched], j)
    band = (high == low + 1)[regions] & ~on_line
    lo = np.where(band, levels[np.clip(low, 0, len(levels) - 1)][regions], lo)
    hi = np.where(band, levels[np.clip(high, 0, len(levels) - 1)][regions], hi)
    return lo, hi, band


def _distance_ratio(
    xy: np.ndarray, z: np.ndarray, lo: np.ndarray, hi: np.ndarray, band: np.ndarray, cell_size: float
) -> np.ndarray:
    """In band cells, ``lo + (hi - lo) * d_lo / (d_lo + d_hi)`` by the distances to the nearest
    point of each bounding level; NaN elsewhere."""
    from scipy.spatial import cKDTree

    out = np.full(lo.shape, np.nan)
    rr, cc = np.nonzero(band)
    cells = np.column_stack([cc, rr]).astype(np.float64) * cell_size
    low, high = lo[rr, cc], hi[rr, cc]
    d_lo, d_hi = np.full(len(rr), np.inf), np.full(len(rr), np.inf)
    for level in np.unique(np.concatenate([low, high])):
        at_lo, at_hi = low == level, high == level
        d = np.full(len(rr), np.inf)
        want = at_lo | at_hi
        d[want] = cKDTree(xy[z == level]).query(cells[want])[0]
        d_lo[at_lo], d_hi[at_hi] = d[at_lo], d[at_hi]
    out[rr, cc] = lo[rr, cc] + (hi[rr, cc] - lo[rr, cc]) * d_lo / np.maximum(d_lo + d_hi, 1e-9)
    return out


#: weight of the thin-plate (bending) energy against the contour points, per cell
STIFFNESS = 0.01
#: in bands (regions between two consecutive levels), the share of the distance-ratio height
#: in the DEM (the rest is the thin plate's): 0 thin plate only, 1 distance ratio only
BAND_WEIGHT = 0.5
#: grids of at most this many cells are solved directly; larger ones by conjugate gradients
#: started from the solution on a grid of twice the cell size (recursively)
DIRECT_CELLS = 160 * 160
CG_RTOL = 1e-6
CG_ITERATIONS = 400


def _thin_plate(
    xy: np.ndarray, z: np.ndarray, rows: int, cols: int, cell_size: float, *, stiffness: float
) -> np.ndarray:
    """The thin-plate heights (rows, cols) through points ``xy`` (n, 2) (x, y) metres of heights ``z``."""
    u = np.clip(xy[:, 0] / cell_size, 0.0, cols - 1.0)
    v = np.clip(xy[:, 1] / cell_size, 0.0, rows - 1.0)
    c0 = np.minimum(u.astype(np.intp), max(cols - 2, 0))
    r0 = np.minimum(v.astype(np.intp), max(rows - 2, 0))
    fu, fv = u - c0, v - r0
    c1, r1 = np.minimum(c0 + 1, cols - 1), np.minimum(r0 + 1, rows - 1)
    n = len(z)
    data = np.concatenate([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv])
    index = np.concatenate([r0 * cols + c0, r0 * cols + c1, r1 * cols + c0, r1 * cols + c1])
    a = sparse.csr_matrix((data, (np.tile(np.arange(n), 4), index)), shape=(n, rows * cols))
    eye_r, eye_c = sparse.identity(rows), sparse.identity(cols)
    m = (a.T @ a + 1e-9 * sparse.identity(rows * cols)).tocsr()  # (definite where nothing else binds)
    if cols >= 3:
        d = sparse.kron(eye_r, _diff(cols, 2))
        m = m + stiffness * (d.T @ d)
    if rows >= 3:
        d = sparse.kron(_diff(rows, 2), eye_c)
        m = m + stiffness * (d.T @ d)
    if rows >= 2 and cols >= 2:
        d = sparse.kron(_diff(rows, 1), _diff(cols, 1))
        m = m + 2 * stiffness * (d.T @ d)
    b = a.T @ z
    if rows * cols <= DIRECT_CELLS:
        return np.asarray(spsolve(m.tocsc(), b)).reshape(rows, cols)
    coarse_rows, coarse_cols = (rows + 1) // 2 + 1, (cols + 1) // 2 + 1
    coarse = _thin_plate(xy, z, coarse_rows, coarse_cols, 2 * cell_size, stiffness=stiffness)
    gy, gx = np.mgrid[0:rows, 0:cols] / 2.0
    start = map_coordinates(coarse, [gy.ravel(), gx.ravel()], order=1, mode="nearest")
    diag = m.diagonal()
    pre = sparse.diags(1.0 / np.where(diag > 0, diag, 1.0))
    x, _ = cg(m, b, x0=start, rtol=CG_RTOL, maxiter=CG_ITERATIONS, M=pre)
    return np.asarray(x).reshape(rows, cols)


def contours_to_dem(
    lines: list[ContourLine],
    *,
    cell_size: float,
    shape: tuple[int, int] | None = None,
    stiffness: float = STIFFNESS,
    band_weight: float = BAND_WEIGHT,
) -> Terrain:
    """Interpolate contour lines into a DEM: a thin-plate surface through them, blended in bands
    with the distance ratio between the two bounding levels.

    The heights h (rows, cols) minimise

        sum_p (B_p h - z_p)^2 + stiffness * sum (h_xx^2 + 2 h_xy^2 + h_yy^2)

    over the contour points p (densified to half a cell, B_p the bilinear interpolation at p,
    z_p its contour's height), with second differences in cells (natural boundaries: the
    surface continues its slope past the map border and past the outermost contours). Unlike a
    TIN, a crest between two stretches of one contour rises above it, a hilltop above its
    highest contour and a valley floor below its lowest, as the neighbouring slopes continue.
    Every cell is then kept between the levels adjacent to its nearest contour's (see
    :func:`_bounds`), so the surface never crosses a level the lines do not show. In a band
    (a region bordered by two consecutive levels L < U only) the height is ``band_weight``
    times the distance ratio ``L + (U - L) * d_L / (d_L + d_U)`` (d the distance to the nearest
    point of each level) plus the rest times the thin plate's: the thin plate alone overshoots
    where contours are spaced very unevenly (a scarp below a plateau) and is then clipped flat,
    the distance ratio alone puts kinks on the band's medial axis. A larger ``stiffness``
    smooths more (noisy, digitised lines). :data:`STIFFNESS` and :data:`BAND_WEIGHT` were chosen
    with ``bench/contours.py`` on tuning terrains. Solved directly up to :data:`DIRECT_CELLS`
    cells, else by conjugate gradients from the solution at twice the cell size.
    ``shape`` (rows, cols) defaults to the grid covering all lines from (0, 0).
    """
    xy, z = _points(lines, cell_size)
    rows, cols = _grid_shape(xy, cell_size, shape)
    z0 = float(z.mean())
    dem = _thin_plate(xy, z - z0, rows, cols, cell_size, stiffness=stiffness) + z0
    lo, hi, band = _bounds(xy, z, rows, cols, cell_size)
    dem = np.clip(dem, lo, hi)
    if band_weight > 0 and band.any():
        ratio = _distance_ratio(xy, z, lo, hi, band, cell_size)
        dem = np.where(band, band_weight * ratio + (1 - band_weight) * dem, dem)
    log.debug("contours -> DEM %s x %s from %d points (thin plate)", rows, cols, len(z))
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
