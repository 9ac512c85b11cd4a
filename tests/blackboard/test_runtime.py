"""The runtime over real zenoh sessions on loopback: in-process and across processes."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from blackboard.agent import AgentRunner
from blackboard.config import ZenohOptions, loopback_endpoint
from blackboard.errors import AgentError, BlackboardError, DeclarationError, TransportError
from blackboard.knowledge_source import Event, EventKind
from blackboard.runtime import Runtime
from blackboard.trace import read_trace
from tests.blackboard.agents import Doubler

AGENTS = "tests.blackboard.agents"
MODES = ["inprocess", "processes"]


@pytest.mark.parametrize("mode", MODES)
def test_post_and_consume(run_id: str, mode: str, tmp_path: Path) -> None:
    seen: list[Event] = []
    with Runtime(run_id=run_id, mode=mode, trace_path=tmp_path / "run.trace") as rt:
        rt.add(f"{AGENTS}:Doubler", name="doubler")
        rt.add(f"{AGENTS}:Echo", name="echo")
        inputs = [rt.post("number", {"x": x, "frame": x % 2}) for x in range(7)]
        outcome = rt.run(timeout_s=20, progress=seen.append)
        echoes = rt.hypotheses("echo")
    assert outcome.quiescent and outcome.agents == {"doubler": "ok", "echo": "ok"}
    assert sorted(h.body["x"] for h in echoes) == [2 * x for x in range(7)]
    doubled = {h.id: h for h in outcome.hypotheses if h.level == "doubled"}
    for echo in echoes:  # links lead back to the inputs
        assert doubled[echo.links[0]].links[0] in {h.id for h in inputs}
        assert echo.source == "echo" and echo.version == 1
    assert sum(e.kind is EventKind.POSTED for e in seen) == 21
    records = read_trace(tmp_path / "run.trace")
    kinds = [r["kind"] for r in records]
    assert kinds.count("post") == 21 and kinds.count("activation_finish") == 14
    assert kinds[0] == "run_start" and kinds[-1] == "run_end"
    assert {r["agent"] for r in records if r["kind"] == "agent_join"} == {"doubler", "echo"}


def test_late_joiner_reads_existing_state(run_id: str) -> None:
    with Runtime(run_id=run_id) as rt:
        for x in (3, 4, 5):
            rt.post("number", {"x": x})
        rt.run(timeout_s=10)
        rt.add(f"{AGENTS}:LateCounter", name="late")
        rt.run(timeout_s=10)
        (count,) = rt.hypotheses("count")
    assert count.body == {"n": 3, "sum": 12}


def test_agenda_orders_by_rating(run_id: str) -> None:
    with Runtime(run_id=run_id) as rt:
        rt.add(f"{AGENTS}:Recorder", name="rec", options={"delay_s": 0.05})
        for x, rating in enumerate([0, 1, 3, 2, 5, 4]):
            rt.post("number", {"x": x, "rating": rating})
        rt.run(timeout_s=10)
        seen = [x for _, x in rt.source("rec").seen]
    assert sorted(seen) == [0, 1, 2, 3, 4, 5]
    ratings = [[0, 1, 3, 2, 5, 4][x] for x in seen[1:]]
    assert ratings == sorted(ratings, reverse=True)  # after the first, highest rating first


def test_superseded_activation_is_obviated(run_id: str, tmp_path: Path) -> None:
    with Runtime(run_id=run_id, trace_path=tmp_path / "t.trace") as rt:
        rt.add(f"{AGENTS}:Recorder", name="rec", options={"delay_s": 0.3})
        rt.add(f"{AGENTS}:Bumper", name="bumper")
        rt.post("number", {"x": 0})  # keeps rec busy while the bumper posts and updates
        rt.post("bump", {})
        rt.run(timeout_s=10)
        seen = rt.source("rec").seen
    assert ("updated", 2) in seen and ("posted", 1) not in seen
    obviated = [r for r in read_trace(tmp_path / "t.trace") if r["kind"] == "activation_obviated"]
    assert len(obviated) == 1 and obviated[0]["agent"] == "rec" and "superseded by version 2" in obviated[0]["reason"]


@pytest.mark.parametrize("n", [50])
def test_concurrent_updates_never_lose_a_write(run_id: str, n: int) -> None:
    # Writers, not Updaters: an Updater triggered by the target itself is rightly obviated when
    # another's update reaches it before its activation runs (a race, under load)
    with Runtime(run_id=run_id) as rt:
        for name in ("u1", "u2", "u3"):
            rt.add(f"{AGENTS}:Writer", name=name, options={"n": n})
        target = rt.post("target", {"origin": True})
        rt.post("go", {"target": target.id})
        rt.run(timeout_s=30)
        (final,) = rt.hypotheses("target")
    assert final.id == target.id and final.version == 1 + 3 * n
    assert final.body == {"origin": True, **{f"u{k}-{i}": i for k in (1, 2, 3) for i in range(n)}}


@pytest.mark.parametrize("mode", MODES)
def test_update_of_a_post_just_seen_from_another_agent(run_id: str, mode: str) -> None:
    with Runtime(run_id=run_id, mode=mode) as rt:
        rt.add(f"{AGENTS}:Doubler", name="doubler")
        rt.add(f"{AGENTS}:Booster", name="booster")
        for x in range(20):
            rt.post("number", {"x": x})
        outcome = rt.run(timeout_s=20)
        doubled = rt.hypotheses("doubled")
    assert outcome.stats["update"] == 20 and len(doubled) == 20
    assert all(h.version == 2 and h.credibility == 0.5 and h.body["boosted"] for h in doubled)


def test_act_failures_are_traced_then_the_agent_dies(run_id: str, tmp_path: Path) -> None:
    with Runtime(run_id=run_id, trace_path=tmp_path / "t.trace") as rt:
        rt.add(f"{AGENTS}:Failing", name="failing")
        rt.add(f"{AGENTS}:Doubler", name="doubler")
        for x in range(5):
            rt.post("number", {"x": x})
        outcome = rt.run(timeout_s=10)
    assert outcome.agents["doubler"] == "ok"
    assert outcome.agents["failing"].startswith("dead: 3 failures") and "cannot handle" in outcome.agents["failing"]
    assert outcome.failures["failing"].startswith("3 failed activations, the last: act raised RuntimeError")
    assert "doubler" not in outcome.failures
    assert len([h for h in outcome.hypotheses if h.level == "doubled"]) == 5
    records = read_trace(tmp_path / "t.trace")
    errors = [r for r in records if r["kind"] == "activation_error"]
    assert len(errors) == 3 and all(r["agent"] == "failing" and "RuntimeError" in r["message"] for r in errors)
    assert [r["agent"] for r in records if r["kind"] == "agent_dead"] == ["failing"]


@pytest.mark.parametrize("mode", MODES)
def test_a_failed_activation_the_agent_survives_is_in_the_outcome(run_id: str, mode: str) -> None:
    with Runtime(run_id=run_id, mode=mode) as rt:
        rt.add(f"{AGENTS}:FailingOn", name="flaky", options={"x": 3})
        rt.add(f"{AGENTS}:Doubler", name="doubler")
        for x in range(5):
            rt.post("number", {"x": x})
        outcome = rt.run(timeout_s=20)
    assert outcome.agents == {"flaky": "ok", "doubler": "ok"}
    assert list(outcome.failures) == ["flaky"]
    assert outcome.failures["flaky"].startswith(
        "1 failed activation, the last: act raised RuntimeError: cannot handle 3"
    )
    assert "posted" in outcome.failures["flaky"]  # the event the activation was for


@pytest.mark.parametrize("mode", MODES)
def test_an_agent_decodes_only_the_messages_it_wants(run_id: str, mode: str) -> None:
    with Runtime(run_id=run_id, mode=mode) as rt:
        rt.add(f"{AGENTS}:Picky", name="picky")
        for x in range(6):
            rt.post("number", {"x": x}, id=f"n-{x}")
        outcome = rt.run(timeout_s=20)
    assert outcome.failures == {} and outcome.agents == {"picky": "ok"}
    assert sorted(h.body["x"] for h in outcome.hypotheses if h.level == "doubled") == [0, 4, 8]


def test_events_before_anyone_listens_keep_large_bodies_once(run_id: str) -> None:
    """Events of a run nobody listens to yet are kept for the first listener; a large body is
    kept as the store keeps it (compressed, decoded when read), not as a second decoded copy."""
    import numpy as np

    with Runtime(run_id=run_id) as rt:
        rt.add(f"{AGENTS}:Big", name="big")
        for x in range(4):
            rt.post("number", {"x": x})
        deadline = time.monotonic() + 20
        while len(rt.hypotheses("big")) < 4 and time.monotonic() < deadline:
            time.sleep(0.05)
        waiting = [e for e in list(rt.node._unreported) if e.hypothesis.level == "big"]
        seen: list = []
        rt.run(timeout_s=20, progress=seen.append)
    assert len(waiting) == 4 and all(type(e.hypothesis).__name__ == "PackedHypothesis" for e in waiting)
    big = sorted((e.hypothesis for e in seen if e.hypothesis.level == "big"), key=lambda h: h.body["x"])
    assert [h.body["x"] for h in big] == [0, 1, 2, 3]
    assert all(np.array_equal(h.body["a"], np.full((256, 256), float(h.body["x"]), np.float32)) for h in big)


@pytest.mark.parametrize("mode", MODES)
def test_setup_failure_is_reported(run_id: str, mode: str) -> None:
    with Runtime(run_id=run_id, mode=mode) as rt:
        with pytest.raises(AgentError, match="^agent 'bad': setup failed: OSError: model file missing$"):
            rt.add(f"{AGENTS}:BadSetup", name="bad")
        rt.add(f"{AGENTS}:Doubler", name="doubler")  # the runtime carries on
        rt.post("number", {"x": 1})
        assert rt.run(timeout_s=10).agents["doubler"] == "ok"


def test_agent_without_a_node_fails_at_once(run_id: str) -> None:
    source = Doubler("doubler")
    runner = AgentRunner(source, run_id=run_id, connect=[loopback_endpoint()])
    with pytest.raises(TransportError, match="cannot open a zenoh session"):
        runner.start()


def test_second_exclusive_writer_is_refused(run_id: str) -> None:
    with Runtime(run_id=run_id) as rt:
        rt.add(f"{AGENTS}:Exclusive", name="first")
        with pytest.raises(DeclarationError, match="'second'.*'position'.*'first'"):
            rt.add(f"{AGENTS}:Exclusive", name="second")


def test_undeclared_level_is_refused(run_id: str, tmp_path: Path) -> None:
    with Runtime(run_id=run_id, trace_path=tmp_path / "t.trace") as rt:
        rt.add(f"{AGENTS}:Rogue", name="rogue")
        rt.post("number", {"x": 1})
        rt.run(timeout_s=10)
        assert rt.hypotheses("position") == []
    (error,) = [r for r in read_trace(tmp_path / "t.trace") if r["kind"] == "activation_error"]
    assert "DeclarationError" in error["message"] and "'position'" in error["message"]


@pytest.mark.parametrize("factory", ["nowhere.module:X", f"{AGENTS}:Nope", "no-colon", "builtins:dict"])
def test_bad_factory(run_id: str, factory: str) -> None:
    with Runtime(run_id=run_id) as rt, pytest.raises(AgentError, match="factory"):
        rt.add(factory, name="x")


def test_run_timeout_names_the_busy_agent(run_id: str) -> None:
    with Runtime(run_id=run_id) as rt:
        rt.add(f"{AGENTS}:Slow", name="slowpoke", options={"delay_s": 1.5})
        rt.post("number", {"x": 1})
        with pytest.raises(AgentError, match="slowpoke.*not quiescent after 0.3 s"):
            rt.run(timeout_s=0.3)
        assert rt.run(timeout_s=10).quiescent


ADDRESSED = {
    "deadline": ({"deadline_s": 0.4}, "no answer within 0.4 s from agent 'det'"),
    "no deadline, idle": ({}, "agent 'det' went idle without answering"),
}


@pytest.mark.parametrize(("extra", "reason"), ADDRESSED.values(), ids=ADDRESSED.keys())
def test_unanswered_addressed_post_times_out_to_the_poster(run_id: str, extra: dict, reason: str) -> None:
    with Runtime(run_id=run_id) as rt:
        rt.add(f"{AGENTS}:Asker", name="asker")
        rt.add(f"{AGENTS}:Silent", name="det")
        rt.post("ask", {"to": "det", "q": "where", **extra})
        rt.run(timeout_s=10)
        (timeout,) = rt.hypotheses("timeout")
    assert timeout.body == {"reason": reason, "q": "where"}


def test_answered_addressed_post_does_not_time_out(run_id: str) -> None:
    with Runtime(run_id=run_id) as rt:
        rt.add(f"{AGENTS}:Asker", name="asker")
        rt.add(f"{AGENTS}:Echo", name="echo", options={"delay_s": 0.1})
        rt.post("ask", {"to": "echo", "q": "where", "deadline_s": 5})
        outcome = rt.run(timeout_s=10)
        assert [h.body for h in rt.hypotheses("answer")] == [{"q": "where"}]
        assert rt.hypotheses("timeout") == [] and outcome.stats.get("timeout", 0) == 0


@pytest.mark.parametrize("mode", MODES)
def test_dead_agent_times_out_addressed_posts(run_id: str, mode: str, tmp_path: Path) -> None:
    with Runtime(run_id=run_id, mode=mode, trace_path=tmp_path / "t.trace") as rt:
        rt.add(f"{AGENTS}:Asker", name="asker")
        rt.add(f"{AGENTS}:Silent", name="detector-house")
        rt.post("ask", {"to": "detector-house", "q": "house?", "deadline_s": 60})
        killer = threading.Timer(0.3, rt.kill, args=("detector-house",))
        killer.start()
        outcome = rt.run(timeout_s=30)  # well before the 60 s deadline
        killer.join()
        (timeout,) = rt.hypotheses("timeout")
    assert timeout.body["reason"] == "agent 'detector-house' left"
    assert outcome.agents["detector-house"].startswith("dead: left") and outcome.agents["asker"] == "ok"
    records = read_trace(tmp_path / "t.trace")
    assert [r["agent"] for r in records if r["kind"] == "agent_leave"][0] == "detector-house"
    (traced,) = [r for r in records if r["kind"] == "timeout"]
    assert traced["agent"] == "asker" and traced["addressed_to"] == "detector-house"


def test_post_to_an_already_dead_agent_times_out(run_id: str) -> None:
    with Runtime(run_id=run_id) as rt:
        rt.add(f"{AGENTS}:Asker", name="asker")
        rt.add(f"{AGENTS}:Silent", name="det")
        rt.kill("det")
        rt.run(timeout_s=10)
        rt.post("ask", {"to": "det", "q": "?", "deadline_s": 60})
        rt.run(timeout_s=10)
        assert [h.body["reason"] for h in rt.hypotheses("timeout")] == ["agent 'det' left"]


@pytest.mark.parametrize(
    "call", [lambda rt: rt.add(f"{AGENTS}:Doubler", name="d"), lambda rt: rt.post("number", {})], ids=["add", "post"]
)
def test_runtime_needs_to_be_started(run_id: str, call) -> None:
    with pytest.raises(BlackboardError, match="context manager"):
        call(Runtime(run_id=run_id))


@pytest.mark.parametrize("mode", MODES)
def test_user_zenoh_config_file(run_id: str, mode: str, tmp_path: Path) -> None:
    config = tmp_path / "zenoh.json5"
    config.write_text("{ scouting: { multicast: { enabled: false } }, transport: { unicast: { lowlatency: false } } }")
    with Runtime(run_id=run_id, mode=mode, zenoh=ZenohOptions(config_file=config)) as rt:
        rt.add(f"{AGENTS}:Doubler", name="doubler")
        rt.post("number", {"x": 5})
        rt.run(timeout_s=20)
        assert [h.body["x"] for h in rt.hypotheses("doubled")] == [10]
