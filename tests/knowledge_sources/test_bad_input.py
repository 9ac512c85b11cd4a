"""Bad input, as an adversarial user gives it: a table of malformed scenarios and a table of bad
command lines, each with its exit status and the fragment of the one-line message it must print.

Every case runs ``mapinterp`` (in-process :func:`knowledge_sources.cli.main` for speed; a subset
as real subprocesses with a hard timeout): none may print a traceback, hang or exit 0. The
pre-run checks (``models.preflight``) catch every scenario case before an agent starts, which is
why the in-process table runs in seconds.
"""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from knowledge_sources.cli import main

Mutate = Callable[[dict, Path], None]


# -- helpers that write real data files ---------------------------------------------------------------


def _dem(array, name: str = "dem.npy") -> Mutate:
    def apply(data: dict, tmp: Path) -> None:
        np.save(tmp / name, array, allow_pickle=True)
        data["terrain"] = {"cell_size": 10.0, "dem": name}

    return apply


def _dem_bytes(content: bytes, name: str = "dem.npy") -> Mutate:
    def apply(data: dict, tmp: Path) -> None:
        (tmp / name).write_bytes(content)
        data["terrain"] = {"cell_size": 10.0, "dem": name}

    return apply


def _contours(doc, raw: str | None = None) -> Mutate:
    def apply(data: dict, tmp: Path) -> None:
        (tmp / "c.geojson").write_text(raw if raw is not None else json.dumps(doc))
        data["terrain"] = {"cell_size": 10.0, "contours": "c.geojson"}

    return apply


def _line(coords, elevation) -> dict:
    props = {} if elevation is None else {"elevation": elevation}
    return {"type": "Feature", "properties": props, "geometry": {"type": "LineString", "coordinates": coords}}


def _fc(*features) -> dict:
    return {"type": "FeatureCollection", "features": list(features)}


def _frame_file(write: Callable[[Path], None], name: str = "f0.png", truth: dict | None = None) -> Mutate:
    def apply(data: dict, tmp: Path) -> None:
        write(tmp / name)
        frame = {"image": name}
        if truth is not None:
            frame["truth"] = truth
        data["sensor"] = {"frames": [frame]}

    return apply


def _png(h: int, w: int) -> Callable[[Path], None]:
    return lambda p: cv2.imwrite(str(p), np.full((h, w, 3), 120, np.uint8))


def _cut_image(ext: str) -> Callable[[Path], None]:
    """An image file cut in half (an interrupted copy): OpenCV alone would decode it with grey rows."""

    def write(p: Path) -> None:
        rng = np.random.default_rng(0)
        ok, data = cv2.imencode(ext, rng.integers(0, 256, (120, 160, 3), dtype=np.uint8))
        assert ok
        p.write_bytes(data.tobytes()[: data.size // 2])

    return write


def _geotiff(heights=None, *, cut: bool = False, bands: int = 1, name: str = "dem.tif", **terrain) -> Mutate:
    """A UTM GeoTIFF DEM (float32; ``bands`` 3: an RGB image), optionally cut in half."""

    def apply(data: dict, tmp: Path) -> None:
        import rasterio
        from rasterio.transform import Affine

        h = np.zeros((96, 96)) if heights is None else np.asarray(heights, float)
        profile = dict(driver="GTiff", width=h.shape[1], height=h.shape[0], crs="EPSG:32617")
        profile["transform"] = Affine(10.0, 0, 500000.0, 0, -10.0, 4000960.0)
        if bands == 3:
            profile.update(count=3, dtype="uint8", photometric="RGB")
        else:
            profile.update(count=1, dtype="float32")
        with rasterio.open(tmp / name, "w", **profile) as ds:
            ds.write(np.zeros((3, *h.shape), np.uint8) if bands == 3 else h[None].astype(np.float32))
        if cut:
            content = (tmp / name).read_bytes()
            (tmp / name).write_bytes(content[: len(content) // 2])
        data["terrain"] = {"dem": name, **terrain}

    return apply


_SPIKY = np.fromfunction(lambda r, c: 0.5 * r + 0.2 * c, (96, 96))
_SPIKY[40, 40] = 5000.0


def _set(path: str, value) -> Mutate:
    """Set a dotted field path (``terrain.cell_size``, ``landmarks.0.x``) to ``value``."""

    def apply(data: dict, tmp: Path) -> None:
        *head, last = path.split(".")
        node = data
        for part in head:
            node = node[int(part)] if isinstance(node, list) else node.setdefault(part, {})
        if isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value

    return apply


def _drop(key: str) -> Mutate:
    return lambda data, tmp: data.pop(key)


def _raw(text: str) -> Mutate:
    """Replace the whole scenario file by ``text``."""

    def apply(data: dict, tmp: Path) -> None:
        data.clear()
        data["__raw__"] = text

    return apply


def _both(*steps: Mutate) -> Mutate:
    def apply(data: dict, tmp: Path) -> None:
        for step in steps:
            step(data, tmp)

    return apply


FC_OK = _fc(_line([[0, 0], [900, 0]], 10.0), _line([[0, 900], [900, 900]], 60.0))

#: (case id, how the small scenario is spoiled, message fragment); every one exits 2
SCENARIOS: list[tuple[str, Mutate, str]] = [
    # the file itself
    ("not-yaml", _raw("name: [unclosed\n  - x: {"), "invalid YAML"),
    ("top-level-list", _raw("- 1\n- 2\n"), "must be a mapping at the top level"),
    ("empty-file", _raw(""), "must be a mapping at the top level"),
    ("unknown-field", _set("colour", "red"), "colour: unknown field"),
    ("path-field", _set("path", "/etc"), "path: unknown field"),
    ("no-name", _drop("name"), "name: is required"),
    ("empty-name", _set("name", ""), "name: must not be empty"),
    ("seed-negative", _set("seed", -1), "seed: must be >= 0"),
    ("seed-text", _set("seed", "x"), "seed: must be an integer"),
    ("seed-huge", _set("seed", 10**30), "seed: must be <="),
    # terrain
    ("no-terrain", _drop("terrain"), "terrain: is required"),
    ("two-sources", _set("terrain.sample", "jacksboro"), "needs exactly one of dem, procedural, contours, sample"),
    ("cell-size-zero", _set("terrain.cell_size", 0), "terrain.cell_size: must be > 0"),
    ("cell-size-inf", _set("terrain.cell_size", float("inf")), "terrain.cell_size: must be a finite number"),
    ("cell-size-nan", _set("terrain.cell_size", float("nan")), "terrain.cell_size: must be a finite number"),
    ("cell-size-1e300", _set("terrain.cell_size", 1e300), "terrain.cell_size: must be <="),
    ("procedural-size-4", _set("terrain.procedural.size", 4), "terrain.procedural.size: must be >= 8"),
    ("relief-negative", _set("terrain.procedural.relief", -1), "terrain.procedural.relief: must be > 0"),
    ("relief-inf", _set("terrain.procedural.relief", float("inf")), "terrain.procedural.relief: must be a finite"),
    ("sample-unknown", _set("terrain", {"cell_size": 10, "sample": "atlantis"}), "terrain.sample: must be one of"),
    ("dem-missing", _set("terrain", {"cell_size": 10, "dem": "nowhere.npy"}), "terrain.dem: file not found"),
    ("dem-1d", _dem(np.arange(50.0)), "DEM must be a 2-D array"),
    ("dem-1x1", _dem(np.zeros((1, 1))), "DEM must be a 2-D array of at least 2x2"),
    ("dem-text", _dem_bytes(b"1 2 3\n4 5 6\n"), "cannot read DEM as a .npy array"),
    ("dem-pickled", _dem_bytes(pickle.dumps(np.zeros((4, 4)))), "cannot read DEM as a .npy array"),
    ("dem-object-array", _dem(np.array([[1, "a"], [None, 2]], dtype=object)), "cannot read DEM"),
    ("dem-strings", _dem(np.array([["a", "b"], ["c", "d"]])), "DEM heights must be real numbers"),
    ("dem-complex", _dem(np.ones((8, 8), complex)), "DEM heights must be real numbers"),
    ("dem-bool", _dem(np.ones((8, 8), bool)), "DEM heights must be real numbers"),
    ("dem-nan", _dem(np.where(np.eye(96) > 0, np.nan, 1.0)), "DEM heights must be finite"),
    ("dem-inf", _dem(np.where(np.eye(96) > 0, np.inf, 1.0)), "DEM heights must be finite"),
    ("dem-1e300", _dem(np.full((96, 96), 1e300)), "not a terrain"),
    ("dem-empty-file", _dem_bytes(b""), "cannot read DEM"),
    ("contours-not-json", _contours(None, raw="{not json"), "not valid GeoJSON"),
    ("contours-not-collection", _contours([1, 2, 3]), "FeatureCollection"),
    ("contours-no-features", _contours(_fc()), "at least one feature"),
    ("contours-no-elevation", _contours(_fc(_line([[0, 0], [900, 0]], None))), "c.geojson: no contour heights: "),
    (
        "contours-3d-not-level",
        _contours(
            _fc(
                {
                    "type": "Feature",
                    "properties": {},
                    "geometry": {"type": "LineString", "coordinates": [[0, 0, 1], [900, 0, 50]]},
                }
            )
        ),
        "features[0]: its z varies along the line (1..50): not a contour line",
    ),
    (
        "contours-attribute-missing",
        lambda d, t: (
            _contours(_fc(_line([[0, 0], [900, 0]], 5), _line([[0, 90], [900, 90]], 9)))(d, t),
            d["terrain"].update(elevation_attribute="hoehe"),
        ),
        "c.geojson: no attribute 'hoehe' with the contour heights (terrain.elevation_attribute); the file has: elevation",
    ),
    ("contours-text-elevation", _contours(_fc(_line([[0, 0], [900, 0]], "high"))), "properties.elevation"),
    (
        "contours-one-elevation",
        _contours(_fc(_line([[0, 0], [900, 0]], 5), _line([[0, 900], [900, 900]], 5))),
        "two or more elevations",
    ),
    (
        "contours-negative",
        _contours(_fc(_line([[-50, 0], [900, 0]], 5), _line([[0, 900], [900, 900]], 9))),
        "must be >= 0",
    ),
    (
        "contours-point",
        _contours(
            _fc(
                {
                    "type": "Feature",
                    "properties": {"elevation": 1},
                    "geometry": {"type": "Point", "coordinates": [1, 2]},
                }
            )
        ),
        "LineString",
    ),
    (
        "contours-one-point-line",
        _contours(_fc(_line([[0, 0]], 5), _line([[0, 900], [900, 900]], 9))),
        "at least 2 finite",
    ),
    # landmarks
    ("landmark-outside", _set("landmarks.0.x", 5000), "landmarks[0]: 'H1' at (5000, 330) is outside the terrain"),
    (
        "landmark-footprint-outside",
        _both(_set("landmarks.0.x", 945), _set("landmarks.0.width", 60)),
        "landmarks[0]: footprint of 'H1' is outside the terrain",
    ),
    ("landmark-x-inf", _set("landmarks.0.x", float("inf")), "landmarks[0].x: must be a finite number"),
    ("landmark-y-nan", _set("landmarks.1.y", float("nan")), "landmarks[1].y: must be a finite number"),
    ("landmark-x-1e300", _set("landmarks.0.x", 1e300), "landmarks[0].x: must be <="),
    ("landmark-height-negative", _set("landmarks.0.height", -3), "landmarks[0].height: must be > 0"),
    ("landmark-width-inf", _set("landmarks.2.width", float("inf")), "landmarks[2].width: must be a finite"),
    ("landmark-yaw-1e300", _set("landmarks.0.yaw_deg", 1e300), "landmarks[0].yaw_deg: must be <="),
    ("landmark-duplicate-id", _set("landmarks.1.id", "H1"), "duplicate landmark id 'H1'"),
    ("landmark-unknown-field", _set("landmarks.0.colour", "red"), "landmarks[0].colour: unknown field"),
    ("landmark-empty-kind", _set("landmarks.0.kind", ""), "landmarks[0].kind: must not be empty"),
    (
        "landmark-kinds-collide",
        _both(_set("landmarks.0.kind", "big house"), _set("landmarks.2.kind", "big_house")),
        "both name the detector agent 'detector-big_house'",
    ),
    # route
    ("route-outside", _set("route.2", [5000, 300]), "route[2]: (5000, 300) is outside the terrain"),
    ("route-inf", _set("route.1", [float("inf"), 3]), "route[1][0]: must be a finite number"),
    ("route-1e300", _set("route.1", [1e300, 3]), "route: point 1 must be finite"),
    ("route-one-point", _set("route", [[220, 260]]), "route: needs at least 2 items"),
    ("route-coincide", _set("route.1", [220, 260]), "points 0 and 1 coincide"),
    ("route-three-numbers", _set("route.0", [1, 2, 3]), "route[0]"),
    ("route-text", _set("route", "north"), "route"),
    # camera
    ("no-camera", _drop("camera"), "camera: is required"),
    ("camera-far-inf", _set("camera.far", float("inf")), "camera.far: must be a finite number"),
    ("camera-far-below-near", _set("camera.far", 0.5), "camera.far: must be > near"),
    ("camera-width-2", _set("camera.width", 2), "camera.width: must be >= 8"),
    ("camera-fov-180", _set("camera.fov_y_deg", 180), "camera.fov_y_deg: must be < 180"),
    ("camera-eye-nan", _set("camera.eye_height", float("nan")), "camera.eye_height: must be a finite"),
    # sensor
    ("no-sensor", _drop("sensor"), "sensor: a run needs camera frames"),
    ("sensor-both", _set("sensor.frames", [{"image": "x.png"}]), "sensor"),
    ("jitter-inf", _set("sensor.simulate.jitter_m", float("inf")), "sensor.simulate.jitter_m: must be a finite"),
    ("jitter-1e300", _set("sensor.simulate.jitter_m", 1e300), "sensor.simulate.jitter_m: must be <= 1000"),
    (
        "jitter-deg-nan",
        _set("sensor.simulate.jitter_deg", float("nan")),
        "sensor.simulate.jitter_deg: must be a finite",
    ),
    ("per-point-zero", _set("sensor.simulate.per_point", 0), "sensor.simulate.per_point: must be >= 1"),
    ("advance-one", _set("sensor.simulate.advance", 1.0), "sensor.simulate.advance: must be < 1"),
    ("lighting-five", _set("sensor.simulate.lighting", 5), "sensor.simulate.lighting: must be <= 1"),
    ("noise-negative", _set("sensor.simulate.noise", -1), "sensor.simulate.noise: must be >= 0"),
    ("frame-missing", _set("sensor", {"frames": [{"image": "nowhere.png"}]}), "file not found"),
    ("frames-empty", _set("sensor", {"frames": []}), "sensor.frames: needs at least 1 items"),
    ("frame-not-image", _frame_file(lambda p: p.write_text("hello")), "sensor.frames[0].image"),
    ("frame-zero-bytes", _frame_file(lambda p: p.write_bytes(b"")), "not a readable image"),
    (
        "frame-npy",
        _frame_file(lambda p: np.save(p, np.zeros((120, 160, 3), np.uint8)), name="f0.npy"),
        "not a readable image",
    ),
    ("frame-1x1", _frame_file(_png(1, 1)), "image is 1x1 pixels; at least 8x8 needed"),
    ("frame-cut-png", _frame_file(_cut_image(".png")), "f0.png: the PNG file is truncated or damaged"),
    ("frame-cut-jpg", _frame_file(_cut_image(".jpg"), name="f0.jpg"), "f0.jpg: the JPEG file is truncated or damaged"),
    ("frame-slit", _frame_file(_png(480, 120)), "sensor.frames[0].image: "),
    (
        "frame-narrow-lens",
        lambda d, t: (_frame_file(_png(120, 160))(d, t), d["sensor"].update(fov_y_deg=10.0)),
        "sees only 21 % of the camera's width and 21 % of its height",
    ),
    ("sensor-fov-simulated", _set("sensor.simulate.fov_y_deg", 50), "sensor.simulate.fov_y_deg: unknown field"),
    ("sensor-fov-no-frames", _set("sensor.fov_y_deg", 50), "fov_y_deg and fov_x_deg describe the images of"),
    ("sensor-fov-x-180", _set("sensor.fov_x_deg", 180), "sensor.fov_x_deg: must be < 180"),
    # raster DEMs as users have them
    ("dem-tif-cut", _geotiff(cut=True), "terrain.dem: "),
    ("dem-tif-rgb", _geotiff(bands=3), "dem.tif: the raster is a colour image (3 band(s): red, green, blue)"),
    ("dem-spikes-refused", _geotiff(_SPIKY, spikes="refuse"), "1 cell(s) stand out from their neighbours by more than"),
    ("dem-spikes-unknown", _geotiff(_SPIKY, spikes="smooth"), "terrain.spikes: must be one of"),
    ("dem-z-scale-zero", _geotiff(z_scale=0), "terrain.z_scale: must be > 0"),
    (
        "frame-truth-inf",
        _frame_file(_png(120, 160), truth={"x": float("inf"), "y": 1, "heading_deg": 0}),
        "sensor.frames[0].truth.x: must be a finite number",
    ),
    # memory, scheduler, expect
    ("memory-size-100", _set("memory", {"size": 100}), "memory.size: must be a power of two"),
    ("memory-shift-65", _set("memory", {"max_shift": [65, 1]}), "memory.max_shift: must be two integers in 0..64"),
    ("memory-blur-inf", _set("memory", {"blur_sigma": float("inf")}), "memory.blur_sigma: must be a finite"),
    (
        "query-timeout-inf",
        _set("scheduler.query_timeout_s", float("inf")),
        "scheduler.query_timeout_s: must be a finite",
    ),
    ("query-timeout-1e300", _set("scheduler.query_timeout_s", 1e300), "scheduler.query_timeout_s: must be <= 3600"),
    ("query-timeout-zero", _set("scheduler.query_timeout_s", 0), "scheduler.query_timeout_s: must be >= 0.01"),
    ("thresholds-crossed", _set("scheduler.absent_threshold", 0.9), "absent_threshold must be <= detector_threshold"),
    ("strategy-unknown", _set("scheduler.strategy", "random"), "scheduler.strategy: must be one of"),
    ("reliability-one", _set("scheduler.reliability", 1.0), "scheduler.reliability: must be < 1"),
    ("candidates-zero", _set("scheduler.candidates", 0), "scheduler.candidates: must be >= 1"),
    ("max-llr-1e300", _set("scheduler.max_llr", 1e300), "scheduler.max_llr: must be <= 20"),
    ("max-llr-inf", _set("scheduler.max_llr", float("inf")), "scheduler.max_llr: must be a finite"),
    ("max-llr-zero", _set("scheduler.max_llr", 0), "scheduler.max_llr: must be > 0"),
    (
        "calibration-1e300",
        _set("scheduler.calibration", {"outline": [1e300, 0, 0, 0, 0, 0]}),
        "scheduler.calibration: outline: every number must be within ±1000",
    ),
    (
        "calibration-four-numbers",
        _set("scheduler.calibration", {"outline": [1, 2, 3, 4]}),
        "scheduler.calibration: outline: a calibration is 6 numbers, [bias, w_statistic",
    ),
    ("expect-top1-two", _set("expect", {"top1_min": 2}), "expect.top1_min: must be <= 1"),
]


def _write(tmp: Path, mutate: Mutate, small_data: dict) -> Path:
    data = small_data
    mutate(data, tmp)
    path = tmp / "bad.yaml"
    if "__raw__" in data:
        path.write_text(data["__raw__"])
    else:
        # yaml.safe_dump writes inf/nan as .inf/.nan, as a user would
        path.write_text(yaml.safe_dump(data))
    return path


def _one_line_error(err: str, fragment: str) -> None:
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("mapinterp"), err
    assert fragment in lines[0], (fragment, err)


def test_the_tables_are_large_enough() -> None:
    assert len(SCENARIOS) >= 60 and len(COMMAND_LINES) >= 30
    assert len({c[0] for c in SCENARIOS}) == len(SCENARIOS)
    assert len({c[0] for c in COMMAND_LINES}) == len(COMMAND_LINES)


@pytest.mark.parametrize("case, mutate, fragment", SCENARIOS, ids=[c[0] for c in SCENARIOS])
def test_malformed_scenario_exits_2_with_one_line(case, mutate, fragment, small_data, tmp_path, capsys) -> None:
    path = _write(tmp_path, mutate, small_data)
    out = tmp_path / "out" / "results.json"
    assert main(["run", str(path), "--no-progress", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    _one_line_error(err, fragment)
    if case not in ("not-yaml", "top-level-list", "empty-file"):
        assert str(path) in err  # names the file
    assert not out.exists()  # nothing ran, nothing written


# -- command lines ---------------------------------------------------------------------------------------


def _results_file(tmp: Path, change: Callable[[dict], None] | None = None, raw: str | None = None) -> str:
    doc = {
        "scenario": "small",
        "strategy": "associative",
        "scenario_path": None,
        "frames": [
            {
                "frame": 0,
                "viewframe": 1,
                "position": [1.0, 2.0],
                "ranking": [[1, 0.5]],
                "truth": None,
                "truth_viewframe": None,
                "correct": None,
            }
        ],
        "summary": {"frames": 1, "top1": None, "mean_queries": 0.0, "mean_error_m": None, "latency_ms_p50": 0.0},
    }
    if change is not None:
        change(doc)
    path = tmp / "r.json"
    path.write_text(raw if raw is not None else json.dumps(doc))
    return str(path)


def _frames(doc: dict, **fields) -> None:
    doc["frames"][0].update(fields)


#: (case id, argv builder(scenario, tmp), message fragment); every one exits 2
COMMAND_LINES: list[tuple[str, Callable[[str, Path], list[str]], str]] = [
    ("rate-zero", lambda s, t: ["run", s, "--rate", "0"], "argument --rate: must be in (0, 10000] Hz, got 0"),
    ("rate-negative", lambda s, t: ["run", s, "--rate", "-1"], "argument --rate: must be in"),
    ("rate-nan", lambda s, t: ["run", s, "--rate", "nan"], "argument --rate: must be in"),
    ("rate-inf", lambda s, t: ["run", s, "--rate", "inf"], "argument --rate: must be in"),
    ("rate-text", lambda s, t: ["run", s, "--rate", "fast"], "argument --rate: must be a number"),
    ("rate-1e-300", lambda s, t: ["run", s, "--rate", "1e-300"], "--rate: 8 frames at 1e-300 Hz take"),
    (
        "rate-too-slow-for-timeout",
        lambda s, t: ["run", s, "--rate", "0.1", "--timeout", "30"],
        "longer than the run's timeout of 30 s",
    ),
    ("timeout-inf", lambda s, t: ["run", s, "--timeout", "inf"], "argument --timeout: must be in"),
    ("timeout-zero", lambda s, t: ["run", s, "--timeout", "0"], "argument --timeout: must be in (0,"),
    ("timeout-negative", lambda s, t: ["run", s, "--timeout", "-5"], "argument --timeout: must be in"),
    ("timeout-nan", lambda s, t: ["run", s, "--timeout", "nan"], "argument --timeout: must be in"),
    ("timeout-1e300", lambda s, t: ["run", s, "--timeout", "1e300"], "argument --timeout: must be in"),
    ("wait-remote-zero", lambda s, t: ["run", s, "--wait-remote", "0"], "argument --wait-remote: must be in"),
    ("wait-remote-nan", lambda s, t: ["run", s, "--wait-remote", "nan"], "argument --wait-remote: must be in"),
    ("out-directory", lambda s, t: ["run", s, "--out", str(t)], "--out: is a folder, not a file"),
    ("out-proc", lambda s, t: ["run", s, "--out", "/proc/version"], "--out: cannot create files in /proc"),
    ("out-under-a-file", lambda s, t: ["run", s, "--out", s + "/r.json"], "is not a folder"),
    ("trace-proc", lambda s, t: ["run", s, "--trace", "/proc/version"], "--trace: cannot create files in /proc"),
    ("trace-directory", lambda s, t: ["run", s, "--trace", str(t)], "--trace: is a folder, not a file"),
    ("trace-dev-null-dir", lambda s, t: ["run", s, "--trace", "/dev/null/t.trace"], "is not a folder"),
    ("strategy-unknown", lambda s, t: ["run", s, "--strategy", "random"], "argument --strategy: invalid choice"),
    ("run-id-bad", lambda s, t: ["run", s, "--run-id", "my run!"], "run id must be 1-128 characters"),
    ("remote-unknown", lambda s, t: ["run", s, "--remote", "detector-church"], "--remote names no agent"),
    ("listen-garbage", lambda s, t: ["run", s, "--listen", "everywhere"], "--listen endpoint must look like"),
    (
        "zenoh-config-missing",
        lambda s, t: ["run", s, "--zenoh-config", str(t / "none.json5")],
        "cannot load zenoh config",
    ),
    ("scenario-missing", lambda s, t: ["run", str(t / "none.yaml")], "none.yaml: file not found"),
    ("scenario-directory", lambda s, t: ["run", str(t)], "cannot read"),
    ("scenario-absent", lambda s, t: ["run"], "the following arguments are required: scenario"),
    ("unknown-option", lambda s, t: ["run", s, "--fast"], "unrecognized arguments: --fast"),
    ("unknown-command", lambda s, t: ["fly", s], "argument COMMAND: invalid choice: 'fly'"),
    (
        "report-wrong-typed-viewframe",
        lambda s, t: ["report", _results_file(t, lambda d: _frames(d, viewframe="x")), "--out", str(t / "rep")],
        "frames[0].viewframe: must be an integer",
    ),
    (
        "report-wrong-typed-position",
        lambda s, t: ["report", _results_file(t, lambda d: _frames(d, position="here")), "--out", str(t / "rep")],
        "frames[0].position",
    ),
    (
        "report-frames-not-list",
        lambda s, t: ["report", _results_file(t, lambda d: d.update(frames=3)), "--out", str(t / "rep")],
        "frames: must be a list",
    ),
    (
        "report-top1-text",
        lambda s, t: ["report", _results_file(t, lambda d: d["summary"].update(top1="high")), "--out", str(t / "rep")],
        "summary.top1: must be a number",
    ),
    (
        "report-infinity",
        lambda s, t: [
            "report",
            _results_file(t, raw='{"scenario": "s", "strategy": "a", "frames": [], "summary": {"frames": Infinity}}'),
            "--out",
            str(t / "rep"),
        ],
        "summary.frames",
    ),
    (
        "report-not-json",
        lambda s, t: ["report", _results_file(t, raw="{oops"), "--out", str(t / "rep")],
        "not a JSON results file",
    ),
    (
        "report-missing-field",
        lambda s, t: ["report", _results_file(t, lambda d: d.pop("summary")), "--out", str(t / "rep")],
        "missing field 'summary'",
    ),
    (
        "report-missing-file",
        lambda s, t: ["report", str(t / "none.json"), "--out", str(t / "rep")],
        "results file not found",
    ),
    (
        "report-max-frames-negative",
        lambda s, t: ["report", _results_file(t), "--out", str(t / "rep"), "--max-frames", "-1"],
        "argument --max-frames: must be in",
    ),
    ("trace-missing", lambda s, t: ["trace", str(t / "none.trace")], "none.trace"),
    (
        "agent-connect-timeout-nan",
        lambda s, t: ["agent", "x:Y", "--name", "a", "--run-id", "r", "--connect-timeout", "nan"],
        "argument --connect-timeout: must be in",
    ),
    ("agent-run-id-bad", lambda s, t: ["agent", "x:Y", "--name", "a", "--run-id", "r/x"], "run id must be"),
]


@pytest.mark.parametrize("case, argv, fragment", COMMAND_LINES, ids=[c[0] for c in COMMAND_LINES])
def test_bad_command_line_exits_2_with_one_line(case, argv, fragment, small, tmp_path, capsys) -> None:
    assert (
        main(
            [*argv(str(small), tmp_path), "--no-progress"]
            if argv(str(small), tmp_path)[:1] == ["run"]
            else argv(str(small), tmp_path)
        )
        == 2
    )
    _one_line_error(capsys.readouterr().err, fragment)


# -- a subset as real processes: exit status, stderr, no traceback, no hang ------------------------------

_SUBPROCESS_SCENARIOS = [
    "dem-strings",
    "contours-one-elevation",
    "landmark-outside",
    "frame-1x1",
    "frame-cut-jpg",
    "frame-slit",
    "dem-tif-cut",
    "query-timeout-inf",
    "cell-size-inf",
    "jitter-inf",
    "route-1e300",
]
_SUBPROCESS_COMMANDS = [
    "rate-nan",
    "rate-1e-300",
    "timeout-inf",
    "out-directory",
    "trace-proc",
    "report-wrong-typed-viewframe",
]


def _mapinterp(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.getcwd(), *sys.path])}
    return subprocess.run(
        [sys.executable, "-m", "knowledge_sources.cli", *argv],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.slow
@pytest.mark.parametrize("case", _SUBPROCESS_SCENARIOS)
def test_malformed_scenario_in_a_real_process(case, small_data, tmp_path) -> None:
    _, mutate, fragment = next(c for c in SCENARIOS if c[0] == case)
    path = _write(tmp_path, mutate, small_data)
    done = _mapinterp(["run", str(path), "--no-progress"], tmp_path)
    assert done.returncode == 2, done.stderr
    _one_line_error(done.stderr, fragment)


@pytest.mark.slow
@pytest.mark.parametrize("case", _SUBPROCESS_COMMANDS)
def test_bad_command_line_in_a_real_process(case, small, tmp_path) -> None:
    _, argv, fragment = next(c for c in COMMAND_LINES if c[0] == case)
    done = _mapinterp(argv(str(small), tmp_path), tmp_path)
    assert done.returncode == 2, done.stderr
    _one_line_error(done.stderr, fragment)
