"""Joining, declarations, liveliness tokens and the waiters of a run's membership."""

from __future__ import annotations

import threading

import pytest

from blackboard.membership import AgentState, JoinRefused, Membership, gone_phrase


def _join(m: Membership, name: str, *, produces=(), exclusive=(), consumes=()) -> AgentState | JoinRefused:
    return m.join(
        name, {"consumes": list(consumes), "produces": list(produces), "exclusive": list(exclusive), "pid": 42}
    )


def test_join_records_the_declarations() -> None:
    m = Membership()
    state = _join(m, "a", consumes=["x"], produces=["y"])
    assert isinstance(state, AgentState) and state.live and state.pid == 42
    assert (state.consumes, state.produces, state.exclusive) == (("x",), ("y",), ())
    assert m.get("a") is state and m.live() == [state]


@pytest.mark.parametrize(
    ("request_", "error", "text"),
    [
        ({"produces": 7}, "malformed", "not iterable"),
        ({}, "malformed", "bad agent name"),
    ],
)
def test_malformed_joins(request_: dict, error: str, text: str) -> None:
    name = "bad name" if not request_ else "a"
    refused = Membership().join(name, request_)
    assert isinstance(refused, JoinRefused) and refused.reply["error"] == error and text in refused.reply["message"]


def test_a_live_name_and_a_second_exclusive_writer_are_refused() -> None:
    m = Membership()
    _join(m, "owner", produces=["pos"], exclusive=["pos"])
    again = _join(m, "owner")
    assert isinstance(again, JoinRefused) and "already joined" in again.reply["message"]
    second = _join(m, "other", produces=["pos"])
    assert isinstance(second, JoinRefused) and (second.level, second.other) == ("pos", "owner")
    # claiming exclusively what a live agent writes is refused too
    _join(m, "writer", produces=["z"])
    third = _join(m, "claimer", produces=["z"], exclusive=["z"])
    assert isinstance(third, JoinRefused) and third.other == "writer"
    # a dead agent's name and levels are free again
    owner = m.get("owner")
    assert owner is not None
    m.set_state(owner, "dead: crashed")
    assert isinstance(_join(m, "owner", produces=["pos"], exclusive=["pos"]), AgentState)


def test_declaration_problems() -> None:
    m = Membership()
    _join(m, "a", produces=["x"])
    assert m.declaration_problem("a", "x") is None
    assert "not declared in produces" in (m.declaration_problem("a", "y") or "")
    assert m.declaration_problem("stranger", "x") is None  # not joined: the node's other checks apply
    _join(m, "owner", produces=["pos"], exclusive=["pos"])
    assert "exclusively by agent 'owner'" in (m.declaration_problem("stranger", "pos") or "")
    assert m.declaration_problem("owner", "pos") is None


def test_presence_needs_the_token_or_a_death() -> None:
    m = Membership()
    _join(m, "a")
    _join(m, "b")
    joined = threading.Event()
    m.await_join(frozenset({"a", "b"}), joined)
    assert not joined.is_set() and m.missing(["a", "b", "c"]) == ["a", "b", "c"]
    m.token("a", True)
    m.check_presence()
    assert m.missing(["a", "b"]) == ["b"] and not joined.is_set()
    b = m.get("b")
    assert b is not None
    m.set_state(b, "dead: setup failed")
    m.check_presence()
    assert joined.is_set() and m.connected() == ["a"]


def test_gone_waiters_wait_for_every_token() -> None:
    m = Membership()
    m.token("a", True)
    gone = threading.Event()
    m.await_gone(gone)
    assert not gone.is_set()
    m.token("a", False)
    m.check_presence()
    assert gone.is_set()


@pytest.mark.parametrize(
    ("state", "phrase"),
    [
        ("dead: left (liveliness token dropped)", "left"),
        ("dead: 3 failures", "is dead: 3 failures"),
        ("stopped", "stopped"),
    ],
)
def test_gone_phrase(state: str, phrase: str) -> None:
    assert gone_phrase(state) == phrase
