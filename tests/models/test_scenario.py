"""Scenario files: bundled ones load, malformed ones fail naming file, field and problem."""

from __future__ import annotations

from pathlib import Path

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


@pytest.mark.parametrize("name", ["hills", "jacksboro", "contours"])
def test_bundled_scenarios_load(name):
    s = load_scenario(SCENARIOS / f"{name}.yaml")
    assert s.name == name and s.path == SCENARIOS / f"{name}.yaml"
    assert s.base_dir == SCENARIOS
    assert len(s.route) >= 20 and len(s.landmarks) >= 5
    assert s.sensor is not None and s.sensor.simulate is not None


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
    ("expect", {"top1_min": 2}, "expect.top1_min: must be <= 1"),
    ("name", "", "name: must not be empty"),
    ("speed", 3, "speed: unknown field"),
]


@pytest.mark.parametrize(("field", "value", "message"), MALFORMED, ids=[m[2].split(":")[0] + "-" + str(i)
                                                                      for i, m in enumerate(MALFORMED)])
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


@pytest.mark.parametrize("terrain", [
    {"cell_size": 10.0},
    {"cell_size": 10.0, "sample": "jacksboro", "procedural": {"size": 32, "relief": 1.0}},
])
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


@pytest.mark.parametrize(("text", "message"), [
    ("name: [unclosed", "invalid YAML"),
    ("- just\n- a list\n", "must be a mapping at the top level, not list"),
    ("", "must be a mapping at the top level, not NoneType"),
])
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
