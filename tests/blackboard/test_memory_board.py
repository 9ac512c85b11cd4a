"""The in-memory blackboard follows the distributed one's rules (same tiny agents as test_runtime)."""

from __future__ import annotations

import numpy as np
import pytest

from blackboard.errors import BlackboardError, CodecError, DeclarationError
from blackboard.knowledge_source import Board, EventKind
from blackboard.memory_board import MemoryBlackboard, MemoryBoard
from blackboard.zenoh_board import ZenohBoard
from tests.blackboard.agents import (
    Asker,
    Booster,
    Bumper,
    Doubler,
    Echo,
    Exclusive,
    Failing,
    LateCounter,
    Picky,
    Recorder,
    Rogue,
    Silent,
    Updater,
)


def test_both_boards_implement_the_board_protocol() -> None:
    assert isinstance(MemoryBlackboard().user, Board)
    assert all(callable(getattr(ZenohBoard, name)) for name in ("post", "update", "retract", "get", "query"))


def test_a_chain_of_agents_runs_to_the_end() -> None:
    bb = MemoryBlackboard()
    bb.add(Doubler("doubler"))
    bb.add(Echo("echo"))
    for x in (1, 2, 3):
        bb.post("number", {"x": x})
    assert bb.run() == 6
    assert sorted(h.body["x"] for h in bb.hypotheses("echo")) == [2, 4, 6]
    doubled = {h.id: h for h in bb.hypotheses("doubled")}
    assert all(h.links[0] in doubled for h in bb.hypotheses("echo"))


def test_an_agent_gets_only_the_messages_it_wants() -> None:
    bb = MemoryBlackboard(raise_errors=True)  # a precondition on a declined message would raise
    bb.add(Picky("picky"))
    for x in range(6):
        bb.post("number", {"x": x}, id=f"n-{x}")
    bb.run()
    assert sorted(h.body["x"] for h in bb.hypotheses("doubled")) == [0, 4, 8]


def test_bodies_travel_through_the_codec() -> None:
    bb = MemoryBlackboard()
    bb.add(Echo("echo"))
    sent = np.arange(3, dtype=np.int16)
    bb.post("doubled", {"pair": (1, 2), "a": sent})
    bb.run()
    (echo,) = bb.hypotheses("echo")
    assert echo.body["pair"] == [1, 2]
    assert echo.body["a"].dtype == np.int16 and np.array_equal(echo.body["a"], sent) and echo.body["a"] is not sent
    with pytest.raises(CodecError):
        bb.post("doubled", {"bad": object()})


def test_agenda_runs_highest_rating_first_in_posting_order() -> None:
    bb = MemoryBlackboard()
    rec = Recorder("rec")
    bb.add(rec)
    for x, rating in ((1, 0.0), (2, 5.0), (3, 1.0), (4, 5.0)):
        bb.post("number", {"x": x, "rating": rating})
    bb.run()
    assert [x for _, x in rec.seen] == [2, 4, 3, 1]


def test_setup_reads_what_is_already_there() -> None:
    bb = MemoryBlackboard()
    bb.post("number", {"x": 5})
    bb.post("number", {"x": 7})
    bb.add(LateCounter("late"))
    (count,) = bb.hypotheses("count")
    assert count.body == {"n": 2, "sum": 12}


def test_updates_version_and_obviate_the_older_activation() -> None:
    bb = MemoryBlackboard()
    rec = Recorder("rec")
    bb.add(Bumper("bumper"))
    bb.add(rec)
    bb.post("bump", {})
    bb.run()
    (number,) = bb.hypotheses("number")
    assert number.version == 2 and number.body["x"] == 2
    assert rec.seen == [("updated", 2)]  # the posted version 1 was superseded before it ran


def test_updates_merge_and_a_superseded_post_is_not_acted_on() -> None:
    bb = MemoryBlackboard()
    bb.add(Updater("u1", n=3))
    bb.add(Updater("u2", n=2))
    h = bb.post("target", {"origin": True})
    bb.run()
    got = bb.user.get(h.id)
    # u1 runs first; its updates reach u2 before u2's activation for version 1 runs: obviated
    assert got is not None and got.version == 1 + 3
    assert got.body == {"origin": True, "u1-0": 0, "u1-1": 1, "u1-2": 2}


def test_own_posts_reach_the_poster_when_it_consumes_the_level() -> None:
    bb = MemoryBlackboard()
    bb.add(Doubler("doubler"))
    bb.add(Booster("booster"))
    bb.post("number", {"x": 1})
    bb.run()
    (doubled,) = bb.hypotheses("doubled")
    assert doubled.body["boosted"] is True and doubled.credibility == 0.5 and doubled.version == 2


def test_declarations_are_enforced() -> None:
    bb = MemoryBlackboard()
    bb.add(Rogue("rogue"))
    bb.post("number", {"x": 1})
    with pytest.raises(DeclarationError, match="position"):
        bb.run()
    bb.add(Exclusive("owner"))
    with pytest.raises(DeclarationError, match="exclusively"):
        bb.add(Exclusive("second"))
    with pytest.raises(DeclarationError, match="already joined"):
        bb.add(Doubler("owner"))


def test_update_and_retract_check_level_and_existence() -> None:
    bb = MemoryBlackboard()
    board = bb.add(Doubler("doubler"))
    n = bb.post("number", {"x": 1})
    with pytest.raises(DeclarationError):
        board.update(n.id, body={"x": 2})
    with pytest.raises(BlackboardError, match="no hypothesis"):
        board.retract("nope")
    bb.user.retract(n.id)
    assert bb.user.get(n.id) is None
    assert [e.kind for e in bb.events] == [EventKind.POSTED, EventKind.RETRACTED]


def test_a_duplicate_id_is_rejected_as_the_node_does() -> None:
    bb = MemoryBlackboard()
    bb.post("number", {"x": 1}, id="n-1")
    bb.post("number", {"x": 2}, id="n-1")
    assert [h.body["x"] for h in bb.hypotheses("number")] == [1]
    assert len(bb.rejected) == 1 and "already exists" in bb.rejected[0][1]


def test_an_answered_query_does_not_time_out() -> None:
    bb = MemoryBlackboard()
    bb.add(Asker("asker"))
    bb.add(Echo("echo"))
    bb.post("ask", {"to": "echo", "q": 1, "deadline_s": 5.0})
    bb.run()
    assert [h.body["q"] for h in bb.hypotheses("answer")] == [1]
    assert bb.hypotheses("timeout") == []


@pytest.mark.parametrize(
    ("addressee", "reason"), [("silent", "went idle without answering"), ("nobody", "is not on the board")]
)
def test_an_unanswered_query_times_out_to_its_poster(addressee: str, reason: str) -> None:
    bb = MemoryBlackboard()
    bb.add(Asker("asker"))
    bb.add(Silent("silent"))
    bb.post("ask", {"to": addressee, "q": 7})
    bb.run()
    (timeout,) = bb.hypotheses("timeout")
    assert timeout.body["q"] == 7 and reason in timeout.body["reason"] and addressee in timeout.body["reason"]


def test_errors_propagate_by_default_and_kill_after_max_failures_otherwise() -> None:
    bb = MemoryBlackboard()
    bb.add(Failing("failing"))
    bb.post("number", {"x": 1})
    with pytest.raises(RuntimeError, match="cannot handle 1"):
        bb.run()
    quiet = MemoryBlackboard(raise_errors=False)
    quiet.add(Failing("failing"))
    for x in range(5):
        quiet.post("number", {"x": x})
    quiet.run()
    assert len(quiet.errors) == 3 and "3 failures" in quiet.dead()["failing"]


def test_the_user_board_is_a_board() -> None:
    bb = MemoryBlackboard()
    assert isinstance(bb.board("user"), MemoryBoard)
    h = bb.user.post("anything", {"k": 1})
    assert bb.user.query("anything")[0].id == h.id
