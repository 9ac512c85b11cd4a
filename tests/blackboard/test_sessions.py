"""Zenoh sessions shared by the agents of one process (real sessions on loopback)."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from blackboard.config import loopback_endpoint, zenoh_config
from blackboard.runtime import Runtime
from blackboard.sessions import SessionRegistry

AGENTS = "tests.blackboard.agents"


def _peer_config():
    return zenoh_config(mode="peer", listen=[loopback_endpoint()])  # a free port on 127.0.0.1, no scouting


def test_a_registry_shares_one_session_per_config_and_closes_it_with_the_last_holder() -> None:
    registry = SessionRegistry()
    config = zenoh_config(mode="peer")  # an ephemeral port on 127.0.0.1: two sessions of it can be open
    first, second = registry.acquire(config), registry.acquire(config)
    assert first.session is second.session and registry.holders(config) == 2
    other = registry.acquire(_peer_config())  # another config (another port): another session
    assert other.session is not first.session
    later = registry.acquire(config, scope="another-run")  # the same config in another run: not shared
    assert later.session is not first.session and registry.holders(config, scope="another-run") == 1
    later.release()
    sub = first.session.declare_subscriber("test/shared", lambda s: None)
    first.release([sub])
    first.release([sub])  # idempotent
    assert not first.open and second.open and not second.session.is_closed()
    assert registry.holders(config) == 1
    second.release()
    assert second.session.is_closed() and registry.holders(config) == 0
    third = registry.acquire(config)  # reopened after the last release
    assert third.session is not first.session and third.open
    third.release()
    other.release()


def test_released_subscribers_stop_hearing_while_the_session_goes_on() -> None:
    registry = SessionRegistry()
    config = _peer_config()
    mine, theirs = registry.acquire(config), registry.acquire(config)
    heard: dict[str, list[bytes]] = {"mine": [], "theirs": []}
    got = threading.Event()

    def on_theirs(sample) -> None:
        heard["theirs"].append(sample.payload.to_bytes())
        got.set()

    sub_mine = mine.session.declare_subscriber("test/shared/k", lambda s: heard["mine"].append(s.payload.to_bytes()))
    theirs.session.declare_subscriber("test/shared/k", on_theirs)
    mine.release([sub_mine])
    theirs.session.put("test/shared/k", b"after")
    assert got.wait(5.0)
    assert heard == {"mine": [], "theirs": [b"after"]}
    theirs.release()


@pytest.mark.parametrize("killed", [False, True])
def test_in_process_agents_share_a_session_and_leave_it_one_by_one(run_id: str, tmp_path: Path, killed: bool) -> None:
    with Runtime(run_id=run_id, trace_path=tmp_path / "run.trace") as rt:
        rt.add(f"{AGENTS}:Doubler", name="doubler")
        rt.add(f"{AGENTS}:Echo", name="echo")
        doubler, echo = rt._runners["doubler"], rt._runners["echo"]
        assert doubler._hold is not None and echo._hold is not None
        assert doubler._hold.session is echo._hold.session  # one session for the process's agents
        for x in range(3):
            rt.post("number", {"x": x})
        outcome = rt.run(timeout_s=20)
        assert outcome.agents == {"doubler": "ok", "echo": "ok"}
        if killed:  # the node sees the agent die (its token went) though the session stays open
            rt.kill("echo")
        else:
            echo.stop()
        assert not echo._hold.open and doubler._hold.open
        rt.post("number", {"x": 10})
        outcome = rt.run(timeout_s=20)
        assert sorted(h.body["x"] for h in rt.hypotheses("doubled")) == [0, 2, 4, 20]
        assert sorted(h.body["x"] for h in rt.hypotheses("echo")) == [0, 2, 4]  # echo heard nothing more
        if killed:
            assert outcome.agents["echo"].startswith("dead") and "token dropped" in outcome.agents["echo"]
        session = doubler._hold.session
    assert session.is_closed()  # the last agent gone: closed
