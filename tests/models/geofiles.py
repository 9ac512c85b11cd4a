"""Georeferenced test files written with rasterio and pyogrio (helpers of the tests, not tests)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import Affine
from rasterio.warp import Resampling, calculate_default_transform, reproject

from models.terrain import Terrain

#: the south-west cell centre of the projected test DEMs: UTM 17N, on its central meridian
UTM = "EPSG:32617"
X0, Y0 = 500000.0, 4000000.0


def write_geotiff(
    path: Path, heights_north_first: np.ndarray, transform: Affine, crs: str | None, *, nodata: float | None = None
) -> Path:
    """A one-band float64 GeoTIFF; ``heights_north_first`` ndarray (rows, cols), raster row 0 first."""
    h = np.asarray(heights_north_first, dtype=np.float64)
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=h.shape[1],
        height=h.shape[0],
        count=1,
        dtype="float64",
        crs=crs,
        transform=transform,
        nodata=nodata,
    ) as ds:
        ds.write(h, 1)
    return path


def terrain_as_utm(path: Path, terrain: Terrain, *, x0: float = X0, y0: float = Y0) -> Path:
    """``terrain`` (row 0 = south) as a UTM GeoTIFF whose south-west cell centre is (x0, y0)."""
    cs = terrain.cell_size
    rows = terrain.shape[0]
    transform = Affine(cs, 0.0, x0 - cs / 2, 0.0, -cs, y0 + (rows - 1) * cs + cs / 2)
    return write_geotiff(path, terrain.heights[::-1], transform, UTM)


def reproject_to_lonlat(src_path: Path, path: Path, *, oversample: int = 2) -> Path:
    """The GeoTIFF ``src_path`` warped (cubic) to EPSG:4326 with ``oversample`` times its cell count per axis."""
    with rasterio.open(src_path) as src:
        transform, w, h = calculate_default_transform(
            src.crs,
            "EPSG:4326",
            src.width,
            src.height,
            *src.bounds,
            dst_width=src.width * oversample,
            dst_height=src.height * oversample,
        )
        out = np.full((h, w), np.nan)
        reproject(
            rasterio.band(src, 1),
            out,
            dst_transform=transform,
            dst_crs="EPSG:4326",
            resampling=Resampling.cubic,
            dst_nodata=np.nan,
        )
    return write_geotiff(path, out, transform, "EPSG:4326", nodata=float("nan"))


def wkb_linestring(points: np.ndarray) -> bytes:
    """2-D little-endian WKB of a LineString, points ndarray of shape (n, 2)."""
    pts = np.asarray(points, dtype="<f8")
    return struct.pack("<BII", 1, 2, len(pts)) + pts.tobytes()


def wkb_multilinestring(parts: list[np.ndarray]) -> bytes:
    return struct.pack("<BII", 1, 5, len(parts)) + b"".join(wkb_linestring(p) for p in parts)


def write_contour_vector(
    path: Path,
    lines: list[tuple[np.ndarray, float]],
    *,
    crs: str | None,
    attribute: str = "elevation",
    driver: str | None = None,
) -> Path:
    """Contour lines as a vector file (driver from the suffix: .shp, .gpkg, .geojson) via pyogrio."""
    import pyogrio

    geometry = np.array([wkb_linestring(p) for p, _ in lines], dtype=object)
    values = np.array([float(e) for _, e in lines])
    ids = np.arange(len(lines), dtype=np.int32)
    pyogrio.raw.write(
        path, geometry, [ids, values], ["id", attribute], geometry_type="LineString", crs=crs, driver=driver
    )
    return path
