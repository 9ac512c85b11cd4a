"""Activity records of agents: compact rows on the wire, the same trace records as before
(over real zenoh sessions on loopback, in-process and across processes)."""

from __future__ import annotations

from pathlib import Path

import pytest
import zenoh

from blackboard.codec import decode, encode
from blackboard.config import ZenohOptions, open_session, zenoh_config
from blackboard.keys import RunKeys
from blackboard.runtime import Runtime
from blackboard.trace import read_trace
from blackboard.trust import join_key, proof, sign, unseal

AGENTS = "tests.blackboard.agents"
_HEAD = ["seq", "t", "kind", "agent", "level", "id", "version", "event", "rating"]
#: the fields, in order, of each kind of activity record in the trace
EXPECTED_KEYS = {
    "activation_start": _HEAD,
    "activation_finish": [*_HEAD, "duration_s"],
    "activation_obviated": [*_HEAD, "reason"],
    "activation_error": [
        "seq",
        "t",
        "kind",
        "agent",
        "level",
        "id",
        "version",
        "event",
        "message",
        "traceback",
        "duration_s",
    ],
}


@pytest.mark.parametrize("mode", ["inprocess", "processes"])
def test_activity_records_in_the_trace(run_id: str, mode: str, tmp_path: Path) -> None:
    trace = tmp_path / "t.trace"
    with Runtime(run_id=run_id, mode=mode, trace_path=trace) as rt:
        rt.add(f"{AGENTS}:Recorder", name="rec", options={"delay_s": 0.3})
        rt.add(f"{AGENTS}:Bumper", name="bumper")
        rt.add(f"{AGENTS}:Failing", name="failing")
        rt.post("number", {"x": 0})  # keeps rec busy while the bumper posts and updates: one obviation
        rt.post("bump", {})
        rt.run(timeout_s=20)
    records = read_trace(trace)
    activity = [r for r in records if r["kind"].startswith("activation_")]
    assert {r["kind"] for r in activity} == set(EXPECTED_KEYS)
    for record in activity:
        assert list(record) == EXPECTED_KEYS[record["kind"]], record
        assert isinstance(record["t"], float) and record["version"] >= 1
    posts = {r["id"]: r for r in records if r["kind"] == "post"}
    for record in activity:
        assert record["level"] == posts[record["id"]]["level"]
    starts = [r for r in activity if r["kind"] == "activation_start"]
    finishes = {(r["agent"], r["id"], r["version"]): r for r in activity if r["kind"] == "activation_finish"}
    for start in starts:
        if start["agent"] == "failing":
            continue
        finish = finishes[(start["agent"], start["id"], start["version"])]
        assert finish["t"] >= start["t"] and finish["duration_s"] >= 0 and finish["rating"] == start["rating"]
    failing = [r for r in activity if r["agent"] == "failing" and r["kind"] != "activation_obviated"]
    pairs = len(failing) // 2
    assert pairs >= 2 and [r["kind"] for r in failing] == ["activation_start", "activation_error"] * pairs
    assert all("RuntimeError: cannot handle" in r["message"] for r in failing[1::2])
    (obviated,) = [r for r in activity if r["kind"] == "activation_obviated" and r["agent"] == "rec"]
    assert obviated["agent"] == "rec" and obviated["reason"] == "superseded by version 2"


@pytest.mark.parametrize("n", [300])
def test_activity_of_a_burst_is_complete(run_id: str, n: int, tmp_path: Path) -> None:
    """Rows are sent in batches (also while the agenda is never empty): none is lost."""
    trace = tmp_path / "t.trace"
    with Runtime(run_id=run_id, trace_path=trace) as rt:
        rt.add(f"{AGENTS}:Burster", name="burster")
        rt.add(f"{AGENTS}:Tally", name="tally")
        rt.post("go", {"n": n})
        outcome = rt.run(timeout_s=30)
    assert outcome.quiescent
    records = read_trace(trace)
    for kind in ("activation_start", "activation_finish"):
        ids = [r["id"] for r in records if r["kind"] == kind and r["agent"] == "tally"]
        assert sorted(ids) == sorted(r["id"] for r in records if r["kind"] == "post" and r["level"] == "item")
    assert outcome.stats["activation_finish"] == n + 1  # the items and the burster's 'go'


def test_node_traces_rows_and_dict_records_alike(run_id: str, tmp_path: Path) -> None:
    """An agent of an older version (dict records) and a current one (rows) give the same trace
    records; a row of an unknown kind is ignored, never a crash."""
    keys = RunKeys(run_id)
    trace = tmp_path / "t.trace"
    head = {"level": "number", "id": "h-1", "version": 1, "event": "posted", "rating": 0.5, "t": 12.5}
    with Runtime(run_id=run_id, trace_path=trace) as rt:
        raw = open_session(zenoh_config(ZenohOptions(), mode="client", connect=[rt.node.endpoint]))
        try:
            agent_key = b""

            def request(message: dict) -> dict:
                payload = encode(message)
                replies = list(
                    raw.get(
                        keys.request,
                        payload=payload,
                        timeout=10,
                        attachment=sign(agent_key, payload) if agent_key else None,
                    )
                )
                return decode(replies[0].ok.payload.to_bytes())

            rt.node.expect("old", "sekrit")  # a joined agent of this run, speaking for itself
            nonce = request({"op": "challenge", "agent": "old"})["nonce"]
            joined = request(
                {
                    "op": "join",
                    "agent": "old",
                    "consumes": [],
                    "produces": [],
                    "exclusive": [],
                    "nonce": nonce,
                    "proof": proof("sekrit", "join", run_id, "old", nonce),
                }
            )
            assert joined["ok"]
            keys_ = unseal(join_key("sekrit", run_id, "old", nonce), joined["keys"])
            assert keys_ is not None
            agent_key = keys_[:32]
            activity = [
                {**head, "kind": "activation_start"},  # an older agent
                {**head, "kind": "activation_finish", "t": 13.0, "duration_s": 0.5},
                ["s", *head.values(), None],  # a current one
                ["f", *list(head.values())[:5], 13.0, 0.5],
                ["o", *head.values(), "superseded by version 2"],
                ["?", *head.values(), None],  # unknown: ignored
            ]
            status = encode(
                {
                    "agent": "old",
                    "state": "busy",
                    "recv": {},
                    "sent": 0,
                    "timeouts": 0,
                    "probe": None,
                    "activity": activity,
                    "reason": None,
                    "seq": 1,
                }
            )
            raw.put(
                keys.status,
                status,
                congestion_control=zenoh.CongestionControl.BLOCK,
                attachment=sign(agent_key, status),
            )
            assert request({"op": "leave", "agent": "old"})["ok"]
            rt.post("number", {"x": 1})
            outcome = rt.run(timeout_s=10)
        finally:
            raw.close()
    assert outcome.quiescent
    records = [r for r in read_trace(trace) if r.get("agent") == "old" and r["kind"].startswith("activation_")]
    stripped = [{k: v for k, v in r.items() if k != "seq"} for r in records]
    start = {"t": 12.5, "kind": "activation_start", "agent": "old", **{k: v for k, v in head.items() if k != "t"}}
    finish = {**start, "kind": "activation_finish", "t": 13.0, "duration_s": 0.5}
    obviated = {**start, "kind": "activation_obviated", "reason": "superseded by version 2"}
    assert stripped == [start, finish, start, finish, obviated]
    assert [list(r) for r in stripped] == [list(r) for r in (start, finish, start, finish, obviated)]
