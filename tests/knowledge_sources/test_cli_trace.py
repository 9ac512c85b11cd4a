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


def test_summary(trace, capsys) -> None:
    code, out, _ = _run(capsys, str(trace[0]))
    assert code == 0
    assert "post 6" in out and "levels:  doubled 2, echo 2, number 2" in out
    assert any(line.startswith("doubler ") and line.split()[1] == "2" for line in out.splitlines())


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


def test_chain(trace, capsys) -> None:
    path, ids = trace
    code, out, _ = _run(capsys, str(path), "--chain", ids["echo4"])
    lines = [line for line in out.splitlines() if not line.startswith(" ")]
    assert code == 0 and [line.split()[0].split("/")[0] for line in lines] == ["echo", "doubled", "number"]
    assert ids["input2"] in lines[-1]
    code, out, _ = _run(capsys, str(path), "--chain", "nope")
    assert code == 1 and "not found" in out


@pytest.mark.parametrize("content", [None, b"\xc1garbage"])
def test_bad_file_is_one_line_error(tmp_path: Path, capsys, content: bytes | None) -> None:
    path = tmp_path / "x.trace"
    if content is not None:
        path.write_bytes(content)
    code, out, err = _run(capsys, str(path))
    assert code == 2 and out == "" and err.startswith("mapinterp trace: error: ") and "x.trace" in err
    assert len(err.strip().splitlines()) == 1
