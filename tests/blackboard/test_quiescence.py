"""The quiescence decision from the node's counters and the agents' idle reports."""

from __future__ import annotations

from collections import Counter

from blackboard.deadlines import Deadlines
from blackboard.hypothesis import Hypothesis
from blackboard.membership import AgentState
from blackboard.quiescence import Quiescence, StepKind


def _agent(name: str = "a", consumes: tuple[str, ...] = ("x",)) -> AgentState:
    return AgentState(name, consumes, (), ())


def _idle(agent: AgentState, *, recv: dict, sent: int = 0, probe: int | None = None, timeouts: int = 0) -> None:
    agent.status = {"state": "idle", "recv": recv, "sent": sent, "probe": probe, "timeouts": timeouts}


def test_caught_up_compares_every_counter() -> None:
    received: Counter[str] = Counter()
    q = Quiescence(received)
    a = _agent()
    assert not q.caught_up(a)  # no report yet
    q.sample("x")
    _idle(a, recv={"x": 0})
    assert not q.caught_up(a)  # has not received the sample on x
    _idle(a, recv={"x": 1})
    assert q.caught_up(a)
    q.sample("other")  # a level it does not consume
    assert q.caught_up(a)
    received["a"] += 1  # the node got a post from it that its report does not count
    assert not q.caught_up(a)
    _idle(a, recv={"x": 1}, sent=1)
    a.timeouts_sent = 1
    assert not q.caught_up(a)
    a.status["state"] = "busy"  # type: ignore[index]
    assert not q.caught_up(a)


def test_probe_then_quiescent_and_a_change_means_a_new_probe() -> None:
    q = Quiescence(Counter())
    a = _agent()
    d = Deadlines()
    _idle(a, recv={})
    step = q.step([a], held=False, deadlines=d)
    assert step.kind is StepKind.PROBE and step.probe == 1
    assert q.step([a], held=False, deadlines=d).kind is StepKind.WAIT  # not answered yet
    _idle(a, recv={}, probe=1)
    assert q.step([a], held=False, deadlines=d).kind is StepKind.QUIESCENT
    q.change()
    assert q.step([a], held=False, deadlines=d).probe == 2


def test_held_requests_and_deadlines_wait() -> None:
    q = Quiescence(Counter())
    a = _agent()
    _idle(a, recv={}, probe=1)
    d = Deadlines()
    assert q.step([a], held=True, deadlines=d).kind is StepKind.WAIT
    d.expect(Hypothesis.new("q", {}, source="a", id="q1", addressed_to="b", deadline_s=5.0))
    assert q.step([a], held=False, deadlines=d).kind is StepKind.WAIT  # the deadline will fire


def test_posts_without_deadline_are_timed_out_when_all_are_idle() -> None:
    q = Quiescence(Counter())
    a = _agent()
    _idle(a, recv={})
    d = Deadlines()
    d.expect(Hypothesis.new("q", {}, source="a", id="q1", addressed_to="b"))
    step = q.step([a], held=False, deadlines=d)
    assert step.kind is StepKind.TIME_OUT and step.time_out == ("q1",)


def test_no_agents_is_quiescent_at_once_and_release_sets_waiters() -> None:
    import threading

    q = Quiescence(Counter())
    waiter = threading.Event()
    q.waiters.append(waiter)
    assert q.step([], held=False, deadlines=Deadlines()).kind is StepKind.QUIESCENT
    q.release()
    assert waiter.is_set() and q.waiters == []
