"""A georeferenced DEM (GeoTIFF or any raster GDAL reads, via rasterio) as a local-metre grid.

The raster's band 1 holds heights in metres (its scale and offset applied). Only north-up
rasters are read (no rotation or shear terms in the geotransform). The grid the models use
(row 0 = south, square cells, see :mod:`models.terrain`) comes from the raster in one of two ways:

* **as is**, when its CRS is projected in metres, its cells are square and ``cell_size`` is not
  given or equals the raster's: heights are only flipped to south-first, nothing is resampled;
* **resampled** (bilinear, GDAL's warper) otherwise: lon/lat rasters, non-square cells, CRS in
  feet, or another ``cell_size`` asked for. The target is a square grid of ``cell_size`` metres
  (default: the smaller ground side of a raster cell) in the working CRS of
  :func:`models.georef.working_crs`, covering the largest north-up rectangle inside the
  raster's footprint, so that no target cell lies outside the data.

Nodata cells (the raster's nodata value, its mask, or non-finite values) are ``"fill"``-ed with
the height of the nearest valid cell (a warning says how many), or ``"refuse"``-d with an
:class:`InputError` naming how many and where. :func:`raster_frame` computes the grid and
:class:`~models.georef.MapFrame` from the metadata alone, without reading heights.
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from rasterio.enums import MaskFlags

from models.errors import InputError
from models.georef import MapFrame, is_metric, parse_crs, working_crs
from models.logs import warn_once

__all__ = [
    "RasterGrid",
    "raster_frame",
    "read_raster_dem",
    "raster_height_units",
    "RASTER_SUFFIXES_NOT",
    "NODATA_SENTINELS",
    "FOOT_M",
    "US_SURVEY_FOOT_M",
]

log = logging.getLogger(__name__)

#: suffixes that are not read as rasters (``terrain.dem`` keeps today's .npy contract)
RASTER_SUFFIXES_NOT = (".npy",)

#: boundary points per raster edge when the footprint is projected into the working CRS
_EDGE_POINTS = 101

#: heights that stand for "no data" in a raster that names no nodata value (what GIS tools
#: write by default); and any magnitude from this on (float32's lowest, -3.4e38)
NODATA_SENTINELS = (-9999.0, -99999.0, -32767.0, -32768.0)
_NODATA_MAGNITUDE = 1e30

#: metres per international foot and per US survey foot
FOOT_M = 0.3048
US_SURVEY_FOOT_M = 1200.0 / 3937.0
_HEIGHT_UNITS = {
    "m": 1.0,
    "metre": 1.0,
    "meter": 1.0,
    "metres": 1.0,
    "meters": 1.0,
    "ft": FOOT_M,
    "foot": FOOT_M,
    "feet": FOOT_M,
    "international foot": FOOT_M,
    "us survey foot": US_SURVEY_FOOT_M,
    "us_survey_foot": US_SURVEY_FOOT_M,
    "ftus": US_SURVEY_FOOT_M,
    "us-ft": US_SURVEY_FOOT_M,
}


@dataclass(frozen=True)
class RasterGrid:
    """The local grid a raster becomes: ``shape`` (rows, cols), ``cell_size`` metres, its frame.

    ``resampled`` is False when the raster's own cells are used as they are; ``dst_transform``
    is then None, else the north-up affine of the target grid in the working CRS.
    """

    frame: MapFrame
    shape: tuple[int, int]
    cell_size: float
    resampled: bool
    dst_transform: object | None
    reason: str = ""


def _open(path: Path):
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioIOError

    if not path.is_file():
        raise InputError(path, "DEM file not found")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        try:
            ds = rasterio.open(path)
        except RasterioIOError as exc:
            raise InputError(path, f"cannot read the DEM as a raster (GDAL): {exc}") from None
    _check_bands(ds, path)
    return ds


def _check_bands(ds, path: Path) -> None:
    """Refuse a colour image (RGB, palette) given as a DEM; say which band of several is read."""
    from rasterio.enums import ColorInterp

    colours = {ColorInterp.red, ColorInterp.green, ColorInterp.blue, ColorInterp.palette}
    interp = set(ds.colorinterp or ())
    if interp & colours:
        what = f"{ds.count} band(s): {', '.join(c.name for c in ds.colorinterp)}"
        ds.close()
        raise InputError(
            path, f"the raster is a colour image ({what}), not heights: give the DEM (one band of elevations)"
        )
    if ds.count > 1:
        warn_once(log, "%s: %d bands: band 1 is read as the heights", path, ds.count)


def raster_height_units(path: str | Path) -> tuple[float | None, str]:
    """Metres per height unit that a raster's metadata states, and why: the band's unit
    (``m``, ``ft``, ``US survey foot`` ...), else None with a hint when its CRS is in feet."""
    path = Path(path)
    with _open(path) as ds:
        unit = (ds.units or ("",))[0] or ""
        crs = ds.crs
    scale = _HEIGHT_UNITS.get(unit.strip().lower())
    if scale is not None:
        return scale, f"the band's unit is {unit!r}"
    if crs is not None:
        from models.georef import parse_crs

        parsed = parse_crs(crs.to_wkt())
        for ax in parsed.axis_info:  # a compound CRS's vertical axis states the heights' unit
            if ax.direction.lower() == "up":
                up = _HEIGHT_UNITS.get(ax.unit_name.strip().lower())
                if up is None and ax.unit_conversion_factor > 0:
                    up = float(ax.unit_conversion_factor)
                if up is not None:
                    return up, f"its vertical CRS is in {ax.unit_name}"
        names = {ax.unit_name.lower() for ax in parsed.axis_info[:2]}
        if any("foot" in n or "feet" in n for n in names):
            return None, f"its CRS is in {' / '.join(sorted(names))}"
    return None, ""


def _grid(ds, path: Path, cell_size: float | None) -> RasterGrid:
    if ds.crs is None:
        raise InputError(
            path,
            "the raster has no CRS: georeference it (gdal_edit.py -a_srs EPSG:nnnn) "
            "or save its heights as .npy with terrain.cell_size",
        )
    if ds.width < 2 or ds.height < 2:
        raise InputError(path, f"DEM must be at least 2x2 cells, got {ds.height} x {ds.width}")
    t = ds.transform
    if abs(t.b) > 1e-9 * abs(t.a) or abs(t.d) > 1e-9 * abs(t.e) or t.a == 0 or t.e == 0:
        raise InputError(
            path,
            f"the raster is rotated or sheared (geotransform {tuple(t)[:6]}): "
            "only north-up rasters are read; warp it north-up first (gdalwarp)",
        )
    crs = parse_crs(ds.crs.to_wkt())
    sx, sy = abs(t.a), abs(t.e)
    h, w = ds.height, ds.width
    # cell centres of the raster's corners, in its CRS
    cx = [t.c + (j + 0.5) * t.a for j in (0, w - 1)]
    cy = [t.f + (i + 0.5) * t.e for i in (0, h - 1)]
    x_lo, x_hi, y_lo, y_hi = min(cx), max(cx), min(cy), max(cy)
    metric, square = is_metric(crs), math.isclose(sx, sy, rel_tol=1e-6)
    if metric and square and (cell_size is None or math.isclose(cell_size, sx, rel_tol=1e-6)):
        return RasterGrid(MapFrame(crs, crs, (x_lo, y_lo)), (h, w), float(sx), False, None)

    from pyproj import Transformer
    from rasterio.transform import Affine

    to_ll = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    lon, lat = to_ll.transform((x_lo + x_hi) / 2, (y_lo + y_hi) / 2)
    work = working_crs(crs, lon=float(lon), lat=float(lat))
    fwd = Transformer.from_crs(crs, work, always_xy=True)
    xs, ys = np.linspace(x_lo, x_hi, _EDGE_POINTS), np.linspace(y_lo, y_hi, _EDGE_POINTS)
    left = fwd.transform(np.full_like(ys, x_lo), ys)
    right = fwd.transform(np.full_like(ys, x_hi), ys)
    bottom = fwd.transform(xs, np.full_like(xs, y_lo))
    top = fwd.transform(xs, np.full_like(xs, y_hi))
    wx_lo, wx_hi = float(np.max(left[0])), float(np.min(right[0]))
    wy_lo, wy_hi = float(np.max(bottom[1])), float(np.min(top[1]))
    if not all(map(math.isfinite, (wx_lo, wx_hi, wy_lo, wy_hi))) or wx_hi <= wx_lo or wy_hi <= wy_lo:
        raise InputError(path, f"the raster's footprint cannot be projected to a local metric grid ({crs_label(crs)})")
    if cell_size is None:  # the smaller ground side of the central raster cell
        mx, my = (x_lo + x_hi) / 2, (y_lo + y_hi) / 2
        p0 = np.array(fwd.transform(mx, my))
        ground_x = float(np.hypot(*(np.array(fwd.transform(mx + sx, my)) - p0)))
        ground_y = float(np.hypot(*(np.array(fwd.transform(mx, my + sy)) - p0)))
        cell_size = min(ground_x, ground_y)
    cols = int(math.floor((wx_hi - wx_lo) / cell_size + 1e-9)) + 1
    rows = int(math.floor((wy_hi - wy_lo) / cell_size + 1e-9)) + 1
    if rows < 2 or cols < 2:
        raise InputError(path, f"terrain.cell_size {cell_size:g} m leaves fewer than 2x2 cells of this raster")
    half = cell_size / 2
    dst = Affine(cell_size, 0.0, wx_lo - half, 0.0, -cell_size, wy_lo + (rows - 1) * cell_size + half)
    if not metric:
        reason = f"its CRS ({crs_label(crs)}) is not projected in metres"
    elif not square:
        reason = f"its cells are not square ({sx:g} x {sy:g})"
    else:
        reason = f"terrain.cell_size {cell_size:g} differs from its cells ({sx:g})"
    return RasterGrid(MapFrame(crs, work, (wx_lo, wy_lo)), (rows, cols), float(cell_size), True, dst, reason)


def crs_label(crs) -> str:
    """A short name for messages: ``EPSG:nnnn`` or the CRS's name."""
    auth = crs.to_authority(min_confidence=90)
    return f"{auth[0]}:{auth[1]}" if auth else crs.name


def raster_frame(path: str | Path, *, cell_size: float | None = None) -> RasterGrid:
    """The local grid of a raster DEM from its metadata (no heights read); see the module doc."""
    path = Path(path)
    with _open(path) as ds:
        return _grid(ds, path, cell_size)


def _fill_nearest(values: np.ndarray, invalid: np.ndarray) -> np.ndarray:
    from scipy.ndimage import distance_transform_edt

    idx = distance_transform_edt(invalid, return_distances=False, return_indices=True)
    return values[tuple(idx)]


def read_raster_dem(
    path: str | Path, *, cell_size: float | None = None, nodata: Literal["fill", "refuse"] = "fill"
) -> tuple[np.ndarray, RasterGrid]:
    """Heights, ndarray of shape (rows, cols) float64 metres with row 0 = south, and their grid.

    Raises :class:`InputError` naming the file for an unreadable, rotated or CRS-less raster,
    an all-nodata raster, or any nodata cell when ``nodata="refuse"``.
    """
    from rasterio.errors import RasterioError

    path = Path(path)
    with _open(path) as ds:
        grid = _grid(ds, path, cell_size)
        try:
            band = ds.read(1, masked=True).astype(np.float64)
        except RasterioError as exc:  # a truncated or damaged file: GDAL names the cause
            cause = exc.__cause__ or exc.__context__ or exc
            raise InputError(path, f"cannot read the DEM's heights (GDAL): {cause}") from None
        scale, offset = (ds.scales or (1.0,))[0], (ds.offsets or (0.0,))[0]
        src_transform, src_crs = ds.transform, ds.crs
        tagged = ds.nodata is not None or any(f != MaskFlags.all_valid for f in ds.mask_flag_enums[0])
    raw = np.ma.getdata(band)
    values = raw * scale + offset
    invalid = np.ma.getmaskarray(band) | ~np.isfinite(values)
    if not tagged:  # no nodata value named: the usual sentinels are holes, not heights
        sentinel = np.isin(raw, NODATA_SENTINELS) | (np.abs(raw) >= _NODATA_MAGNITUDE)
        if sentinel.any():
            warn_once(
                log,
                "%s names no nodata value, but %d cells hold %s: taken as nodata",
                path,
                int(sentinel.sum()),
                ", ".join(f"{v:g}" for v in np.unique(raw[sentinel])[:3]),
            )
            invalid |= sentinel
    n_bad = int(invalid.sum())
    if n_bad == invalid.size:
        raise InputError(path, "every cell of the DEM is nodata")
    if n_bad:
        r, c = map(int, np.argwhere(invalid)[0])
        if nodata == "refuse":
            raise InputError(
                path,
                f"{n_bad} of {invalid.size} cells are nodata (the first at raster row {r}, "
                f"col {c}); set terrain.nodata: fill to fill them from their nearest neighbours",
            )
        warn_once(
            log,
            "%s: %d of %d nodata cells (%.1f %%) filled with the nearest valid height",
            path,
            n_bad,
            invalid.size,
            100.0 * n_bad / invalid.size,
        )
        values = _fill_nearest(values, invalid)
    if not grid.resampled:
        heights = values[::-1] if src_transform.e < 0 else values
        if src_transform.a < 0:
            heights = heights[:, ::-1]
    else:
        from rasterio.crs import CRS as RioCRS
        from rasterio.warp import Resampling, reproject

        out = np.full(grid.shape, np.nan, dtype=np.float64)
        reproject(
            values,
            out,
            src_transform=src_transform,
            src_crs=src_crs,
            dst_transform=grid.dst_transform,
            dst_crs=RioCRS.from_wkt(grid.frame.work.to_wkt()),
            resampling=Resampling.bilinear,
            src_nodata=None,
            dst_nodata=np.nan,
        )
        holes = ~np.isfinite(out)
        if holes.all():
            raise InputError(path, "resampling the DEM to a local metric grid gave no data")
        if holes.any():  # the footprint's edge cells, where the warper found too little data
            out = _fill_nearest(out, holes)
        heights = out[::-1]
        log.info("%s resampled to %d x %d cells of %g m because %s", path, *grid.shape, grid.cell_size, grid.reason)
    return np.ascontiguousarray(heights, dtype=np.float64), grid
