"""Every key expression of a run comes from RunKeys, and a read selector round-trips its parameters."""

from __future__ import annotations

import pytest
import zenoh

from blackboard.keys import RunKeys, read_parameters

KEYS = RunKeys("r1")


def test_control_keys_live_under_the_verbatim_ctl_chunk() -> None:
    control = [KEYS.status, KEYS.request, KEYS.probe, KEYS.node_token, KEYS.run_end, KEYS.inbox("a")]
    assert all(k.startswith("mapinterp/r1/@ctl/") for k in control) and len(set(control)) == len(control)
    hypotheses = zenoh.KeyExpr(KEYS.all_hypotheses)
    assert not any(hypotheses.intersects(zenoh.KeyExpr(k)) for k in control)
    assert not hypotheses.intersects(zenoh.KeyExpr(KEYS.liveliness("a")))


def test_hypothesis_keys() -> None:
    assert KEYS.hypothesis("answer", "h-1") == "mapinterp/r1/answer/h-1"
    assert KEYS.any_level("h-1") == "mapinterp/r1/*/h-1"
    assert KEYS.level("answer") == "mapinterp/r1/answer/*"
    assert KEYS.liveliness_agent(KEYS.liveliness("detector-house")) == "detector-house"


@pytest.mark.parametrize(
    ("key", "pattern"),
    [
        ("mapinterp/r1/answer/h-1", ("answer", "h-1")),
        ("mapinterp/r1/*/h-1", ("*", "h-1")),
        ("mapinterp/r1/*/*", ("*", "*")),
        ("mapinterp/r1/a/h-$*", None),
        ("mapinterp/r1/**", None),
    ],
)
def test_hypothesis_pattern(key: str, pattern: tuple[str, str] | None) -> None:
    assert KEYS.hypothesis_pattern(key) == pattern


@pytest.mark.parametrize("seen", [{}, {"camera": 3}, {"camera": 3, "indexer-0": 12}])
def test_read_selector_round_trip(seen: dict[str, int]) -> None:
    selector = zenoh.Selector(KEYS.read_selector(KEYS.level("x"), agent="a", sent=5, seen=seen))
    assert str(selector.key_expr) == KEYS.level("x")
    assert read_parameters(selector.parameters) == ("a", 5, seen)


def test_malformed_read_parameters_read_as_nothing() -> None:
    assert read_parameters({"agent": "a", "sent": "many"}) == ("a", 0, {})
    assert read_parameters({"agent": "a", "sent": "2", "after": "x:1,y"}) == ("a", 0, {})
    assert read_parameters({}) == ("", 0, {})
