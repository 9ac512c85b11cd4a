"""``mapinterp table``: the Table A analogue, real rendering (pyrender on EGL) and real files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from knowledge_sources.cli import main
from knowledge_sources.commands.table import TableRow, format_table

ROOT = Path(__file__).resolve().parents[2]
TABLE_A = ROOT / "scenarios" / "table_a.yaml"


def test_table_a_every_row_minimum_is_on_the_diagonal(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["table", str(TABLE_A), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    rows = doc["rows"]
    assert [v["index"] for v in doc["viewframes"]] == [0, 1, 2, 3]
    assert len(rows) == 4
    for i, row in enumerate(rows):
        variances = np.asarray(row["variances"])
        assert variances.shape == (4,)
        assert int(np.argmin(variances)) == i == row["best"] == row["truth_viewframe"]
        assert row["correct"] is True
        # a real error variance of unit-energy images: 0 < v < 4 / N^2
        assert np.all((variances > 0) & (variances < 4.0 / 128**2))


def test_table_a_text_marks_the_minimum(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["table", str(TABLE_A)]) == 0
    out = capsys.readouterr().out
    assert "4/4 rows have their minimum on the truth viewframe" in out
    rows = [[c.strip() for c in ln.split("│")[1:-1]] for ln in out.splitlines() if ln.startswith("│ frame_")]
    assert len(rows) == 4  # a rich table: one row per camera image
    for i, cells in enumerate(rows):
        assert [c.endswith("*") for c in cells[1:5]] == [j == i for j in range(4)]
        assert cells[-1] == f"V{i} ok"


def _write_scenario(tmp_path: Path, **changes) -> Path:
    data = yaml.safe_load(TABLE_A.read_text())
    for frame in data["sensor"]["frames"]:
        frame["image"] = str(TABLE_A.parent / frame["image"])
    data.update(changes)
    data = {k: v for k, v in data.items() if v is not None}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"sensor": None}, "sensor"),
        ({"sensor": {"frames": [{"image": "missing.png"}]}}, "missing.png"),
        ({"memory": {"size": 100}}, "memory.size"),
    ],
)
def test_bad_scenarios_give_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], changes: dict, message: str
) -> None:
    assert main(["table", str(_write_scenario(tmp_path, **changes))]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mapinterp table: error:") and message in err
    assert "\n" not in err


def test_unreadable_camera_image_names_the_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "broken.png"
    bad.write_bytes(b"not a png")
    path = _write_scenario(tmp_path, sensor={"frames": [{"image": str(bad)}]})
    assert main(["table", str(path)]) == 2
    assert "broken.png" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("rows", "summary"),
    [
        ([TableRow(0, "a.png", [1e-4, 2e-4], 0, 3.0, 0), TableRow(1, "b.png", [1e-4, 2e-4], 0, 1.0, 1)], "1/2 rows"),
        ([TableRow(0, "simulated", [2e-4, 1e-4], 1, 0.5, None)], None),
    ],
)
def test_format_table(rows: list[TableRow], summary: str | None) -> None:
    text = format_table("x", [0, 1], rows, size=128)
    body = text.splitlines()[3:]
    for row, line in zip(rows, body):
        assert line.count("*") == 1
        assert ("WRONG" in line) == (row.correct is False)
    assert (summary in text) if summary else ("rows have their minimum" not in text)


def test_with_viewframes_between_the_route_points_a_rows_truth_is_the_nearest_viewframe(
    small_data, tmp_path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The table's columns are every viewframe; a frame's truth is the viewframe nearest its true
    pose: SMALL's frames stand at their route points (5 % of a leg on), so the viewframe on the
    point, 3 k for frame k, not the route point's index k."""
    from models.route_views import view_count

    path = tmp_path / "views.yaml"
    path.write_text(yaml.safe_dump({**small_data, "render": {"views_per_leg": 3}}))
    assert main(["table", str(path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert len(doc["viewframes"]) == view_count(len(small_data["route"]), 3)
    assert [row["truth_viewframe"] for row in doc["rows"]] == [3 * row["frame"] for row in doc["rows"]]
