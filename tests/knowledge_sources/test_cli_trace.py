"""``mapinterp trace`` on the trace of a real (small, in-process) run."""

from __future__ import annotations

import json
import sys
import uuid
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:  # tests.blackboard.agents by name
    sys.path.insert(0, str(ROOT))

from blackboard.runtime import Runtime  # noqa: E402
from knowledge_sources.cli import main  # noqa: E402


@pytest.fixture(scope="module")
def trace(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str]]:
    path = tmp_path_factory.mktemp("trace") / "run.trace"
    with Runtime(run_id=f"cli-trace-{uuid.uuid4().hex[:8]}", trace_path=path) as rt:
        rt.add("tests.blackboard.agents:Doubler", name="doubler")
        rt.add("tests.blackboard.agents:Echo", name="echo")
        inputs = {x: rt.post("number", {"x": x, "frame": x}).id for x in (1, 2)}
        rt.run(timeout_s=20)
        echo = next(h for h in rt.hypotheses("echo") if h.body["x"] == 4)
    return path, {"echo4": echo.id, "input2": inputs[2]}


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["trace", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.replace("┃", "│").split("│")[1:-1]]


def test_summary(trace, capsys) -> None:
    code, out, _ = _run(capsys, str(trace[0]))
    assert code == 0
    assert "post 6" in out and "doubled 2, echo 2, number 2" in out and "incomplete" not in out
    rows = [_cells(line) for line in out.splitlines() if line and line[0] in "│┃"]
    assert rows[0][:2] == ["agent", "posts"]
    assert ["doubler", "2"] == next(r for r in rows if r[0] == "doubler")[:2]


def test_filtered_summary_is_not_called_incomplete(trace, capsys) -> None:
    """The filter drops run_end; the run still ended, and the summary says so."""
    code, out, _ = _run(capsys, str(trace[0]), "--agent", "echo")
    assert code == 0 and "incomplete" not in out and "run_end" not in out
    code, out, _ = _run(capsys, str(trace[0]), "--agent", "echo", "--json")
    assert json.loads(out)["complete"] is True


@pytest.mark.parametrize(
    "flag, value, known",
    [
        ("--agent", "dubler", "doubler, echo"),
        ("--level", "doubles", "doubled, echo, number"),
    ],
)
def test_unknown_filter_name_is_an_error_listing_the_known_ones(trace, capsys, flag, value, known) -> None:
    code, out, err = _run(capsys, str(trace[0]), flag, value)
    assert code == 2 and out == ""
    assert f"no {flag[2:]} '{value}' in this trace" in err and known in err


def test_timeline_is_in_time_order_and_shows_bodies(trace, capsys) -> None:
    code, out, _ = _run(capsys, str(trace[0]), "--timeline")
    times = [float(line.split()[0].rstrip("s")) for line in out.splitlines()]
    assert code == 0 and times == sorted(times) and len(times) > 10
    assert any("doubled/" in line and "[x=4" in line for line in out.splitlines())


def test_summary_json(trace, capsys) -> None:
    code, out, _ = _run(capsys, str(trace[0]), "--json")
    data = json.loads(out)
    assert code == 0 and data["complete"] and data["kinds"]["post"] == 6 and set(data["agents"]) >= {"doubler", "echo"}


ARGS = {
    "agent": (["--agent", "echo", "--timeline"], {"echo"}),
    "level": (["--level", "doubled", "--timeline"], {"doubler", "echo"}),  # echo's activations on doubled
}


@pytest.mark.parametrize(("args", "agents"), ARGS.values(), ids=ARGS.keys())
def test_timeline_filters(trace, capsys, args: list[str], agents: set[str]) -> None:
    code, out, _ = _run(capsys, str(trace[0]), *args, "--json")
    records = json.loads(out)
    assert code == 0 and records and {r["agent"] for r in records} == agents


def test_frame_filter(trace, capsys) -> None:
    code, out, _ = _run(capsys, str(trace[0]), "--frame", "2", "--timeline", "--json")
    posts = [r for r in json.loads(out) if r["kind"] == "post"]
    assert code == 0 and sorted(r["body"]["x"] for r in posts) == [2, 4, 4]


def test_chain_is_a_tree(trace, capsys) -> None:
    path, ids = trace
    code, out, _ = _run(capsys, str(path), "--chain", ids["echo4"])
    lines = out.splitlines()
    assert code == 0 and lines[0].startswith("echo/")
    # each input one level deeper: echo <- doubled <- number
    assert lines[1].startswith("└── doubled/") and lines[2].startswith("    └── number/" + ids["input2"])
    code, out, err = _run(capsys, str(path), "--chain", "nope")
    assert code == 2 and "no hypothesis 'nope'" in err


def test_chain_exports_graphviz_dot(trace, capsys, tmp_path) -> None:
    path, ids = trace
    dot = tmp_path / "chain.dot"
    code, out, _ = _run(capsys, str(path), "--chain", ids["echo4"], "--export", str(dot))
    text = dot.read_text()
    assert code == 0 and text.startswith("digraph derivation {") and text.rstrip().endswith("}")
    assert f'"{ids["input2"]}" -> ' in text  # the input points at what was derived from it
    assert text.count(" -> ") == 2 and text.count("[label=") == 3
    code, _, err = _run(capsys, str(path), "--export", str(dot))
    assert code == 2 and "--chain" in err


def test_perfetto_export_follows_the_trace_event_format(trace, capsys, tmp_path) -> None:
    """Fields of the Chrome trace-event format (JSON object form) checked event by event."""
    from blackboard.trace import read_trace

    path, ids = trace
    out_path = tmp_path / "timeline.json"
    code, out, _ = _run(capsys, str(path), "--export", str(out_path))
    assert code == 0 and "perfetto" in out
    doc = json.loads(out_path.read_text())
    assert set(doc) >= {"traceEvents", "displayTimeUnit"} and doc["displayTimeUnit"] in ("ms", "ns")
    events = doc["traceEvents"]
    records = read_trace(path)
    threads = {}
    flows: dict[int, dict[str, dict]] = {}
    for e in events:
        assert isinstance(e["name"], str) and isinstance(e["pid"], int) and isinstance(e["tid"], int)
        ph = e["ph"]
        assert ph in {"M", "X", "i", "s", "f"}
        if ph == "M":
            assert e["name"] in {"process_name", "thread_name", "thread_sort_index"} and isinstance(e["args"], dict)
            if e["name"] == "thread_name":
                threads[e["tid"]] = e["args"]["name"]
            continue
        assert isinstance(e["ts"], (int, float)) and e["ts"] >= 0
        if ph == "X":
            assert isinstance(e["dur"], (int, float)) and e["dur"] >= 0 and e["cat"].startswith("activation")
        elif ph == "i":
            assert e["s"] in {"g", "p", "t"}
        else:
            assert isinstance(e["id"], int) and e["cat"] == "link"
            flows.setdefault(e["id"], {})[ph] = e
    # agents as threads, one slice per finished activation, one instant per post, a flow per link
    agents = {r["agent"] for r in records if r.get("agent")}
    assert agents <= set(threads.values())
    used = {e["tid"] for e in events if e["ph"] != "M"}
    assert used <= set(threads)
    finished = [r for r in records if r["kind"] in ("activation_finish", "activation_error")]
    assert len([e for e in events if e["ph"] == "X"]) == len(finished)
    posts = [r for r in records if r["kind"] == "post"]
    assert len([e for e in events if e["ph"] == "i" and e["cat"] == "post"]) == len(posts)
    assert len(flows) == sum(len(r.get("links") or ()) for r in posts) > 0
    for pair in flows.values():
        assert set(pair) == {"s", "f"} and pair["s"]["ts"] <= pair["f"]["ts"] and pair["f"]["bp"] == "e"
    # a slice's span is the activation's: its end is the finish record's time, its start that
    # minus the activation's duration (compared as sorted lists: activations of two agents may
    # start within a microsecond, so "the first slice" need not be the earliest-starting one)
    t0 = min(r["t"] for r in records)
    slices = [e for e in events if e["ph"] == "X"]
    ends = sorted(e["ts"] + e["dur"] for e in slices)
    assert ends == pytest.approx(sorted((r["t"] - t0) * 1e6 for r in finished), abs=1.0)
    starts = sorted(e["ts"] for e in slices)
    assert starts == pytest.approx(sorted((r["t"] - r["duration_s"] - t0) * 1e6 for r in finished), abs=1.0)


@pytest.mark.parametrize("content", [None, b"\xc1garbage"])
def test_bad_file_is_one_line_error(tmp_path: Path, capsys, content: bytes | None) -> None:
    path = tmp_path / "x.trace"
    if content is not None:
        path.write_bytes(content)
    code, out, err = _run(capsys, str(path))
    assert code == 2 and out == "" and err.startswith("mapinterp trace: error: ") and "x.trace" in err
    assert len(err.strip().splitlines()) == 1
