"""A GeoTIFF in a projected CRS and one in lon/lat localize as the equivalent .npy scenario does
(real rendering, real blackboard); results carry map-CRS and lon/lat positions."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from pyproj import Transformer

from knowledge_sources.mission import run_mission
from models.terrain import procedural_terrain
from tests.models.geofiles import UTM, X0, Y0, reproject_to_lonlat, terrain_as_utm

pytestmark = pytest.mark.slow

KEYS = ("frame", "viewframe", "queries", "backtracks", "truth_viewframe", "correct")


def _write(path, doc):
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.fixture(scope="module")
def three(tmp_path_factory, request):
    """The knowledge_sources SMALL scenario as .npy, as a UTM GeoTIFF and as a lon/lat GeoTIFF."""
    from tests.knowledge_sources.conftest import SMALL

    tmp = tmp_path_factory.mktemp("geo")
    p = SMALL["terrain"]["procedural"]
    terrain = procedural_terrain(size=p["size"], relief=p["relief"], cell_size=10.0, rng=p["seed"])
    np.save(tmp / "dem.npy", terrain.heights)
    utm = terrain_as_utm(tmp / "utm.tif", terrain)
    reproject_to_lonlat(utm, tmp / "ll.tif", oversample=2)
    to_ll = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True)

    def lonlat(x, y):
        lon, lat = to_ll.transform(X0 + x, Y0 + y)
        return [round(float(lon), 9), round(float(lat), 9)]

    local = {**SMALL, "terrain": {"cell_size": 10.0, "dem": "dem.npy"}}
    projected = {
        **SMALL,
        "terrain": {"dem": "utm.tif"},
        "route": [[X0 + x, Y0 + y] for x, y in SMALL["route"]],
        "landmarks": [{**lm, "x": X0 + lm["x"], "y": Y0 + lm["y"]} for lm in SMALL["landmarks"]],
    }
    geographic = {
        **SMALL,
        "crs": "EPSG:4326",
        "terrain": {"dem": "ll.tif", "cell_size": 10.0},
        "route": [lonlat(x, y) for x, y in SMALL["route"]],
        "landmarks": [{**lm, **dict(zip("xy", lonlat(lm["x"], lm["y"])))} for lm in SMALL["landmarks"]],
    }
    return {
        name: run_mission(_write(tmp / f"{name}.yaml", doc))
        for name, doc in (("npy", local), ("utm", projected), ("lonlat", geographic))
    }


def test_projected_geotiff_gives_the_npy_results(three):
    a, b = three["npy"], three["utm"]
    assert "crs" not in a and b["crs"] == UTM
    assert [{k: f[k] for k in KEYS} for f in a["frames"]] == [{k: f[k] for k in KEYS} for f in b["frames"]]
    for fa, fb in zip(a["frames"], b["frames"]):
        assert [k for k, _ in fa["ranking"]] == [k for k, _ in fb["ranking"]]
        if fa["position"] is not None:
            assert fb["position"] == pytest.approx(fa["position"], abs=1e-6)
            assert fb["position_map"] == pytest.approx([X0 + fa["position"][0], Y0 + fa["position"][1]], abs=1e-6)
        assert fb["truth_map"] == pytest.approx([X0 + fa["truth"][0], Y0 + fa["truth"][1]], abs=1e-6)


def test_lonlat_geotiff_gives_the_npy_results(three):
    """Its DEM was resampled twice (to lon/lat by the test, back to metres on load), so images
    differ a little: the same frames are right, with the same viewframes and the same ranking
    top-1; which wrong viewframe a wrong frame ends on is not compared."""
    a, c = three["npy"], three["lonlat"]
    assert c["crs"] == "EPSG:4326"
    assert a["summary"]["top1"] > 0.7  # the comparison means something: the .npy run localizes
    assert [f["correct"] for f in c["frames"]] == [f["correct"] for f in a["frames"]]
    assert [f["ranking"][0][0] for f in c["frames"]] == [f["ranking"][0][0] for f in a["frames"]]
    to_ll = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True)
    for fa, fc in zip(a["frames"], c["frames"]):
        lon, lat = to_ll.transform(X0 + fa["truth"][0], Y0 + fa["truth"][1])
        assert fc["truth_lonlat"] == pytest.approx([lon, lat], abs=1e-6)  # the same simulated poses
        # the single-frame decision is a viewframe's pose, the same on both maps; the track's
        # continuous position depends on the rankings' variances, which the resampling changes a little
        sa, sc = fa["frame_only"], fc["frame_only"]
        if not sa["correct"]:
            continue
        assert sc["viewframe"] == sa["viewframe"]
        # the same place on the Earth: lon/lat of the npy run's UTM position, within centimetres
        lon, lat = to_ll.transform(X0 + sa["position"][0], Y0 + sa["position"][1])
        assert sc["position_lonlat"] == pytest.approx([lon, lat], abs=1e-6)
        assert sc["position_map"] == sc["position_lonlat"]
        assert sc["error_m"] == pytest.approx(sa["error_m"], abs=0.05)
        assert fc["position_lonlat"] is not None and fc["position_map"] == fc["position_lonlat"]


def test_report_writes_geojson_that_gdal_reads(three, tmp_path):
    """positions.geojson of a lon/lat run: GDAL (pyogrio) reads it as EPSG:4326 with every feature."""
    import json

    import pyogrio

    from knowledge_sources.cli import main
    from knowledge_sources.results import write_results

    run = three["lonlat"]
    out = tmp_path / "report"
    assert main(["report", str(write_results(tmp_path / "r.json", run)), "--out", str(out), "--max-frames", "1"]) == 0
    path = out / "positions.geojson"
    assert "positions.geojson" in (out / "report.md").read_text()
    info = pyogrio.read_info(path)
    assert info["crs"] == "EPSG:4326"
    doc = json.loads(path.read_text())
    kinds = [f["properties"]["kind"] for f in doc["features"]]
    n = len(run["frames"])
    assert kinds.count("route") == 1 and kinds.count("route_point") == n and kinds.count("landmark") == 3
    assert kinds.count("truth") == n and kinds.count("estimate") == n and kinds.count("error") == n
    assert info["features"] == len(kinds)
    estimates = [f for f in doc["features"] if f["properties"]["kind"] == "estimate"]
    for feat, rec in zip(estimates, run["frames"]):
        assert feat["properties"]["frame"] == rec["frame"]
        assert feat["geometry"]["coordinates"] == pytest.approx(rec["position_lonlat"])
