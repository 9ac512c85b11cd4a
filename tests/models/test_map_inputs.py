"""Maps as users hand them over: DEMs with holes, spikes, feet, broken files; contour files
whose height attribute is named otherwise or whose lines carry their height as z.

Every case is a real file written into ``tmp_path`` (rasterio, pyogrio) and read through the
scenario, as ``mapinterp run`` reads it. Heights are (rows, cols) metres, row 0 = south.
"""

from __future__ import annotations

import json
import logging
import struct

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from models.contours import dem_to_contours
from models.errors import ScenarioError
from models.scenario import scenario_from_dict
from models.terrain import Terrain, procedural_terrain
from models.terrain_sources import scenario_terrain
from tests.models.geofiles import UTM, X0, Y0, write_contour_vector, write_geotiff

CAMERA = {"width": 32, "height": 24, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 5000.0}
CS = 10.0


@pytest.fixture(scope="module")
def hills() -> Terrain:
    return procedural_terrain(size=64, relief=80.0, cell_size=CS, rng=5)


def _transform(rows: int, cs: float = CS, x0: float = X0, y0: float = Y0) -> Affine:
    return Affine(cs, 0, x0, 0, -cs, y0 + rows * cs)


def _terrain(tmp_path, route=((150, 150), (300, 300)), **terrain) -> Terrain:
    data = {"name": "maps", "terrain": terrain, "route": [list(p) for p in route], "camera": CAMERA}
    return scenario_terrain(scenario_from_dict(data, path=tmp_path / "s.yaml"))


# -- rasters -------------------------------------------------------------------------------------


@pytest.mark.parametrize("sentinel", [-9999.0, -32768.0, -3.4028234663852886e38])
def test_untagged_nodata_sentinels_are_holes_not_pits(hills, tmp_path, sentinel, caplog):
    """A GeoTIFF that names no nodata value but holds -9999 (a GIS tool's default): before,
    a 10 km deep pit in the terrain; now nodata, filled and said so."""
    h = hills.heights[::-1].copy()
    h[10:14, 20:25] = sentinel
    path = write_geotiff(tmp_path / "holes.tif", h, _transform(64), UTM)
    with caplog.at_level(logging.WARNING):
        t = _terrain(tmp_path, dem=str(path))
    assert t.heights.min() >= hills.heights.min() - 1e-9
    assert "names no nodata value, but 20 cells hold" in caplog.text
    with pytest.raises(ScenarioError, match=r"s.yaml: terrain.dem: .*holes.tif: 20 of 4096 cells are nodata"):
        _terrain(tmp_path, dem=str(path), nodata="refuse")


def test_nan_holes_in_a_utm_dem_and_nodata_tagged_int16(hills, tmp_path):
    h = hills.heights[::-1].copy()
    h[30:33, 5:9] = np.nan
    nan_path = write_geotiff(tmp_path / "nan.tif", h, _transform(64), UTM)
    t = _terrain(tmp_path, dem=str(nan_path))
    assert np.all(np.isfinite(t.heights)) and t.heights.max() <= hills.heights.max() + 1e-9
    with rasterio.open(
        tmp_path / "i16.tif", "w", driver="GTiff", width=64, height=64, count=1, dtype="int16", crs=UTM,
        transform=_transform(64), nodata=-32768,
    ) as ds:  # fmt: skip
        v = np.round(hills.heights[::-1]).astype(np.int16)
        v[:3] = -32768
        ds.write(v, 1)
    t = _terrain(tmp_path, dem=str(tmp_path / "i16.tif"))
    np.testing.assert_allclose(t.heights[:-3], np.round(hills.heights[:-3]))


def test_single_cell_spikes_and_pits_are_filled_kept_or_refused(hills, tmp_path, caplog):
    h = hills.heights[::-1].copy()
    h[5, 5], h[40, 40], h[20, 50] = 3000.0, 2500.0, -500.0
    path = write_geotiff(tmp_path / "spikes.tif", h, _transform(64), UTM)
    with caplog.at_level(logging.WARNING):
        t = _terrain(tmp_path, dem=str(path))
    assert "3 cell(s) stand out from their neighbours" in caplog.text and "+2967 m at x 50, y 580" in caplog.text
    assert t.heights.max() < hills.heights.max() + 5 and t.heights.min() > hills.heights.min() - 5
    untouched = np.ones_like(h, bool)
    untouched[[5, 40, 20], [5, 40, 50]] = False
    np.testing.assert_array_equal(t.heights[::-1][untouched], h[untouched])
    assert _terrain(tmp_path, dem=str(path), spikes="keep").heights.max() == 3000.0
    with pytest.raises(ScenarioError, match=r"terrain.dem: .*spikes.tif: 3 cell\(s\) stand out .*terrain.spikes"):
        _terrain(tmp_path, dem=str(path), spikes="refuse")


def test_real_relief_is_not_taken_for_spikes(tmp_path):
    """Cliffs, a steep cone and the bundled DEMs keep every cell."""
    from models.terrain import sample_terrain
    from models.terrain_sources import despike

    y, x = np.mgrid[0:64, 0:64]
    cliff = np.where(x < 30, 0.0, 400.0) + 0.0 * y  # a 400 m wall
    cone = np.maximum(0.0, 600.0 - 60.0 * np.hypot(x - 32, y - 32))  # 60 m per 10 m cell
    for heights in (cliff, cone, sample_terrain("jacksboro", cell_size=80.0).heights):
        assert despike(heights, path=tmp_path / "x", policy="fill", cell_size=10.0) is heights


def test_heights_in_feet(hills, tmp_path, caplog):
    """A state-plane DEM in US survey feet (heights too): the CRS is resampled to metres, and
    the heights are converted when the band says so or the scenario gives z_scale; else a
    warning names terrain.z_scale."""
    ft = 1200 / 3937
    h_ft = hills.heights[::-1] / ft
    transform = Affine(CS / ft, 0, 2_000_000, 0, -CS / ft, 600_000 + 64 * CS / ft)
    path = write_geotiff(tmp_path / "ft.tif", h_ft, transform, "EPSG:2264")
    with caplog.at_level(logging.WARNING):
        plain = _terrain(tmp_path, dem=str(path))
    assert "heights taken as metres, but its CRS is in us survey foot: set terrain.z_scale" in caplog.text
    assert plain.heights.max() == pytest.approx(hills.heights.max() / ft, rel=0.02)
    scaled = _terrain(tmp_path, dem=str(path), z_scale=ft)
    assert scaled.heights.max() == pytest.approx(hills.heights.max(), rel=0.02)
    with rasterio.open(path, "r+") as ds:
        ds.units = ("US survey foot",)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        stated = _terrain(tmp_path, dem=str(path))
    assert "z_scale" not in caplog.text
    np.testing.assert_allclose(stated.heights, scaled.heights)
    # a .npy DEM in feet
    np.save(tmp_path / "ft.npy", hills.heights / 0.3048)
    t = _terrain(tmp_path, dem=str(tmp_path / "ft.npy"), cell_size=CS, z_scale=0.3048)
    np.testing.assert_allclose(t.heights, hills.heights)


def test_broken_and_colour_rasters_are_refused_naming_the_file(hills, tmp_path, caplog):
    good = write_geotiff(tmp_path / "good.tif", hills.heights[::-1], _transform(64), UTM)
    data = good.read_bytes()
    (tmp_path / "cut.tif").write_bytes(data[: len(data) // 2])
    with pytest.raises(ScenarioError, match=r"s.yaml: terrain.dem: .*cut.tif: cannot read the DEM's heights \(GDAL\)"):
        _terrain(tmp_path, dem=str(tmp_path / "cut.tif"))
    with rasterio.open(
        tmp_path / "rgb.tif", "w", driver="GTiff", width=64, height=64, count=3, dtype="uint8", crs=UTM,
        transform=_transform(64), photometric="RGB",
    ) as ds:  # fmt: skip
        ds.write(np.zeros((3, 64, 64), np.uint8))
    with pytest.raises(ScenarioError, match=r"rgb.tif: the raster is a colour image \(3 band\(s\): red, green, blue\)"):
        _terrain(tmp_path, dem=str(tmp_path / "rgb.tif"))
    with rasterio.open(
        tmp_path / "two.tif", "w", driver="GTiff", width=64, height=64, count=2, dtype="float32", crs=UTM,
        transform=_transform(64),
    ) as ds:  # fmt: skip
        ds.write(np.stack([hills.heights[::-1], np.zeros((64, 64))]).astype(np.float32))
    with caplog.at_level(logging.WARNING):
        t = _terrain(tmp_path, dem=str(tmp_path / "two.tif"))
    assert "2 bands: band 1 is read as the heights" in caplog.text
    np.testing.assert_allclose(t.heights, hills.heights, atol=1e-4)


# -- contour files -------------------------------------------------------------------------------


def _lines(hills):
    return dem_to_contours(hills, interval=10.0)


def _wkb_z(points: np.ndarray, z: float) -> bytes:
    pts = np.column_stack([points, np.full(len(points), z)]).astype("<f8")
    return struct.pack("<BII", 1, 1002, len(pts)) + pts.tobytes()  # ISO WKB LineString Z


@pytest.mark.parametrize(
    "attribute, suffix",
    [
        ("elev", ".geojson"),
        ("ELEVATION", ".shp"),
        ("contour", ".gpkg"),
        ("height", ".gpkg"),
        ("z", ".shp"),
        ("Elev_m", ".gpkg"),
    ],
)
def test_contour_heights_under_other_names(hills, tmp_path, attribute, suffix):
    """Before, every name but ``elevation`` was refused; now the usual names are found in any
    case, and any other is named with terrain.elevation_attribute."""
    lines = [(p + [X0, Y0], e) for p, e in _lines(hills)]
    path = write_contour_vector(tmp_path / f"c{suffix}", lines, crs=UTM, attribute=attribute)
    want = _terrain(tmp_path, contours=str(write_contour_vector(tmp_path / "ref.gpkg", lines, crs=UTM)), cell_size=CS)
    if attribute == "Elev_m":  # not a usual name: refused naming the fields, then named
        with pytest.raises(
            ScenarioError, match=r"terrain.contours: .*c.gpkg: no contour heights: .*\(the file has: id, Elev_m\)"
        ):
            _terrain(tmp_path, contours=str(path), cell_size=CS)
        got = _terrain(tmp_path, contours=str(path), cell_size=CS, elevation_attribute="elev_m")
    else:
        got = _terrain(tmp_path, contours=str(path), cell_size=CS)
    np.testing.assert_allclose(got.heights, want.heights)
    assert abs(got.heights - hills.heights[: got.shape[0], : got.shape[1]]).mean() < 2.0


def test_3d_contour_lines_carry_their_height_as_z(hills, tmp_path):
    import pyogrio

    lines = [(p + [X0, Y0], e) for p, e in _lines(hills)]
    geometry = np.array([_wkb_z(p, e) for p, e in lines], dtype=object)
    pyogrio.raw.write(
        tmp_path / "z.gpkg",
        geometry,
        [np.arange(len(lines), dtype=np.int32)],
        ["id"],
        geometry_type="LineString Z",
        crs=UTM,
    )
    want = _terrain(tmp_path, contours=str(write_contour_vector(tmp_path / "ref.gpkg", lines, crs=UTM)), cell_size=CS)
    got = _terrain(tmp_path, contours=str(tmp_path / "z.gpkg"), cell_size=CS)
    np.testing.assert_allclose(got.heights, want.heights)
    # plain GeoJSON (local metres) with [x, y, z] coordinates and no properties, in feet
    feats = [
        {
            "type": "Feature",
            "properties": {},
            "geometry": {
                "type": "LineString",
                "coordinates": np.column_stack([p, np.full(len(p), e / 0.3048)]).tolist(),
            },
        }
        for p, e in _lines(hills)
    ]
    (tmp_path / "z.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    local = _terrain(tmp_path, contours=str(tmp_path / "z.geojson"), cell_size=CS, z_scale=0.3048)
    np.testing.assert_allclose(local.heights, want.heights, atol=1e-6)


def test_the_lonlat_jacksboro_dem_with_untagged_holes_and_in_feet(tmp_path):
    """The bundled lon/lat GeoTIFF (int16, no nodata value) with a block of -32768 beside the
    route: before, a 33 km deep pit in the resampled map; now the same heights as around it.
    Its heights in feet with the band's unit 'ft': the metre DEM again."""
    from pathlib import Path

    src = Path(__file__).resolve().parents[2] / "scenarios" / "data" / "jacksboro.tif"
    with rasterio.open(src) as ds:
        h, profile = ds.read(1), ds.profile
    holes = h.copy()
    holes[146:158, 219:228] = -32768
    with rasterio.open(tmp_path / "holes.tif", "w", **profile) as ds:
        ds.write(holes, 1)
    with rasterio.open(tmp_path / "ft.tif", "w", **{**profile, "dtype": "float32"}) as ds:
        ds.write((h / 0.3048).astype(np.float32), 1)
        ds.units = ("ft",)

    def load(name: str) -> Terrain:
        data = {"name": "geo", "crs": "EPSG:4326", "terrain": {"dem": str(tmp_path / name)}, "camera": CAMERA}
        data["route"] = [[-84.2359998, 36.6081003], [-84.2356332, 36.6077596]]
        return scenario_terrain(scenario_from_dict(data, path=tmp_path / "s.yaml"))

    original = load(str(src))
    filled = load("holes.tif")
    assert filled.heights.min() >= original.heights.min() - 1.0
    assert np.mean(np.abs(filled.heights - original.heights) > 1.0) < 0.01
    np.testing.assert_allclose(load("ft.tif").heights, original.heights, atol=1e-3)


def test_rfc7946_geojson_contours_in_lonlat_without_a_crs_member(hills, tmp_path, caplog):
    """GeoJSON as geojson.io, mapshaper or shapely write it: lon/lat degrees and no crs member.
    Before, read as a map of a few metres; now as lon/lat (with a warning), the same DEM as the
    UTM file of the same lines."""
    from pyproj import Transformer

    to_ll = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True)
    lines = [(p + [X0, Y0], e) for p, e in _lines(hills)]
    feats = [
        {
            "type": "Feature",
            "properties": {"ELEV": e},
            "geometry": {"type": "LineString", "coordinates": np.column_stack(to_ll.transform(*p.T)).tolist()},
        }
        for p, e in lines
    ]
    (tmp_path / "ll.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    with caplog.at_level(logging.WARNING):
        route = [to_ll.transform(X0 + 150, Y0 + 150), to_ll.transform(X0 + 300, Y0 + 300)]
        got = _terrain(tmp_path, route, contours=str(tmp_path / "ll.geojson"), cell_size=CS)
    assert "read as lon/lat (RFC 7946)" in caplog.text
    assert got.frame is not None and got.frame.crs.to_epsg() == 4326
    want = _terrain(tmp_path, contours=str(write_contour_vector(tmp_path / "utm.gpkg", lines, crs=UTM)), cell_size=CS)
    assert abs(got.shape[0] - want.shape[0]) <= 2 and abs(got.shape[1] - want.shape[1]) <= 2
    r, c = min(got.shape[0], want.shape[0]), min(got.shape[1], want.shape[1])
    assert np.median(np.abs(got.heights[:r, :c] - want.heights[:r, :c])) < 2.0


@pytest.mark.parametrize("vertical, metres_per_unit", [("6360", 1200 / 3937), ("5703", 1.0)])
def test_a_compound_crs_states_the_heights_unit(tmp_path, caplog, vertical, metres_per_unit):
    """State plane feet horizontally, NAVD88 in US survey feet (6360) or metres (5703)
    vertically: the vertical CRS says what the heights are, and no warning is needed."""
    from pyproj import CRS
    from rasterio.crs import CRS as RioCRS

    ft = 1200 / 3937
    h = np.fromfunction(lambda r, c: 100.0 + r + 2 * c, (40, 40))
    crs = RioCRS.from_wkt(CRS(f"EPSG:2264+{vertical}").to_wkt())
    path = write_geotiff(tmp_path / "c.tif", h / metres_per_unit, Affine(CS / ft, 0, 2e6, 0, -CS / ft, 6e5), crs)
    with caplog.at_level(logging.WARNING):
        t = _terrain(tmp_path, dem=str(path))
    assert "z_scale" not in caplog.text
    assert t.heights.min() >= 99.0  # metres, not feet (feet taken as metres: up to 3.3 times more)
    assert t.heights.max() == pytest.approx(h.max(), abs=2.0)
