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
    from knowledge_sources.html_report import frame_order

    detailed = [f["frame"] for f in frame_order(results["frames"])[:3]]  # wrong frames first
    for name in (
        "positions.png",
        "track.png",
        "belief.png",
        "rankings.png",
        "queries.png",
        *(f"frames/frame_{i:03d}.png" for i in detailed),
    ):
        img = cv2.imread(str(report / name))
        assert img is not None and img.shape[0] > 200 and img.std() > 5, name  # a real, non-blank figure
    left_out = sorted(set(range(8)) - set(detailed))
    assert not any((report / "frames" / f"frame_{i:03d}.png").exists() for i in left_out)  # --max-frames honoured
    md = (report / "report.md").read_text()
    assert "| associative |" in md and "| prior |" in md
    _check_html(report, results, json.loads(prior.read_text()), detailed)


def _check_html(report, results, prior, detailed) -> None:
    """index.html parsed: every image and link it refers to exists, frames wrong-first, both runs shown."""
    from html.parser import HTMLParser

    class Page(HTMLParser):
        def __init__(self) -> None:
            super().__init__()
            self.refs, self.ids, self.rows, self.sections = [], set(), [], []
            self._row: list[str] | None = None
            self._cell: list[str] | None = None

        def handle_starttag(self, tag, attrs):
            a = dict(attrs)
            for key in ("src", "href"):
                if a.get(key):
                    self.refs.append(a[key])
            if a.get("id"):
                self.ids.add(a["id"])
                if tag == "section":
                    self.sections.append(a["id"])
            if tag == "tr":
                self._row = []
            if tag in ("td", "th") and self._row is not None:
                self._cell = []

        def handle_endtag(self, tag):
            if tag in ("td", "th") and self._cell is not None and self._row is not None:
                self._row.append("".join(self._cell).strip())
                self._cell = None
            if tag == "tr" and self._row is not None:
                self.rows.append(self._row)
                self._row = None

        def handle_data(self, data):
            if self._cell is not None:
                self._cell.append(data)

    page = Page()
    page.feed((report / "index.html").read_text(encoding="utf-8"))
    assert page.refs, "the page refers to nothing"
    for ref in page.refs:
        if ref.startswith("#"):
            assert ref[1:] in page.ids, ref
        else:
            assert "://" not in ref and not ref.startswith("/"), ref  # relative: opens from disk
            target = report / ref
            assert target.is_file() and target.stat().st_size > 0, ref
            if ref.endswith(".png"):
                img = cv2.imread(str(target))
                assert img is not None and img.std() > 1, ref
    # the summaries side by side: one column per results file
    header = next(r for r in page.rows if r[:1] == [""])
    assert header[1:] == ["results.json", "prior.json"]
    strategy = next(r for r in page.rows if r[:1] == ["strategy"])
    assert strategy[1:] == ["associative", "prior"]
    # frames table: every frame once, wrong first, right last
    table = [r for r in page.rows if len(r) == 10 and r[0].isdigit()]
    assert sorted(int(r[0]) for r in table) == list(range(8))
    by_frame = {f["frame"]: f for f in results["frames"]}
    rank = [0 if by_frame[int(r[0])]["correct"] is False else 2 if by_frame[int(r[0])]["correct"] else 1 for r in table]
    assert rank == sorted(rank)
    prior_cells = {int(r[0]): r[9] for r in table}
    for f in prior["frames"]:
        assert prior_cells[f["frame"]].startswith(f"{f['viewframe']} / ")
    # a section per detailed frame, in the same order, with camera, true and both chosen viewframes
    assert page.sections == [f"frame-{i}" for i in detailed]
    for i in detailed:
        assert f"frames/frame_{i:03d}_camera.png" in page.refs
        for k in (0, 1):
            chosen = (results if k == 0 else prior)["frames"][i]["viewframe"]
            assert chosen is None or f"frames/frame_{i:03d}_{k}_chosen.png" in page.refs


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


def test_a_report_with_viewframes_between_the_route_points_shows_the_viewframe_on_the_true_point(small_data, tmp_path):
    """The results name route points; the report's true viewframe is the one standing on the true
    route point (3 k with three a leg), the chosen one the decision's own viewframe."""
    small_data["route"] = small_data["route"][:3]
    path = tmp_path / "views.yaml"
    path.write_text(yaml.safe_dump({**small_data, "render": {"views_per_leg": 3}}))
    out, report = tmp_path / "results.json", tmp_path / "report"
    assert main(["run", str(path), "--out", str(out), "--no-progress"]) == 0
    assert main(["report", str(out), "--out", str(report)]) == 0
    results = json.loads(out.read_text())
    truths = {f["truth_viewframe"] for f in results["frames"]}
    shown = {p.name for p in (report / "frames").glob("viewframe_*.png")}
    assert shown == {f"viewframe_{3 * k:03d}.png" for k in truths}
    for f in results["frames"]:
        assert cv2.imread(str(report / "frames" / f"frame_{f['frame']:03d}_0_chosen.png")) is not None
