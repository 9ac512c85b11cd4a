"""``mapinterp render``: files written for a small scenario, a bundled one, and clean errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import pytest
import yaml

from knowledge_sources.cli import main
from models.route_views import view_count, view_route
from models.scenario import DENSE_VIEWS_PER_LEG

ROOT = Path(__file__).resolve().parents[2]

SMALL = {
    "name": "small",
    "seed": 4,
    "terrain": {"cell_size": 10.0, "procedural": {"size": 64, "relief": 40.0, "seed": 2}},
    "landmarks": [
        {"id": "H1", "kind": "house", "x": 260.0, "y": 320.0, "width": 20, "depth": 12, "height": 8},
        {"id": "T1", "kind": "tower", "x": 500.0, "y": 100.0, "width": 4, "depth": 4, "height": 30},
    ],
    "route": [[200, 300], [240, 310], [300, 300]],
    "camera": {"width": 160, "height": 120, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 2000.0},
}


def _scenario(tmp_path: Path, data: dict) -> Path:
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_render_writes_frames_descriptions_priors_and_overview(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["render", str(_scenario(tmp_path, SMALL)), "--out", str(out)]) == 0
    views = view_count(3, DENSE_VIEWS_PER_LEG)  # a short route: viewframes between the route points too
    assert f"small: {views} viewframes" in capsys.readouterr().out
    places = view_route(SMALL["route"], DENSE_VIEWS_PER_LEG)[0]
    for i in range(views):
        img = cv2.imread(str(out / f"vf_{i:03d}.png"))
        assert img.shape == (120, 160, 3)
        doc = json.loads((out / f"vf_{i:03d}.json").read_text())
        assert doc["index"] == i and set(doc["pose"]) == {"x", "y", "z", "heading_deg", "pitch_deg"}
        assert [doc["pose"]["x"], doc["pose"]["y"]] == pytest.approx(places[i].tolist())
    first = json.loads((out / "vf_000.json").read_text())["description"]
    assert "H1" in first["visible"] and first["nodes"]["H1"]["kind"] == "house"
    priors = json.loads((out / "priors.json").read_text())
    assert set(priors) == {"H1", "T1"} and 0 < priors["H1"] <= 1
    overview = cv2.imread(str(out / "overview.png"))
    assert overview is not None and overview.shape[0] > 300 and overview.shape[1] > 300


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"landmarks": [{**SMALL["landmarks"][0], "height": 0}]}, "landmarks[0].height: must be > 0"),
        ({"route": [[200, 300], [2000, 300]]}, "route[1]: (2000, 300) is outside the terrain"),
        ({"terrain": {"cell_size": 10.0, "contours": "nowhere.geojson"}}, "terrain.contours: file not found"),
    ],
)
def test_user_mistakes_are_one_line_errors(tmp_path, capsys, change, message):
    path = _scenario(tmp_path, {**SMALL, **change})
    assert main(["render", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"mapinterp render: error: {path}: {message}" or err.startswith(
        f"mapinterp render: error: {path}: {message}"
    )
    assert "\n" not in err


def test_bad_contour_file_names_the_file(tmp_path, capsys):
    (tmp_path / "c.geojson").write_text('{"type": "FeatureCollection", "features": []}')
    path = _scenario(tmp_path, {**SMALL, "terrain": {"cell_size": 10.0, "contours": "c.geojson"}})
    assert main(["render", str(path), "--out", str(tmp_path / "o")]) == 2
    assert f"{tmp_path / 'c.geojson'}: expected a GeoJSON FeatureCollection" in capsys.readouterr().err


@pytest.mark.slow
def test_render_bundled_hills_scenario_from_the_console_script(tmp_path):
    out = tmp_path / "hills"
    exe = Path(sys.executable).with_name("mapinterp")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "knowledge_sources.cli"]
    proc = subprocess.run(
        [*cmd, "render", str(ROOT / "scenarios" / "hills.yaml"), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    frames = sorted(out.glob("vf_*.png"))
    assert len(frames) == view_count(30, DENSE_VIEWS_PER_LEG) and (out / "overview.png").exists()
    docs = [json.loads(p.with_suffix(".json").read_text()) for p in frames]
    counts = [len(d["description"]["visible"]) for d in docs]
    assert sum(c > 0 for c in counts) >= len(counts) // 2  # landmarks are seen along the route
    assert max(counts) <= 4
    # the camera sees terrain relief: every frame has both sky and ground
    for p in frames[::5]:
        img = cv2.imread(str(p))
        sky = (img == img[0, 0]).all(axis=2).mean()
        assert 0.05 < sky < 0.95
