"""``mapinterp run`` and ``mapinterp report`` from the command line, on real files."""

from __future__ import annotations

import json

import cv2
import pytest
import yaml

from knowledge_sources.cli import main

pytestmark = pytest.mark.slow


def test_run_then_report(small, tmp_path, capsys):
    out, trace = tmp_path / "out" / "results.json", tmp_path / "out" / "run.trace"
    assert main(["run", str(small), "--out", str(out), "--trace", str(trace), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "top-1" in printed and "mean queries" in printed  # the summary table
    results = json.loads(out.read_text())
    assert results["scenario"] == "small" and len(results["frames"]) == 8
    assert trace.stat().st_size > 0

    prior = tmp_path / "out" / "prior.json"
    assert main(["run", str(small), "--strategy", "prior", "--out", str(prior), "--no-progress"]) == 0
    report = tmp_path / "report"
    assert main(["report", str(out), str(prior), "--out", str(report), "--max-frames", "3"]) == 0
    for name in ("positions.png", "track.png", "belief.png", "rankings.png", "queries.png", "frames/frame_000.png",
                 "frames/frame_002.png"):
        img = cv2.imread(str(report / name))
        assert img is not None and img.shape[0] > 200 and img.std() > 5, name  # a real, non-blank figure
    assert not (report / "frames" / "frame_003.png").exists()  # --max-frames honoured
    md = (report / "report.md").read_text()
    assert "| associative |" in md and "| prior |" in md


def test_run_malformed_scenario_is_one_clear_line(small_data, tmp_path, capsys):
    small_data["camera"]["fov_y_deg"] = 200
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(small_data))
    assert main(["run", str(path), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and "camera.fov_y_deg" in err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "content, message",
    [(None, "results file not found"), ("{not json", "not a JSON results file"), ('{"frames": []}', "missing field")],
)
def test_report_bad_results_file(tmp_path, capsys, content, message):
    path = tmp_path / "results.json"
    if content is not None:
        path.write_text(content)
    assert main(["report", str(path), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "results.json" in err and message in err
