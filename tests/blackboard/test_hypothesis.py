"""Hypotheses: validation table, record round trip (property), versions, run keys."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from blackboard.codec import decode, encode
from blackboard.errors import CodecError
from blackboard.hypothesis import Hypothesis, validate_name
from blackboard.keys import RunKeys

_names = st.from_regex(r"[A-Za-z0-9_-]{1,20}", fullmatch=True)


@settings(max_examples=100, deadline=None)
@given(
    level=_names,
    source=_names,
    credibility=st.floats(0, 1),
    links=st.lists(_names, max_size=4),
    x=st.integers(-1000, 1000),
    addressed=st.none() | _names,
    deadline=st.none() | st.floats(0.01, 100),
)
def test_record_round_trip(level, source, credibility, links, x, addressed, deadline) -> None:
    h = Hypothesis.new(
        level,
        {"x": x, "a": np.arange(3)},
        source=source,
        credibility=credibility,
        links=links,
        addressed_to=addressed,
        deadline_s=deadline,
    )
    back = Hypothesis.from_record(decode(encode(h.to_record())))
    assert back == h  # compares everything but the body
    assert back.body["x"] == x and back.body["a"].tolist() == [0, 1, 2]
    assert back.id.startswith(f"{source}-") and back.version == 1


BAD = {
    "id with slash": {"id": "a/b"},
    "id with star": {"id": "*"},
    "empty level": {"level": ""},
    "level with space": {"level": "a b"},
    "credibility > 1": {"credibility": 1.5},
    "credibility < 0": {"credibility": -0.1},
    "version 0": {"version": 0},
    "body not a dict": {"body": [1]},
    "bad link": {"links": ("ok", "no/pe")},
    "zero deadline": {"deadline_s": 0.0},
    "bad addressee": {"addressed_to": "x y"},
    "unhashable level": {"level": ["answer"]},
    "unhashable source": {"source": {"s": 1}},
    "unhashable addressee": {"addressed_to": ["a"]},
}


@pytest.mark.parametrize("change", BAD.values(), ids=BAD.keys())
def test_invalid_fields_are_refused(change: dict) -> None:
    fields = {
        "id": "h1",
        "level": "answer",
        "source": "s",
        "credibility": 0.5,
        "links": (),
        "version": 1,
        "timestamp": 0.0,
        "body": {},
        **change,
    }
    with pytest.raises(ValueError):
        Hypothesis(**fields)


@pytest.mark.parametrize(
    "record",
    [
        None,
        [],
        {"id": "h"},
        {"id": "h", "level": "l", "source": "s", "credibility": 2, "version": 1, "timestamp": 0, "body": {}},
    ],
)
def test_from_record_refuses_malformed(record: object) -> None:
    with pytest.raises(CodecError) as info:
        Hypothesis.from_record(record, key="k/e/y")
    assert info.value.key == "k/e/y"


def test_evolve_merges_body_and_bumps_version() -> None:
    h = Hypothesis.new("l", {"a": 1, "b": 2}, source="s")
    h2 = h.evolve(body={"b": 3, "c": 4}, credibility=0.25)
    assert (h2.version, h2.body, h2.credibility, h2.id) == (2, {"a": 1, "b": 3, "c": 4}, 0.25, h.id)
    assert h.body == {"a": 1, "b": 2}


@pytest.mark.parametrize("name", ["a", "A-b_9", "x" * 128])
def test_valid_names(name: str) -> None:
    assert validate_name(name, "level") == name


@pytest.mark.parametrize("name", ["", "x" * 129, "a/b", "@ctl", "a*", "é", 3])
def test_invalid_names(name: object) -> None:
    with pytest.raises(ValueError, match="level"):
        validate_name(name, "level")


def test_run_keys() -> None:
    keys = RunKeys("r1")
    assert keys.hypothesis("answer", "h-1") == "mapinterp/r1/answer/h-1"
    assert keys.split("mapinterp/r1/answer/h-1") == ("answer", "h-1")
    assert keys.split("mapinterp/r2/answer/h-1") is None
    assert keys.split("mapinterp/r1/@ctl/status") == ("@ctl", "status")  # never a level: @ is refused
    with pytest.raises(ValueError):
        RunKeys("a/b")


@pytest.mark.parametrize("change", BAD.values(), ids=BAD.keys())
def test_from_record_refuses_what_the_constructor_refuses(change: dict) -> None:
    """The fast path of from_record validates exactly as the constructor, with the same message."""
    fields = {
        "id": "h1",
        "level": "answer",
        "source": "s",
        "credibility": 0.5,
        "links": (),
        "version": 1,
        "timestamp": 0.0,
        "body": {},
        **change,
    }
    with pytest.raises(ValueError) as direct:
        Hypothesis(**fields)
    with pytest.raises(CodecError) as fast:
        Hypothesis.from_record({**fields, "links": list(fields["links"])}, key="k")
    assert fast.value.message == f"bad hypothesis record: {direct.value}"


def test_fast_construction_equals_the_constructor() -> None:
    h = Hypothesis.new("answer", {"x": 1}, source="s", links=["a", "b"], credibility=1, deadline_s=2)
    direct = Hypothesis(**{f: getattr(h, f) for f in h.__dataclass_fields__})
    assert h == direct and h.body == direct.body and type(h.links) is tuple and type(h.credibility) is float
    assert Hypothesis.from_record(h.to_record()) == h
    with pytest.raises(AttributeError):  # still frozen
        h.version = 3  # type: ignore[misc]


@pytest.mark.parametrize("bad", ["a b", "", "x" * 129, 3, "lvl/x"])
def test_known_names_never_admit_a_bad_one(bad: object) -> None:
    """Names are remembered once valid; a bad one is refused however many good ones came first."""
    for i in range(3):
        Hypothesis.new(f"level{i}", {}, source="known")
    with pytest.raises(ValueError, match="level"):
        Hypothesis.new(bad, {}, source="known")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="source"):
        Hypothesis.new("level0", {}, source=bad, id="h1")  # type: ignore[arg-type]
