"""Scenario files: bundled ones load, malformed ones fail naming file, field and problem."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from pydantic import ValidationError

from models.errors import ModelError, ScenarioError
from models.scenario import Scenario, load_scenario, scenario_from_dict

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"

VALID = {
    "name": "t",
    "seed": 1,
    "terrain": {"cell_size": 10.0, "procedural": {"size": 32, "relief": 20.0}},
    "landmarks": [{"id": "H1", "kind": "house", "x": 100.0, "y": 120.0, "width": 20, "depth": 12, "height": 8}],
    "route": [[50, 50], [90, 60], [130, 80]],
    "camera": {"width": 160, "height": 120, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 2000.0},
    "sensor": {"simulate": {"per_point": 2}},
}


def _with(path: str, value):
    """A copy of VALID with ``path`` (dots, [i]) set to ``value`` (``...`` deletes it)."""
    data = yaml.safe_load(yaml.safe_dump(VALID))
    parts = path.replace("[", ".").replace("]", "").split(".")
    node = data
    for p in parts[:-1]:
        node = node[int(p)] if p.isdigit() else node.setdefault(p, {})
    last = int(parts[-1]) if parts[-1].isdigit() else parts[-1]
    if value is ...:
        del node[last]
    else:
        node[last] = value
    return data


@pytest.mark.parametrize("name", ["hills", "jacksboro", "contours", "jacksboro_geo"])
def test_bundled_scenarios_load(name):
    s = load_scenario(SCENARIOS / f"{name}.yaml")
    assert s.name == name and s.path == SCENARIOS / f"{name}.yaml"
    assert s.base_dir == SCENARIOS
    assert len(s.route) >= 20 and len(s.landmarks) >= 5
    assert s.sensor is not None and s.sensor.simulate is not None


def test_bundled_lonlat_scenario_lies_on_its_geotiff():
    """jacksboro_geo: lon/lat route on a lon/lat GeoTIFF, converted to local metres inside the DEM."""
    from models.terrain_sources import load_terrain

    s = load_scenario(SCENARIOS / "jacksboro_geo.yaml")
    assert s.crs == "EPSG:4326" and s.map_frame is not None and s.map_frame.name == "EPSG:4326"
    t = load_terrain(s.terrain, base_dir=s.base_dir, seed=s.seed)
    assert 70 < t.cell_size < 80  # 3 arc-seconds east-west at 36.6 N, the smaller ground side
    assert all(t.contains(x, y) for x, y in s.route)
    # consecutive route points are 50 m apart on the ground (they were laid out in metres)
    steps = np.hypot(*np.diff(np.asarray(s.route), axis=0).T)
    np.testing.assert_allclose(steps, 50.0, atol=0.15)  # drive() rounds to 0.1 m
    # heights agree with the raw npz shipped with matplotlib at the first route point's cell
    from matplotlib import cbook

    lon, lat = s.map_frame.to_lonlat(*s.route[0])
    with cbook.get_sample_data("jacksboro_fault_dem.npz") as raw:
        z, west, north, d = raw["elevation"], float(raw["xmin"]), float(raw["ymin"]), float(raw["dx"])
    r, c = (north - float(lat)) / d - 0.5, (float(lon) - west) / d - 0.5
    r0, c0 = int(r), int(c)
    near = z[r0 : r0 + 2, c0 : c0 + 2].astype(float)
    assert near.min() - 1 <= t.height_at(*s.route[0]) <= near.max() + 1


def test_valid_scenario_defaults(tmp_path):
    path = tmp_path / "ok.yaml"
    path.write_text(yaml.safe_dump(VALID))
    s = load_scenario(path)
    assert isinstance(s, Scenario)
    assert s.memory.size == 128 and s.memory.edge == "sobel"
    assert s.scheduler.strategy == "associative" and s.scheduler.candidates == 8
    assert s.sensor.simulate.per_point == 2 and s.sensor.simulate.seed is None
    assert s.landmarks[0].yaw_deg == 0.0 and s.camera.pitch_deg == 0.0
    assert s.route[1] == (90.0, 60.0)


MALFORMED = [
    ("landmarks[0].height", -1, "landmarks[0].height: must be > 0"),
    ("landmarks[0].width", 0, "landmarks[0].width: must be > 0"),
    ("landmarks[0].x", "east", "landmarks[0].x: must be a number"),
    ("landmarks[0].colour", "red", "landmarks[0].colour: unknown field"),
    ("landmarks[0].id", ..., "landmarks[0].id: is required"),
    ("camera.far", 0.5, "camera.far: must be > near (1)"),
    ("camera.fov_y_deg", 180, "camera.fov_y_deg: must be < 180"),
    ("camera.width", 160.5, "camera.width: must be an integer"),
    ("camera", ..., "camera: is required"),
    ("route", [[0, 0]], "route: needs at least 2 items"),
    ("route", [[0, 0], [0, 0]], "route: points 0 and 1 coincide"),
    ("route", [[0, 0], [1, 2, 3]], "route[1]: allows at most 2 items"),
    ("route", [[0, 0], [1, "x"]], "route[1][1]: must be a number"),
    ("terrain.dem", "missing.npy", "terrain.dem: file not found"),
    ("terrain.sample", "everest", "terrain.sample: must be one of 'jacksboro'"),
    ("terrain.cell_size", 0, "terrain.cell_size: must be > 0"),
    ("terrain.procedural.relief", -5, "terrain.procedural.relief: must be > 0"),
    ("sensor", {}, "sensor: needs exactly one of frames, simulate"),
    ("sensor", {"frames": [{"image": "f000.png"}]}, "sensor.frames[0].image: file not found"),
    ("sensor.simulate.advance", 1.0, "sensor.simulate.advance: must be < 1"),
    ("sensor.simulate.noise", -1, "sensor.simulate.noise: must be >= 0"),
    ("memory", {"size": 100}, "memory.size: must be a power of two in 16..1024"),
    ("memory", {"edge": "laplace"}, "memory.edge: must be one of 'sobel', 'scharr', 'laplacian', 'canny' or 'none'"),
    ("scheduler", {"accept": 1.5}, "scheduler.accept: must be <= 1"),
    ("scheduler", {"strategy": "random"}, "scheduler.strategy: must be one of 'associative' or 'prior'"),
    ("scheduler", {"backtracking": "firm"}, "scheduler.backtracking: must be one of 'hard' or 'soft'"),
    ("scheduler", {"questions": "any"}, "scheduler.questions: must be one of 'information' or 'probability'"),
    ("scheduler", {"floor": 1.0}, "scheduler.floor: must be < 1"),
    ("scheduler", {"max_llr": 0}, "scheduler.max_llr: must be > 0"),
    ("scheduler", {"neighbour_visibility": 0.7}, "scheduler.neighbour_visibility: must be <= 0.5"),
    ("scheduler", {"align_deg": [2.0, 60.0]}, "scheduler.align_deg: must be two angles in [0, 45) degrees"),
    ("scheduler", {"calibration": {"house": [1.0, 2.0]}}, "scheduler.calibration: house: a calibration is 6 numbers"),
    ("scheduler", {"detector_scales": [1.0, 8.0]}, "scheduler.detector_scales: every scale must be within [0.25, 4]"),
    ("scheduler", {"detector_scales": []}, "scheduler.detector_scales"),
    ("scheduler", {"position_spread": [1.0, 0.0, 0.2]}, "scheduler.position_spread: must be three values in (0, 90]"),
    ("scheduler", {"position_dof": 0}, "scheduler.position_dof: must be > 0"),
    ("scheduler", {"max_position_llr": 50}, "scheduler.max_position_llr: must be <= 20"),
    ("scheduler", {"position_evidence": "maybe"}, "scheduler.position_evidence"),
    ("skyline", {"coarse_candidates": 0}, "skyline.coarse_candidates: must be >= 1"),
    ("memory", {"coarse_candidates": 0}, "memory.coarse_candidates: must be >= 1"),
    ("skyline", {"coarse_candidates": 2.5}, "skyline.coarse_candidates: must be an integer"),
    ("expect", {"top1_min": 2}, "expect.top1_min: must be <= 1"),
    ("expect", {"top1_frame_only_min": 1.5}, "expect.top1_frame_only_min: must be <= 1"),
    ("tracking", {"cell_m": 1e9}, "tracking.cell_m: must be <= 10000"),
    ("tracking", {"temperature": float("inf")}, "tracking.temperature: must be a finite number"),
    ("tracking", {"gain": float("nan")}, "tracking.gain: must be a finite number"),
    ("tracking", {"max_speed_mps": 5000}, "tracking.max_speed_mps: must be <= 1000"),
    ("sensor.simulate.drive", {"interval_s": 1e6}, "sensor.simulate.drive.interval_s: must be <= 3600"),
    ("sensor.simulate.drive", {"frames": 10**7}, "sensor.simulate.drive.frames: must be <= 1000000"),
    ("sensor.simulate.drive", {"speed_mps": [1, 1e9]}, "sensor.simulate.drive.speed_mps: must be [min, max]"),
    ("name", "", "name: must not be empty"),
    ("speed", 3, "speed: unknown field"),
]


@pytest.mark.parametrize(
    ("field", "value", "message"), MALFORMED, ids=[m[2].split(":")[0] + "-" + str(i) for i, m in enumerate(MALFORMED)]
)
def test_malformed_scenario_names_file_field_and_problem(tmp_path, field, value, message):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(_with(field, value)))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert str(info.value).startswith(f"{path}: {message}")
    assert info.value.path == path
    assert isinstance(info.value, ModelError)


def test_duplicate_landmark_ids(tmp_path):
    data = _with("landmarks", VALID["landmarks"] * 2)
    with pytest.raises(ScenarioError, match=r"landmarks: duplicate landmark id 'H1'"):
        scenario_from_dict(data, path=tmp_path / "x.yaml")


@pytest.mark.parametrize(
    "terrain",
    [
        {"cell_size": 10.0},
        {"cell_size": 10.0, "sample": "jacksboro", "procedural": {"size": 32, "relief": 1.0}},
    ],
)
def test_terrain_needs_exactly_one_source(terrain):
    with pytest.raises(ScenarioError, match=r"^terrain: needs exactly one of dem, procedural, contours, sample"):
        scenario_from_dict(_with("terrain", terrain))


def test_relative_paths_resolve_against_the_scenario_folder(tmp_path, monkeypatch):
    (tmp_path / "sub" / "frames").mkdir(parents=True)
    (tmp_path / "sub" / "frames" / "f000.png").write_bytes(b"not checked here")
    (tmp_path / "sub" / "dem.npy").write_bytes(b"")
    data = _with("sensor", {"frames": [{"image": "frames/f000.png", "truth": {"x": 1, "y": 2, "heading_deg": 3}}]})
    data["terrain"] = {"cell_size": 5.0, "dem": "dem.npy"}
    path = tmp_path / "sub" / "s.yaml"
    path.write_text(yaml.safe_dump(data))
    monkeypatch.chdir(tmp_path)  # the cwd must not matter
    s = load_scenario(Path("sub/s.yaml"))
    assert s.sensor.frames[0].image == (tmp_path / "sub" / "frames" / "f000.png")
    assert s.terrain.dem == tmp_path / "sub" / "dem.npy"
    assert s.sensor.frames[0].truth.heading_deg == 3.0


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("name: [unclosed", "invalid YAML"),
        ("- just\n- a list\n", "must be a mapping at the top level, not list"),
        ("", "must be a mapping at the top level, not NoneType"),
    ],
)
def test_unparsable_files(tmp_path, text, message):
    path = tmp_path / "s.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError, match=message):
        load_scenario(path)


def test_missing_file(tmp_path):
    with pytest.raises(ScenarioError, match="nope.yaml: file not found"):
        load_scenario(tmp_path / "nope.yaml")


def test_path_is_not_an_input_field():
    with pytest.raises(ScenarioError, match="^path: unknown field"):
        scenario_from_dict({**VALID, "path": "/etc"})


def test_scenario_is_frozen():
    s = scenario_from_dict(VALID)
    with pytest.raises(ValidationError):
        s.seed = 3


def test_every_problem_is_listed_at_once_with_did_you_mean(tmp_path):
    data = _with("camera.fov_y_deg", 200)
    data["terrain"] = {**data["terrain"], "cell_sise": 10.0}
    data["camera"]["pich_deg"] = 2.0
    data["landmarks"][0]["height"] = -1
    data["landmarks"][0]["colour"] = "red"
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    lines = str(info.value).splitlines()
    assert all(line.startswith(f"{path}: ") for line in lines)
    got = {line[len(f"{path}: ") :] for line in lines}
    assert got == {
        "terrain.cell_sise: unknown field (did you mean cell_size?)",
        "camera.pich_deg: unknown field (did you mean pitch_deg?)",
        "camera.fov_y_deg: must be < 180",
        "landmarks[0].height: must be > 0",
        "landmarks[0].colour: unknown field (known: id, kind, x, y, width, depth, height, yaw_deg)",
    }
    assert len(info.value.problems) == 5 and info.value.field == lines[0][len(f"{path}: ") :].split(":")[0]


def test_json_schema_covers_the_bundled_scenarios():
    """The schema `mapinterp schema` prints names every field the bundled scenarios use."""
    schema = Scenario.model_json_schema()
    defs = schema.get("$defs", {})

    def fields_of(node):
        if "$ref" in node:
            node = defs[node["$ref"].split("/")[-1]]
        for key in ("anyOf", "allOf"):
            for sub in node.get(key, []):
                yield from fields_of(sub)
        yield from node.get("properties", {}).items()

    def walk(value, node, where):
        if isinstance(value, dict):
            props = dict(fields_of(node))
            for k, v in value.items():
                assert k in props, f"{where}.{k} not in the schema"
                walk(v, props[k], f"{where}.{k}")
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            items = next((n["items"] for n in [node, *node.get("anyOf", [])] if "items" in n), {})
            for i, v in enumerate(value):
                walk(v, items, f"{where}[{i}]")

    for path in sorted(SCENARIOS.glob("*.yaml")):
        walk(yaml.safe_load(path.read_text()), schema, path.name)


def test_readme_documents_every_field_the_bundled_scenarios_use():
    import re

    readme = (SCENARIOS.parent / "README.md").read_text(encoding="utf-8")
    documented: set[str] = set()
    for line in readme.splitlines():
        if not line.startswith("| `"):
            continue
        names = re.findall(r"`([^`]+)`", line.split("|")[1])
        if not names:
            continue
        first = names[0]
        documented.add(first)
        base = first.rsplit(".", 1)[0] if "." in first else ""
        documented |= {base + n for n in names[1:] if n.startswith(".")}
    used: set[str] = set()

    def walk(value, where):
        if isinstance(value, dict):
            for k, v in value.items():
                walk(v, f"{where}.{k}" if where else k)
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            for v in value:
                walk(v, where + "[]")
        else:
            used.add(where)

    for path in SCENARIOS.glob("*.yaml"):
        walk(yaml.safe_load(path.read_text()), "")
    wild = {d[:-1] for d in documented if d.endswith("*")}
    missing = sorted(u for u in used if u not in documented and not any(u.startswith(w) for w in wild))
    assert not missing, f"README.md does not document {missing}"


#: numeric fields bounded by a validator rather than by Field(ge/le): (spec, field, a value out of bounds)
_VALIDATED_NUMBERS = {
    ("Scenario", "route"): [[0.0, 0.0], [1e300, 0.0]],
    ("DriveSpec", "speed_mps"): (1.0, 1e300),
    ("MemorySpec", "size"): 2**40,
    ("MemorySpec", "max_shift"): (1, 10**9),
    ("MemorySpec", "roll_search_deg"): (0.0, 1e300),
    ("VerifySpec", "roll_search_deg"): (0.0, 1e300),
    ("SchedulerSpec", "align_deg"): (1.0, 1e300),
    ("SchedulerSpec", "detector_scales"): (1.0, 1e300),
    ("SchedulerSpec", "position_spread"): (1.0, 1.0, 1e300),
    ("SchedulerSpec", "calibration"): {"outline": (1e300, 0.0, 0.0, 0.0, 0.0, 0.0)},
}


def _numeric_fields():
    """Every (spec class, field name, field info) of the schema that holds numbers."""
    import inspect
    import typing

    from pydantic import BaseModel

    seen: set[type] = set()
    todo: list[type[BaseModel]] = [Scenario]
    while todo:
        spec = todo.pop()
        if spec in seen:
            continue
        seen.add(spec)
        for name, info in spec.model_fields.items():
            leaves, stack = [], [info.annotation]
            while stack:
                t = stack.pop()
                args = typing.get_args(t)
                stack.extend(args) if args else leaves.append(t)
            if any(t in (int, float) for t in leaves):
                yield spec, name, info
            todo.extend(t for t in leaves if inspect.isclass(t) and issubclass(t, BaseModel))


def test_every_number_of_the_schema_has_both_bounds():
    import annotated_types as at

    found = set()
    for spec, name, info in _numeric_fields():
        lower = any(isinstance(m, (at.Ge, at.Gt)) for m in info.metadata)
        upper = any(isinstance(m, (at.Le, at.Lt)) for m in info.metadata)
        if not (lower and upper):
            assert (spec.__name__, name) in _VALIDATED_NUMBERS, f"{spec.__name__}.{name} has no upper or lower bound"
            found.add((spec.__name__, name))
    assert found == set(_VALIDATED_NUMBERS)  # the table is not stale
    assert len(list(_numeric_fields())) > 80


@pytest.mark.parametrize("spec_field", sorted(_VALIDATED_NUMBERS), ids=lambda c: ".".join(c))
def test_numbers_bounded_by_a_validator_refuse_a_huge_value(spec_field):
    import models.scenario as schema

    spec_name, name = spec_field
    value = _VALIDATED_NUMBERS[spec_field]
    if spec_name == "Scenario":
        with pytest.raises(ScenarioError, match=name):
            scenario_from_dict({**VALID, name: value})
    else:
        with pytest.raises(ValidationError, match=name):
            getattr(schema, spec_name).model_validate({name: value})
