"""``mapinterp trace T --export run.rrd`` and ``mapinterp run --rerun FILE.rrd``, read back with
rerun's own RRD reader (rerun.chunk.RrdReader)."""

from __future__ import annotations

import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

from blackboard.trace import read_trace
from knowledge_sources.cli import main
from knowledge_sources.results import load_results

pytestmark = pytest.mark.slow
rerun = pytest.importorskip("rerun", reason="the optional extra mapinterp[rerun]")

PER_FRAME = ("/camera/image", "/edges/camera", "/viewframe/true", "/map/truth", "/scheduler/steps")


def read_rrd(path: Path) -> dict[str, dict[int | None, dict[str, object]]]:
    """entity path -> frame (None for static) -> component column -> the row's value."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    assert [r.application_id for r in reader.recordings()] == ["mapinterp"]
    out: dict[str, dict[int | None, dict[str, object]]] = defaultdict(dict)
    for chunk in reader.stream().to_chunks():
        batch = chunk.to_record_batch()
        n = chunk.num_rows
        frames = batch.column("frame").to_pylist() if "frame" in batch.schema.names else [None] * n
        columns = {name: batch.column(name).to_pylist() for name in batch.schema.names if ":" in name}
        for i, f in enumerate(frames):
            out[chunk.entity_path].setdefault(f, {}).update({name: values[i] for name, values in columns.items()})
    return out


@pytest.fixture(scope="module", params=[1, 3], ids=["a-view-a-point", "views-between-points"])
def run(tmp_path_factory, request):
    """A real run of the small scenario with its trace and results, and its live .rrd; with a
    viewframe per route point, and with viewframes between the route points."""
    import yaml

    from tests.knowledge_sources.conftest import SMALL

    tmp = tmp_path_factory.mktemp("rerun")
    scenario = tmp / "small.yaml"
    scenario.write_text(yaml.safe_dump({**SMALL, "render": {"views_per_leg": request.param}}))
    trace, results, live = tmp / "run.trace", tmp / "r.json", tmp / "live.rrd"
    assert (
        main(
            ["run", str(scenario), "--trace", str(trace), "--out", str(results), "--no-progress", "--rerun", str(live)]
        )
        == 0
    )
    return {"trace": trace, "results": load_results(results), "live": live, "tmp": tmp}


def _check_recording(data: dict, results: dict, records: list) -> None:
    frames = [f["frame"] for f in results["frames"]]
    for entity in PER_FRAME:
        assert sorted(data[entity]) == frames, entity
    fmt = data["/camera/image"][frames[0]]["Image:format"][0]
    assert (fmt["width"], fmt["height"]) == (160, 120)
    assert list(data["/map/terrain"]) == [None]  # static
    for rec in results["frames"]:
        f = rec["frame"]
        values = data["/ranking"][f]["BarChart:values"][0]["buffer"]
        assert values == pytest.approx([v for _, v in rec["ranking"]])
        assert rec["reason"][:30] in data["/scheduler/steps"][f]["TextDocument:text"][0]
        if rec["viewframe"] is not None:
            assert f in data["/viewframe/chosen"] and f in data["/map/estimate"]
    # one box per answer about a landmark the candidate viewframe shows, labelled with its verdict
    answers = defaultdict(list)
    for r in records:
        if r["kind"] == "post" and r.get("level") == "answer":
            answers[r["body"]["frame"]].append(r["body"])
    labelled = {
        f: row["Boxes2D:labels"] for f, row in data["/camera/image/answers"].items() if row.get("Boxes2D:labels")
    }
    assert labelled, "no answer boxes at all"
    for f, labels in labelled.items():
        assert len(labels) <= len(answers[f])
        for label in labels:
            lm, verdict = label.split()[:2]
            wanted = {"present": True, "absent": False, "uncertain": None}[verdict]
            assert any(a["landmark"] == lm and a["present"] is wanted for a in answers[f])
    assert set(labelled) <= set(answers)


def test_trace_export_reads_back_with_rerun(run, capsys) -> None:
    out = run["tmp"] / "export.rrd"
    assert main(["trace", str(run["trace"]), "--export", str(out)]) == 0
    assert "rerun recording written" in capsys.readouterr().out
    _check_recording(read_rrd(out), run["results"], read_trace(run["trace"]))


def test_live_stream_of_run_reads_back_with_rerun(run) -> None:
    _check_recording(read_rrd(run["live"]), run["results"], read_trace(run["trace"]))


def test_missing_rerun_is_one_clear_line(run, tmp_path) -> None:
    """Without the extra (the module hidden), the export says how to install it, exit 2."""
    code = (
        "import sys; sys.modules['rerun'] = None\n"
        "from knowledge_sources.cli import main\n"
        f"sys.exit(main(['trace', {str(run['trace'])!r}, '--export', {str(tmp_path / 'x.rrd')!r}]))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=Path(__file__).resolve().parents[2],
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == (
        "mapinterp trace: error: rerun-sdk is not installed: pip install 'mapinterp[rerun]' (or pip install rerun-sdk)"
    )
    assert not (tmp_path / "x.rrd").exists()


def test_run_with_rerun_but_without_the_extra_fails_at_once(run, tmp_path) -> None:
    """mapinterp run --rerun says how to install the extra before it starts the run."""
    code = (
        "import sys; sys.modules['rerun'] = None\n"
        "from knowledge_sources.cli import main\n"
        f"sys.exit(main(['run', {str(run['tmp'] / 'small.yaml')!r}, '--rerun', {str(tmp_path / 'y.rrd')!r}]))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=Path(__file__).resolve().parents[2],
    )
    assert proc.returncode == 2 and "mapinterp run: error: rerun-sdk is not installed" in proc.stderr
    assert not (tmp_path / "y.rrd").exists()
