"""Pending addressed posts and their deadlines, on a clock the test moves."""

from __future__ import annotations

from blackboard.deadlines import Deadlines
from blackboard.hypothesis import Hypothesis


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _post(hyp_id: str, *, to: str | None = "det", deadline_s: float | None = None) -> Hypothesis:
    return Hypothesis.new("query", {}, source="asker", id=hyp_id, addressed_to=to, deadline_s=deadline_s)


def test_only_addressed_or_timed_posts_are_expected() -> None:
    d = Deadlines(Clock())
    assert not d.expect(Hypothesis.new("x", {}, source="a"))
    assert d.expect(_post("q1")) and d.expect(_post("q2", to=None, deadline_s=1.0))
    assert "q1" in d and "q2" in d and bool(d)


def test_an_answer_linking_to_it_ends_the_wait() -> None:
    d = Deadlines(Clock())
    d.expect(_post("q1", deadline_s=5.0))
    d.answered(["other", "q1"])
    assert not d and d.due() == []


def test_deadlines_fire_in_order_with_a_reason() -> None:
    clock = Clock()
    d = Deadlines(clock)
    d.expect(_post("late", deadline_s=10.0))
    d.expect(_post("soon", deadline_s=2.0))
    d.expect(_post("never"))
    assert d.wait_s() == 2.0 and d.any_deadline()
    clock.now += 5.0
    assert d.due() == [("soon", "no answer within 2.0 s from agent 'det'")]
    assert "soon" in d  # still pending until popped (the node times it out)
    assert d.pop("soon") is not None and d.pop("soon") is None
    assert d.wait_s() == 5.0
    clock.now += 20.0
    assert [i for i, _ in d.due()] == ["late"] and d.wait_s() is None


def test_a_popped_post_does_not_fire() -> None:
    clock = Clock()
    d = Deadlines(clock)
    d.expect(_post("q", deadline_s=1.0))
    d.pop("q")
    clock.now += 2.0
    assert d.due() == []


def test_posts_addressed_to_an_agent() -> None:
    d = Deadlines(Clock())
    d.expect(_post("a", to="det"))
    d.expect(_post("b", to="other"))
    d.expect(_post("c", to="det", deadline_s=3.0))
    assert d.addressed_to("det") == ["a", "c"] and d.addressed_to("nobody") == []
