"""The ``mapinterp`` dispatcher as a real process: ``python -m knowledge_sources.cli``, and output
piped into a reader that stops early (``| head``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from blackboard.trace import TraceKind, TraceWriter
from knowledge_sources.cli import COMMANDS, EXIT_BROKEN_PIPE

ROOT = Path(__file__).resolve().parents[2]


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "knowledge_sources.cli", *args]


@pytest.fixture(scope="module")
def long_trace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A trace whose timeline is far longer than a pipe buffer (64 KiB)."""
    path = tmp_path_factory.mktemp("cli") / "long.trace"
    writer = TraceWriter(path)
    writer.write(TraceKind.RUN_START, t=999.0, run_id="long")  # the timeline is in time order
    for i in range(5000):
        writer.write(
            TraceKind.POST,
            t=1000.0 + i,
            agent="camera",
            level="sensor_frame",
            id=f"sf-{i:06d}",
            version=1,
            links=[],
            body={"frame": i},
        )
    writer.write(TraceKind.RUN_END, t=6000.0, stats={})
    writer.close()
    return path


def test_python_m_runs_the_dispatcher() -> None:
    done = subprocess.run(_cli("--help"), cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0
    assert all(name in done.stdout for name in COMMANDS)


@pytest.mark.parametrize("read_lines", [0, 1], ids=["reader-gone-at-once", "reader-stops-after-a-line"])
def test_reader_closing_the_pipe_ends_quietly(long_trace: Path, read_lines: int) -> None:
    """``mapinterp trace FILE --timeline | head``: no traceback, status 141 (as after SIGPIPE)."""
    proc = subprocess.Popen(
        _cli("trace", str(long_trace), "--timeline"),
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and proc.stderr is not None
    lines = [proc.stdout.readline() for _ in range(read_lines)]
    proc.stdout.close()
    err = proc.stderr.read()
    proc.stderr.close()
    assert proc.wait(60) == EXIT_BROKEN_PIPE, err
    assert [line.split()[1] for line in lines] == ["run_start"] * read_lines
    assert err == ""  # neither a traceback nor "Exception ignored ... BrokenPipeError" at exit


def test_complete_output_still_exits_0(long_trace: Path) -> None:
    done = subprocess.run(
        _cli("trace", str(long_trace), "--timeline"), cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0 and done.stderr == ""
    assert len(done.stdout.splitlines()) == 5002


def test_version() -> None:
    from importlib.metadata import version

    done = subprocess.run(_cli("--version"), cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.strip() == f"mapinterp {version('mapinterp')}"


def test_global_flags_after_the_sub_command(long_trace: Path) -> None:
    """-v and --debug work after the sub-command as before it: -vv logs at DEBUG, --debug shows a
    traceback for a mapinterp error instead of the one-line message."""
    missing = long_trace.parent / "missing.trace"
    for argv in (("--debug", "trace", str(missing)), ("trace", str(missing), "--debug")):
        done = subprocess.run(_cli(*argv), cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert done.returncode == 1 and "Traceback" in done.stderr and "TraceError" in done.stderr, argv
    done = subprocess.run(_cli("trace", str(missing)), cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    for argv in (("-vv", "schema"), ("schema", "-vv")):
        code = (
            "import logging, sys; from knowledge_sources.cli import main; "
            f"main({list(argv)!r}); print(logging.getLogger().level, file=sys.stderr)"
        )
        done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert done.stderr.strip().splitlines()[-1] == str(10), (argv, done.stderr)


@pytest.mark.parametrize("shell", ["bash", "zsh"])
def test_shell_completion_knows_every_command_and_option(shell: str) -> None:
    done = subprocess.run(_cli("--print-completion", shell), cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0
    assert all(name in done.stdout for name in COMMANDS)
    assert "--export" in done.stdout and "--max-frames" in done.stdout and "--rerun" in done.stdout


def test_schema_is_the_scenario_json_schema(tmp_path: Path) -> None:
    import json

    done = subprocess.run(_cli("schema"), cwd=ROOT, capture_output=True, text=True, timeout=60)
    schema = json.loads(done.stdout)
    assert done.returncode == 0 and schema["title"] == "mapinterp scenario"
    assert {"name", "terrain", "route", "camera", "crs"} <= set(schema["properties"])
    assert set(schema["required"]) >= {"name", "terrain", "route", "camera"}
    terrain = schema["$defs"]["TerrainSpec"]["properties"]
    assert {"dem", "cell_size", "nodata", "elevation_attribute", "contours"} <= set(terrain)
    out = tmp_path / "s.json"
    assert subprocess.run(_cli("schema", "--out", str(out)), cwd=ROOT, timeout=60).returncode == 0
    assert json.loads(out.read_text()) == schema
