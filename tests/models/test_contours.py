"""Contour lines to DEM: accuracy on known surfaces (hills above their top contour, ridges that
are not terraces), the large-grid solver, GeoJSON and OGR reading and their errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from models.contours import contours_to_dem, contours_to_tin, dem_to_contours, load_contours, save_contours
from models.errors import InputError
from models.terrain import Terrain


def _analytic(cell: float = 10.0, n: int = 101) -> Terrain:
    y, x = np.mgrid[0:n, 0:n] * cell
    z = 60 + 25 * np.sin(2 * np.pi * x / 700) * np.cos(2 * np.pi * y / 900) + 0.01 * x
    return Terrain(heights=z, cell_size=cell)


@pytest.mark.parametrize("interval", [2.0, 5.0])
def test_contours_round_trip_to_a_known_surface(tmp_path, interval):
    truth = _analytic()
    lines = dem_to_contours(truth, interval=interval)
    assert len(lines) > 10
    path = tmp_path / "c.geojson"
    save_contours(lines, path)
    dem = contours_to_dem(load_contours(path), cell_size=10.0, shape=truth.shape)
    err = dem.heights - truth.heights
    inner = np.s_[5:-5, 5:-5]  # away from the map border where contours end
    rms = float(np.sqrt(np.mean(err[inner] ** 2)))
    # linear interpolation between contours: errors well under one contour interval
    assert rms < 0.2 * interval
    assert np.abs(err[inner]).max() < interval
    # and the interpolation beats simply taking the nearest contour's height
    from scipy.interpolate import griddata

    xy = np.concatenate([p for p, _ in lines])
    zz = np.concatenate([np.full(len(p), e) for p, e in lines])
    gy, gx = np.mgrid[0:101, 0:101] * 10.0
    nearest = griddata(xy, zz, (gx, gy), method="nearest")
    assert rms < np.sqrt(np.mean((nearest - truth.heights)[inner] ** 2))


def test_default_shape_covers_the_lines():
    lines = [(np.array([[0.0, 0.0], [95.0, 0.0]]), 10.0), (np.array([[0.0, 42.0], [95.0, 42.0]]), 20.0)]
    dem = contours_to_dem(lines, cell_size=10.0)
    assert dem.shape == (5, 10)
    assert dem.height_at(50.0, 21.0) == pytest.approx(15.0, abs=0.3)


def _grid(n: int = 81, cell: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    return tuple(np.mgrid[0:n, 0:n].astype(np.float64) * cell)  # type: ignore[return-value]


@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["hill", "bowl"])
def test_a_hilltop_rises_above_its_top_contour_and_a_bowl_sinks_below_its_lowest(sign):
    """A paraboloid hill peaking 6 m above its highest contour (every 10 m), and the same upside
    down: the interpolation continues the slopes past the innermost contour, as a TIN cannot."""
    y, x = _grid()
    r2 = (x - 400.0) ** 2 + (y - 400.0) ** 2
    truth = Terrain(heights=100.0 + sign * (96.0 - 96.0 * r2 / 400.0**2), cell_size=10.0)
    lines = dem_to_contours(truth, interval=10.0)
    inner = 190.0 if sign > 0 else 10.0  # the innermost contour's height
    assert inner in {e for _, e in lines} and (inner + sign * 10.0) not in {e for _, e in lines}
    dem = contours_to_dem(lines, cell_size=10.0, shape=truth.shape)
    tin = contours_to_tin(lines, cell_size=10.0, shape=truth.shape, smooth=0)
    peak = (truth.heights.max() if sign > 0 else truth.heights.min()) - 100.0
    got = (dem.heights.max() if sign > 0 else dem.heights.min()) - 100.0
    assert abs(got - peak) < 1.5  # 96 m, 6 m beyond the innermost contour
    assert abs((tin.heights.max() if sign > 0 else tin.heights.min()) - 100.0 - peak) > 5.0  # flat at 90
    # the whole surface: well within one contour interval
    rms = float(np.sqrt(np.mean((dem.heights - truth.heights)[3:-3, 3:-3] ** 2)))
    assert rms < 0.5


def test_a_ridge_crest_is_not_a_terrace():
    """A crest rising gently along x between flanks falling in y: every contour is a U around
    the crest, whose tip a TIN fills with flat triangles. The crest must rise smoothly and stay
    close to the truth."""
    y, x = _grid()
    truth = Terrain(heights=60.0 + 0.05 * x - 0.0015 * (y - 400.0) ** 2, cell_size=10.0)
    lines = dem_to_contours(truth, interval=10.0)
    dem = contours_to_dem(lines, cell_size=10.0, shape=truth.shape)
    tin = contours_to_tin(lines, cell_size=10.0, shape=truth.shape, smooth=0)
    crest = np.s_[40, 5:-5]  # row 40: y = 400 m
    err, tin_err = dem.heights[crest] - truth.heights[crest], tin.heights[crest] - truth.heights[crest]
    assert np.abs(err).max() < 1.0
    assert np.abs(err).mean() < 0.5 * np.abs(tin_err).mean()
    # rising all along: no flat stretch (a terrace) on the crest
    assert np.all(np.diff(dem.heights[crest]) > 0.1)
    # and the crest is the highest row of its cross-sections
    assert np.all(np.argmax(dem.heights[:, 5:-5], axis=0) == 40)


def test_large_grids_solved_iteratively_match_the_direct_solution(monkeypatch):
    """Above DIRECT_CELLS the solve starts from a coarser grid and iterates; it must agree
    with the direct solution."""
    import models.contours as mc

    truth = _analytic(cell=10.0, n=81)
    lines = dem_to_contours(truth, interval=5.0)
    direct = contours_to_dem(lines, cell_size=10.0, shape=truth.shape).heights
    monkeypatch.setattr(mc, "DIRECT_CELLS", 30 * 30)  # 81 x 81 -> 42 x 42 -> 22 x 22 (direct)
    iterative = contours_to_dem(lines, cell_size=10.0, shape=truth.shape).heights
    assert float(np.sqrt(np.mean((iterative - direct) ** 2))) < 0.05
    assert np.abs(iterative - direct).max() < 0.5


def test_unevenly_spaced_contours_give_neither_overshoot_nor_a_terrace():
    """A scarp (0 m and 10 m lines 20 m apart) below a gentle slope (the 20 m line 280 m
    further): the thin plate alone would carry the scarp's slope on and be clipped flat at
    20 m; between the 10 m and 20 m lines the DEM must stay between them and keep rising."""
    lines = [
        (np.array([[0.0, 0.0], [300.0, 0.0]]), 0.0),
        (np.array([[0.0, 20.0], [300.0, 20.0]]), 10.0),
        (np.array([[0.0, 300.0], [300.0, 300.0]]), 20.0),
    ]
    dem = contours_to_dem(lines, cell_size=10.0).heights
    assert dem.shape == (31, 31)
    between = dem[3:30]
    assert between.min() >= 10.0 and between.max() <= 20.0
    assert np.all(np.diff(dem[2:, 15]) > 0.05)  # rising from the 10 m line to the 20 m line
    assert abs(dem[16, 15] - 15.0) < 3.0  # half way up: the truth is a ramp
    only_plate = contours_to_dem(lines, cell_size=10.0, band_weight=0.0).heights
    assert abs(only_plate[16, 15] - 15.0) > 4.0  # what the blend is for


def _write(tmp_path, doc) -> object:
    p = tmp_path / "c.geojson"
    p.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return p


def _line(coords, elevation=10.0, kind="LineString"):
    return {
        "type": "Feature",
        "properties": {"elevation": elevation},
        "geometry": {"type": kind, "coordinates": coords},
    }


BAD = [
    ("{not json", "not valid GeoJSON"),
    ({"type": "FeatureCollection", "features": []}, "at least one feature"),
    (
        {"features": [{"geometry": {"type": "LineString", "coordinates": [[0, 0], [1, 1]]}, "properties": {}}]},
        r"no contour heights: no attribute named like an elevation .* and no z coordinates; "
        r"name it with terrain.elevation_attribute \(the file has: none\)",
    ),
    (
        {"features": [_line([[0, 0], [1, 1]], elevation="high")]},
        r"features\[0\]: needs a numeric properties.elevation, not 'high'",
    ),
    ({"features": [{"type": "Feature", "properties": {"elevation": 1}}]}, r"features\[0\]: has no geometry"),
    (  # 3-D lines without an attribute: z must be one level per line
        {"features": [{"properties": {}, "geometry": {"type": "LineString", "coordinates": [[0, 0, 5], [1, 1, 9]]}}]},
        r"features\[0\]: its z varies along the line \(5..9\): not a contour line",
    ),
    ({"features": [_line([[0, 0], [1, 1]]), _line([[0, 0]], 20.0)]}, r"features\[1\]: a line needs at least 2"),
    ({"features": [_line([0, 0], kind="Point")]}, r"features\[0\]: geometry must be a LineString"),
    ({"features": [_line([["a", 0], [1, 1]])]}, r"features\[0\]: coordinates must be numbers"),
]


@pytest.mark.parametrize(("doc", "message"), BAD)
def test_bad_contour_files(tmp_path, doc, message):
    path = _write(tmp_path, doc)
    with pytest.raises(InputError, match=message) as info:
        load_contours(path)
    assert info.value.path == path


def test_missing_contour_file(tmp_path):
    with pytest.raises(InputError, match="contour file not found"):
        load_contours(tmp_path / "none.geojson")


def test_multilinestring_and_errors_of_contours_to_dem(tmp_path):
    path = _write(tmp_path, {"features": [_line([[[0, 0], [50, 0]], [[0, 10], [50, 10]]], 5.0, "MultiLineString")]})
    lines = load_contours(path)
    assert len(lines) == 2 and lines[1][1] == 5.0
    with pytest.raises(ValueError, match="two or more elevations"):
        contours_to_dem(lines, cell_size=10.0)
    with pytest.raises(ValueError, match=">= 0"):
        contours_to_dem([(np.array([[-50.0, 0], [0, 0]]), 1.0), (np.array([[0.0, 5], [9, 9]]), 2.0)], cell_size=10.0)


# --- vector formats through pyogrio, georeferenced contour files -------------------------------


@pytest.mark.parametrize("suffix", [".shp", ".gpkg", ".geojson"])
def test_georeferenced_contour_files_give_the_local_dem_and_a_map_frame(tmp_path, suffix):
    """The same lines as local metres (plain GeoJSON) and in UTM (Shapefile, GeoPackage, GeoJSON
    with a crs member) give the same DEM; the map frame puts local (0, 0) at the lines' SW corner."""
    from models.contours import read_contours
    from tests.models.geofiles import UTM, X0, Y0, write_contour_vector

    truth = _analytic(cell=20.0, n=31)
    lines = dem_to_contours(truth, interval=10.0)
    save_contours(lines, tmp_path / "local.geojson", decimals=6)
    local, frame = read_contours(tmp_path / "local.geojson")
    assert frame is None
    lo = np.concatenate([p for p, _ in lines]).min(axis=0)
    path = write_contour_vector(
        tmp_path / f"utm{suffix}", [(p + (X0, Y0), e) for p, e in lines], crs=UTM, attribute="ELEV"
    )
    geo, frame = read_contours(path, attribute="ELEV")
    assert frame is not None and frame.name == UTM
    np.testing.assert_allclose(frame.origin, (X0 + lo[0], Y0 + lo[1]), atol=1e-6)
    assert len(geo) == len(local)
    for (pg, eg), (pl, el) in zip(geo, local):
        assert eg == el
        np.testing.assert_allclose(pg, pl - lo, atol=1e-5)
    # the scenario's terrain: the same heights at the same map positions
    a = contours_to_dem(local, cell_size=20.0)
    b = contours_to_dem(geo, cell_size=20.0)
    mx, my = frame.to_map(300.0, 400.0)
    assert b.height_at(300.0, 400.0) == pytest.approx(a.height_at(mx - X0, my - Y0), abs=0.5)


def test_contour_attribute_errors_list_the_fields(tmp_path):
    from tests.models.geofiles import UTM, write_contour_vector

    path = write_contour_vector(
        tmp_path / "c.gpkg", [(np.array([[0.0, 0], [10, 10]]), 5.0)], crs=UTM, attribute="hoehe"
    )
    with pytest.raises(InputError, match=r"c.gpkg: no contour heights: .*the file has: id, hoehe\)"):
        load_contours(path)
    assert load_contours(path, attribute="hoehe")[0][1] == 5.0
    assert load_contours(path, attribute="HOEHE")[0][1] == 5.0  # another case: the one there is
    with pytest.raises(
        InputError, match=r"c.gpkg: no attribute 'hohe' .*\(terrain.elevation_attribute\); the file has: id, hoehe"
    ):
        load_contours(path, attribute="hohe")
    (tmp_path / "junk.shp").write_bytes(b"nope")
    with pytest.raises(InputError, match=r"junk.shp: cannot read contour lines \(OGR\)"):
        load_contours(tmp_path / "junk.shp")


def test_multilinestring_and_local_metres_from_a_vector_file_without_crs(tmp_path):
    import pyogrio

    from models.contours import read_contours
    from tests.models.geofiles import wkb_multilinestring

    geometry = np.array(
        [
            wkb_multilinestring([np.array([[0.0, 0], [50, 0]]), np.array([[0.0, 10], [50, 10]])]),
            wkb_multilinestring([np.array([[0.0, 40], [50, 40]])]),
        ],
        dtype=object,
    )
    with pytest.warns(UserWarning, match="'crs' was not provided"):
        pyogrio.raw.write(
            tmp_path / "m.gpkg", geometry, [np.array([1.0, 9.0])], ["elevation"], geometry_type="MultiLineString"
        )
    lines, frame = read_contours(tmp_path / "m.gpkg")
    assert frame is None and [e for _, e in lines] == [1.0, 1.0, 9.0]
    np.testing.assert_array_equal(lines[1][0], [[0.0, 10.0], [50.0, 10.0]])
