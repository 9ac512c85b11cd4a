"""The node's trace writer: hypotheses, rejections and activity rows become trace records and counts."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from blackboard.hypothesis import Hypothesis
from blackboard.run_trace import RunTrace
from blackboard.trace import TraceKind, read_trace


def test_records_and_counts(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    trace = RunTrace(tmp_path / "t.trace")
    hyp = Hypothesis.new("number", {"x": 1}, source="user", id="n-1")
    trace.hypothesis(TraceKind.POST, hyp)
    with caplog.at_level(logging.WARNING):
        trace.reject("mapinterp/r/number/bad", "malformed message", size=3)
    trace.activity(
        "doubler",
        [
            ["s", "number", "n-1", 1, "posted", 1.0, 10.0, None],
            ["f", "number", "n-1", 1, "posted", 1.0, 11.0, 0.5],
            ["o", "number", "n-2", 1, "posted", 1.0, 12.0, "superseded by version 2"],
            ["?", "number", "n-3", 1, "posted", 1.0, 12.0, None],  # unknown code: ignored
            {"kind": "activation_error", "t": 13.0, "level": "number", "id": "n-1", "message": "boom"},
            {"kind": "not-a-kind"},
        ],
    )
    trace.close()
    records = read_trace(tmp_path / "t.trace")
    kinds = [r["kind"] for r in records]
    assert kinds == [
        "post",
        "rejected",
        "activation_start",
        "activation_finish",
        "activation_obviated",
        "activation_error",
    ]
    post = records[0]
    assert (post["id"], post["level"], post["agent"], post["body"]) == ("n-1", "number", "user", {"x": 1})
    assert records[3]["duration_s"] == 0.5 and records[4]["reason"] == "superseded by version 2"
    assert all(r["agent"] == "doubler" for r in records[2:])
    assert trace.stats == {
        "rejected": 1,
        "activation_start": 1,
        "activation_finish": 1,
        "activation_obviated": 1,
        "activation_error": 1,
    }
    assert "malformed message" in caplog.text


def test_without_a_file_it_only_counts() -> None:
    trace = RunTrace(None)
    assert not trace.writing
    trace.write(TraceKind.RUN_START, run_id="r")
    trace.activity("a", [["s", "x", "h", 1, "posted", None, 1.0, None]])
    trace.close()
    assert trace.stats == {"activation_start": 1}
