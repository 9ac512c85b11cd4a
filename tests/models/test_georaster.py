"""Georeferenced DEMs (GeoTIFFs written here with rasterio) become the local-metre grid."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from pyproj import Transformer
from rasterio.transform import Affine

from models.errors import InputError, ScenarioError
from models.georaster import raster_frame, read_raster_dem
from models.scenario import scenario_from_dict
from models.terrain import Terrain, procedural_terrain
from models.terrain_sources import load_terrain
from tests.models.geofiles import UTM, X0, Y0, reproject_to_lonlat, terrain_as_utm, write_geotiff

CAMERA = {"width": 32, "height": 24, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 5000.0}


@pytest.fixture(scope="module")
def hills() -> Terrain:
    return procedural_terrain(size=64, relief=80.0, cell_size=10.0, rng=5)


def plane(x, y):
    """A tilted plane of map coordinates: bilinear resampling reproduces it exactly."""
    return 100.0 + 0.01 * (np.asarray(x) - X0) + 0.02 * (np.asarray(y) - Y0)


def scenario(terrain: dict, route, **extra):
    return scenario_from_dict({"name": "geo", "terrain": terrain, "route": route, "camera": CAMERA, **extra})


def test_projected_geotiff_is_the_npy_grid_unchanged(hills, tmp_path):
    path = terrain_as_utm(tmp_path / "utm.tif", hills)
    heights, grid = read_raster_dem(path)
    assert not grid.resampled and grid.cell_size == 10.0 and grid.shape == hills.shape
    np.testing.assert_array_equal(heights, hills.heights)  # row 0 = south, nothing resampled
    assert grid.frame.name == UTM and grid.frame.origin == (X0, Y0)
    mx, my = grid.frame.to_map(30.0, 40.0)
    assert (float(mx), float(my)) == (X0 + 30.0, Y0 + 40.0)


def test_scenario_on_a_projected_geotiff_equals_the_npy_scenario(hills, tmp_path):
    np.save(tmp_path / "dem.npy", hills.heights)
    terrain_as_utm(tmp_path / "utm.tif", hills)
    route = [(120.0, 130.0), (160.0, 170.0), (220.0, 200.0)]
    lm = {"id": "H1", "kind": "house", "x": 150.0, "y": 180.0, "width": 18, "depth": 12, "height": 8}
    local = scenario({"dem": str(tmp_path / "dem.npy"), "cell_size": 10.0}, route, landmarks=[lm])
    geo = scenario(
        {"dem": str(tmp_path / "utm.tif")},
        [(X0 + x, Y0 + y) for x, y in route],
        landmarks=[{**lm, "x": X0 + 150.0, "y": Y0 + 180.0}],
    )
    assert local.map_frame is None and geo.map_frame is not None
    assert geo.route == local.route and geo.landmarks == local.landmarks
    t_local = load_terrain(local.terrain, base_dir=tmp_path, seed=0)
    t_geo = load_terrain(geo.terrain, base_dir=tmp_path, seed=0)
    np.testing.assert_array_equal(t_geo.heights, t_local.heights)
    assert t_geo.cell_size == t_local.cell_size and t_geo.frame is not None


def test_lonlat_geotiff_is_resampled_to_square_metres(hills, tmp_path):
    """The same hills warped to lon/lat and back: heights where the map says, within resampling error."""
    ll = reproject_to_lonlat(terrain_as_utm(tmp_path / "utm.tif", hills), tmp_path / "ll.tif")
    heights, grid = read_raster_dem(ll, cell_size=10.0)
    assert grid.resampled and "not projected in metres" in grid.reason
    assert grid.frame.name == "EPSG:4326" and grid.frame.work.is_projected
    t = Terrain(heights=heights, cell_size=grid.cell_size, frame=grid.frame)
    # compare at points spread over the map: local -> lon/lat -> UTM -> the original's local metres
    rng = np.random.default_rng(0)
    x, y = rng.uniform(60, 560, 400), rng.uniform(60, 560, 400)
    lon, lat = grid.frame.to_lonlat(x, y)
    ux, uy = Transformer.from_crs("EPSG:4326", UTM, always_xy=True).transform(lon, lat)
    diff = t.height_at(x, y) - hills.height_at(ux - X0, uy - Y0)
    rms = np.sqrt(np.mean(diff**2))
    assert rms < 0.8 and np.abs(diff).max() < 4.0  # relief 80 m, resampled twice
    shifted = t.height_at(x, y) - hills.height_at(ux - X0 + 5.0, uy - Y0)  # half a cell off: much worse
    assert np.sqrt(np.mean(shifted**2)) > 3 * rms
    # default cell: the smaller ground side of a raster cell (oversampled twice: about 5 m)
    _, default = read_raster_dem(ll)
    assert 3.5 < default.cell_size < 5.5


def test_plane_is_reproduced_through_non_square_cells(tmp_path):
    """Non-square projected cells are resampled to square ones at the right map positions."""
    sx, sy, rows, cols = 10.0, 15.0, 40, 60
    transform = Affine(sx, 0, X0, 0, -sy, Y0 + rows * sy)
    jj, ii = np.meshgrid(np.arange(cols), np.arange(rows))
    path = write_geotiff(
        tmp_path / "rect.tif", plane(X0 + (jj + 0.5) * sx, Y0 + rows * sy - (ii + 0.5) * sy), transform, UTM
    )
    heights, grid = read_raster_dem(path)
    assert grid.resampled and grid.cell_size == 10.0 and "not square" in grid.reason
    t = Terrain(heights=heights, cell_size=grid.cell_size, frame=grid.frame)
    x0, x1, y0, y1 = t.extent
    x, y = np.meshgrid(np.linspace(x0 + 20, x1 - 20, 15), np.linspace(y0 + 20, y1 - 20, 15))
    mx, my = grid.frame.to_map(x, y)
    np.testing.assert_allclose(t.height_at(x, y), plane(mx, my), atol=1e-6)
    # a coarser cell asked for: GDAL's downsampling kernel is discrete, so within a tenth of a
    # source cell's rise (15 m * 0.02) rather than exact, at the right map positions
    heights, grid = read_raster_dem(path, cell_size=25.0)
    t = Terrain(heights=heights, cell_size=25.0, frame=grid.frame)
    assert grid.shape == (24, 24)  # cell centres 590 m x 585 m apart
    x, y = np.meshgrid(np.arange(50.0, 500.0, 25.0), np.arange(50.0, 500.0, 25.0))
    mx, my = grid.frame.to_map(x, y)
    np.testing.assert_allclose(t.height_at(x, y), plane(mx, my), atol=0.03)


def test_nodata_cells_are_filled_or_refused(hills, tmp_path, caplog):
    h = hills.heights[::-1].copy()
    h[10:14, 20:25] = -9999.0
    h[30, 5] = np.nan
    cs = hills.cell_size
    transform = Affine(cs, 0, X0, 0, -cs, Y0 + h.shape[0] * cs)
    path = write_geotiff(tmp_path / "holes.tif", h, transform, UTM, nodata=-9999.0)
    with caplog.at_level(logging.WARNING, logger="models.georaster"):
        heights, _ = read_raster_dem(path)
    assert "21 of 4096 nodata cells" in caplog.text
    assert np.all(np.isfinite(heights)) and heights.min() > -1.0  # no -9999 left
    # a filled cell takes a neighbour's height
    r = h.shape[0] - 1 - 30
    assert heights[r, 5] in {heights[r, 4], heights[r, 6], heights[r - 1, 5], heights[r + 1, 5]}
    with pytest.raises(
        InputError, match=r"holes.tif: 21 of 4096 cells are nodata \(the first at raster row 10, col 20\)"
    ):
        read_raster_dem(path, nodata="refuse")
    every = write_geotiff(tmp_path / "none.tif", np.full((4, 4), -9999.0), transform, UTM, nodata=-9999.0)
    with pytest.raises(InputError, match="every cell of the DEM is nodata"):
        read_raster_dem(every)


@pytest.mark.parametrize(
    "case, match",
    [
        ("rotated", "rotated or sheared"),
        ("no_crs", "has no CRS"),
        ("garbage", "cannot read the DEM as a raster"),
        ("missing", "DEM file not found"),
    ],
)
def test_rasters_that_cannot_be_placed_are_refused_with_the_file_named(case, match, tmp_path):
    path = tmp_path / f"{case}.tif"
    if case == "rotated":
        write_geotiff(path, np.zeros((8, 8)), Affine(10, 2, X0, 2, -10, Y0), UTM)
    elif case == "no_crs":
        write_geotiff(path, np.zeros((8, 8)), Affine(10, 0, 0, 0, -10, 80), None)
    elif case == "garbage":
        path.write_bytes(b"not a raster at all")
    with pytest.raises(InputError, match=match) as err:
        raster_frame(path)
    assert str(path) in str(err.value)


def test_scenario_coordinates_in_another_crs(hills, tmp_path):
    """Route in lon/lat on a UTM GeoTIFF: converted to the same local metres as the UTM route."""
    terrain_as_utm(tmp_path / "utm.tif", hills)
    route = [(120.0, 130.0), (160.0, 170.0)]
    lon, lat = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True).transform(
        [X0 + x for x, _ in route], [Y0 + y for _, y in route]
    )
    s = scenario({"dem": str(tmp_path / "utm.tif")}, list(zip(lon, lat)), crs="EPSG:4326")
    np.testing.assert_allclose(s.route, route, atol=1e-6)


@pytest.mark.parametrize(
    "terrain, extra, field, match",
    [
        ({"dem": "dem.npy"}, {}, "terrain", "cell_size is required"),
        ({"dem": "dem.npy", "cell_size": 10.0}, {"crs": "EPSG:4326"}, "crs", "needs a georeferenced map"),
        ({"dem": "utm.tif"}, {"crs": "EPSG:99999999"}, "crs", "unknown CRS"),
        ({"dem": "utm.tif", "nodata": "zero"}, {}, "terrain.nodata", "must be one of"),
        ({"dem": "bad.tif"}, {}, "terrain.dem", "cannot read the DEM as a raster"),
    ],
)
def test_scenario_errors_name_the_field(hills, tmp_path, terrain, extra, field, match):
    np.save(tmp_path / "dem.npy", hills.heights)
    terrain_as_utm(tmp_path / "utm.tif", hills)
    (tmp_path / "bad.tif").write_bytes(b"junk")
    terrain = {k: (str(tmp_path / v) if k == "dem" else v) for k, v in terrain.items()}
    with pytest.raises(ScenarioError, match=match) as err:
        scenario(terrain, [(X0 + 100, Y0 + 100), (X0 + 200, Y0 + 200)], **extra)
    assert err.value.field == field


def test_route_off_the_map_names_the_point_in_map_coordinates(hills, tmp_path):
    from models.environment import build_environment

    terrain_as_utm(tmp_path / "utm.tif", hills)
    # lon/lat given without crs: (-81, 36) read as UTM metres lies far off the map
    s = scenario({"dem": str(tmp_path / "utm.tif")}, [(-81.0, 36.0), (-81.001, 36.001)])
    with pytest.raises(ScenarioError, match=r"route\[0\]: \(-81, 36\) is outside the terrain \(EPSG:32617.*crs"):
        build_environment(s)
