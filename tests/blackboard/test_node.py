"""The blackboard node against raw zenoh sessions: malformed and oversized messages, two runs on
one network, a burst of 10,000 posts, and the trace of a run killed with SIGKILL."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import zenoh

from blackboard.codec import encode
from blackboard.config import ZenohOptions, loopback_endpoint, open_session, zenoh_config
from blackboard.keys import RunKeys
from blackboard.runtime import Runtime
from blackboard.trace import read_trace

AGENTS = "tests.blackboard.agents"


def _raw_session(endpoint: str) -> zenoh.Session:
    return open_session(zenoh_config(ZenohOptions(), mode="client", connect=[endpoint]))


def test_malformed_and_oversized_messages_are_rejected_and_traced(run_id: str, tmp_path: Path) -> None:
    limit = 64 * 1024
    keys = RunKeys(run_id)
    with Runtime(run_id=run_id, trace_path=tmp_path / "t.trace", max_message_bytes=limit) as rt:
        rt.add(f"{AGENTS}:Doubler", name="doubler")
        raw = _raw_session(rt.node.endpoint)
        try:
            put = lambda key, data: raw.put(key, data, congestion_control=zenoh.CongestionControl.BLOCK)  # noqa: E731
            put(keys.hypothesis("number", "garbage"), b"\xc1\x00garbage")
            put(keys.hypothesis("number", "huge"), encode({"op": "post", "x": bytes(limit + 1)}))
            put(keys.hypothesis("number", "no-op"), encode({"hello": 1}))
            record = {
                "id": "other",
                "level": "number",
                "source": "x",
                "credibility": 1.0,
                "links": [],
                "version": 1,
                "timestamp": 0.0,
                "body": {"x": 1},
            }
            put(keys.hypothesis("number", "mismatch"), encode({"op": "post", "hyp": record, "sender": "x"}))
            put(keys.status, b"\xff\xfe")
            # the raw session's puts travel beside the run's own messages: wait until the node
            # has met all five, or the run may reach quiescence before the large one arrives
            deadline = time.monotonic() + 10
            while rt.node.stats["rejected"] < 5 and time.monotonic() < deadline:
                time.sleep(0.02)
            rt.post("number", {"x": 21})
            outcome = rt.run(timeout_s=10)
        finally:
            raw.close()
        assert outcome.agents == {"doubler": "ok"}
        assert [h.body["x"] for h in rt.hypotheses("doubled")] == [42]
        assert [h.id for h in rt.hypotheses("number")] == [rt.hypotheses("number")[0].id]
    rejected = [r for r in read_trace(tmp_path / "t.trace") if r["kind"] == "rejected"]
    by_key = {r["key"].rsplit("/", 1)[-1]: r["message"] for r in rejected}
    assert "malformed" in by_key["garbage"]
    assert "exceeds the limit" in by_key["huge"]
    assert "not a post" in by_key["no-op"]
    assert "not signed by a joined agent 'x'" in by_key["mismatch"]
    assert "malformed status" in by_key["status"]


def test_two_runs_on_one_network_are_isolated(run_id: str) -> None:
    endpoint = loopback_endpoint()
    with (
        Runtime(run_id=f"{run_id}-a", zenoh=ZenohOptions(listen=[endpoint])) as a,
        Runtime(run_id=f"{run_id}-b", zenoh=ZenohOptions(connect=[endpoint])) as b,
    ):
        a.add(f"{AGENTS}:Doubler", name="doubler")
        b.add(f"{AGENTS}:Doubler", name="doubler")  # same agent name, other run: no conflict
        for x in range(5):
            a.post("number", {"x": x})
        b.post("number", {"x": 100})
        a.run(timeout_s=10)
        b.run(timeout_s=10)
        assert sorted(h.body["x"] for h in a.hypotheses("doubled")) == [0, 2, 4, 6, 8]
        assert [h.body["x"] for h in b.hypotheses("doubled")] == [200]
        assert a.node.stats.get("rejected", 0) == 0 and b.node.stats.get("rejected", 0) == 0


@pytest.mark.slow
def test_burst_of_10000_posts_loses_nothing(run_id: str, tmp_path: Path) -> None:
    n = 10_000
    with Runtime(run_id=run_id, trace_path=tmp_path / "t.trace") as rt:
        rt.add(f"{AGENTS}:Burster", name="burster")
        rt.add(f"{AGENTS}:Tally", name="tally")
        rt.post("go", {"n": n, "size": 1024})
        outcome = rt.run(timeout_s=120)
        tally = rt.source("tally")
        stored = len(rt.hypotheses("item"))
        if tally.seen != set(range(n)) or tally.activations != n:  # say why, not only that
            errors = [
                r
                for r in read_trace(tmp_path / "t.trace")
                if r["kind"] in ("activation_error", "rejected", "agent_dead", "timeout")
            ]
            pytest.fail(
                f"tally saw {len(tally.seen)} of {n} items ({tally.activations} activations), "
                f"{stored} stored, outcome {outcome.quiescent=} {outcome.agents=} {outcome.stats=}; "
                f"errors in the trace: {errors[:5]}"
            )
        assert stored == n and outcome.stats["post"] == n + 1
    records = read_trace(tmp_path / "t.trace")
    assert sum(r["kind"] == "post" for r in records) == n + 1
    assert sum(r["kind"] == "activation_finish" and r["agent"] == "tally" for r in records) == n


_CRASHING_RUN = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {root!r})
    from blackboard.runtime import Runtime
    rt = Runtime(run_id={run_id!r}, trace_path={trace!r}, mode="processes").__enter__()
    rt.add("tests.blackboard.agents:Doubler", name="doubler")
    for x in range(20):
        rt.post("number", {{"x": x}})
    rt.run(timeout_s=20)
    print("quiescent", rt.node.agents["doubler"].pid, flush=True)
    time.sleep(600)
""")


def _gone(pid: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


def test_trace_reads_after_the_run_is_killed(run_id: str, tmp_path: Path) -> None:
    """kill -9 a process running a Runtime (processes mode): the trace reads, the agent process exits."""
    trace = tmp_path / "killed.trace"
    root = str(Path(__file__).resolve().parents[2])
    script = _CRASHING_RUN.format(root=root, run_id=run_id, trace=str(trace))
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        word, child = proc.stdout.readline().split()
        assert word == "quiescent"
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        if proc.stdout is not None:
            proc.stdout.close()
    assert _gone(int(child), timeout_s=10), "the agent process outlived its parent"
    records = read_trace(trace)
    kinds = [r["kind"] for r in records]
    assert kinds[0] == "run_start" and "run_end" not in kinds
    assert kinds.count("post") == 40 and kinds.count("activation_finish") == 20 and "quiescent" in kinds
    # and a record cut in half by a crash mid-write loses only that record
    data = trace.read_bytes()
    trace.write_bytes(data + data[:7])
    assert len(read_trace(trace)) == len(records)


class _SlowToClose:
    """A real zenoh session whose close, like one over a loaded link, closes it and then reports
    zenoh's "close operation timed out!"."""

    def __init__(self, session: zenoh.Session) -> None:
        self._session = session

    def __getattr__(self, name: str) -> object:
        return getattr(self._session, name)

    def close(self) -> None:
        self._session.close()
        raise zenoh.ZError("close operation timed out!")


@pytest.mark.parametrize("which", ["_session", "_router"])
def test_a_session_close_that_times_out_still_ends_and_closes_the_trace(
    which: str, run_id: str, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    trace = tmp_path / "t.trace"
    with Runtime(run_id=run_id, trace_path=trace) as rt:
        rt.add(f"{AGENTS}:Doubler", name="doubler")
        rt.post("number", {"x": 2})
        rt.run(timeout_s=10)
        setattr(rt.node, which, _SlowToClose(getattr(rt.node, which)))
    records = read_trace(trace)
    assert records[-1]["kind"] == "run_end"
    writer = rt.node._trace._writer
    assert writer is not None and writer._file is None  # closed: no file left for the GC to warn about
    assert "did not close cleanly: close operation timed out!" in caplog.text
