"""Pure trace views over a hand-made record list (filters, frame closure, chain, summary)."""

from __future__ import annotations

import json

import pytest

from blackboard.trace_view import (
    derivation_chain,
    filter_records,
    frame_ids,
    render_chain,
    render_summary,
    render_timeline,
    summarize,
    to_json,
)


def _post(seq: int, agent: str, level: str, id: str, links: tuple[str, ...] = (), **body: object) -> dict:
    return {
        "seq": seq,
        "t": 100.0 + seq,
        "kind": "post",
        "agent": agent,
        "level": level,
        "id": id,
        "version": 1,
        "links": list(links),
        "credibility": 1.0,
        "body": body,
    }


RECORDS = [
    {"seq": 1, "t": 100.0, "kind": "run_start", "run_id": "r1"},
    {"seq": 2, "t": 100.5, "kind": "agent_join", "agent": "det"},
    _post(3, "user", "sensor_frame", "f1", frame=1),
    _post(4, "user", "sensor_frame", "f2", frame=2),
    _post(5, "det", "detection", "d1", ("f1",), what="house"),
    _post(6, "det", "detection", "d2", ("f2",), what="tree"),
    _post(7, "ranker", "ranking", "r1", ("d1", "d2")),
    _post(8, "ranker", "position", "p1", ("r1", "ghost")),
    {
        "seq": 9,
        "t": 109.0,
        "kind": "activation_finish",
        "agent": "det",
        "level": "sensor_frame",
        "id": "f1",
        "version": 1,
        "duration_s": 0.25,
    },
    {
        "seq": 10,
        "t": 110.0,
        "kind": "activation_error",
        "agent": "det",
        "level": "sensor_frame",
        "id": "f2",
        "version": 1,
        "duration_s": 0.5,
        "message": "act raised ValueError: x",
    },
    {"seq": 11, "t": 111.0, "kind": "timeout", "agent": "ranker", "id": "q1", "reason": "agent 'det' left"},
    {"seq": 12, "t": 112.0, "kind": "rejected", "key": "mapinterp/r1/x/y", "message": "malformed message"},
]


FILTERS = {
    "agent": ({"agent": "det"}, [2, 5, 6, 9, 10]),
    "level": ({"level": "detection"}, [5, 6]),
    "id": ({"id": "f2"}, [4, 10]),
    "agent and level": ({"agent": "det", "level": "sensor_frame"}, [9, 10]),
    "frame 1": ({"frame": 1}, [3, 5, 7, 8, 9]),
    "frame as text": ({"frame": "2"}, [4, 6, 7, 8, 10]),
    "no match": ({"agent": "nobody"}, []),
}


@pytest.mark.parametrize(("filters", "seqs"), FILTERS.values(), ids=FILTERS.keys())
def test_filters(filters: dict, seqs: list[int]) -> None:
    assert [r["seq"] for r in filter_records(RECORDS, **filters)] == seqs


def test_frame_closure_follows_links_forward() -> None:
    assert frame_ids(RECORDS, 1) == {"f1", "d1", "r1", "p1"}
    assert frame_ids(RECORDS, 99) == set()


def test_chain_goes_back_to_the_inputs() -> None:
    chain = derivation_chain(RECORDS, "p1")
    assert [r["id"] for r in chain] == ["p1", "r1", "ghost", "d1", "d2", "f1", "f2"]
    assert chain[2]["kind"] == "missing"
    assert derivation_chain(RECORDS, "nope") == []
    text = render_chain(chain)
    assert "position/p1 v1 by ranker" in text and "ghost: not in the trace" in text and "<- input" in text


def test_summary() -> None:
    s = summarize(RECORDS)
    assert s["run_id"] == "r1" and s["records"] == 12 and s["duration_s"] == pytest.approx(12.0)
    assert not s["complete"]
    assert s["levels"] == {"detection": 2, "position": 1, "ranking": 1, "sensor_frame": 2}
    det = s["agents"]["det"]
    assert (det["posts"], det["activations"], det["errors"], det["act_s"], det["act_max_s"]) == (2, 1, 1, 0.75, 0.5)
    assert s["timeouts"] == [{"id": "q1", "agent": "ranker", "reason": "agent 'det' left"}]
    text = render_summary(s)
    assert "incomplete" in text and "rejected: malformed message" in text and "agent 'det' left" in text


def test_timeline_and_json() -> None:
    lines = render_timeline(RECORDS).splitlines()
    assert len(lines) == len(RECORDS)
    assert lines[4].split()[:3] == ["5.0000s", "post", "det"] and "<- f1" in lines[4]
    assert render_timeline([]) == "(no records)"
    back = json.loads(to_json(summarize(RECORDS)))
    assert back["agents"]["ranker"]["posts"] == 2
    assert json.loads(to_json([{"b": b"xyz"}])) == [{"b": {"__bytes__": 3}}]


@pytest.mark.parametrize("by_reference", [False, True], ids=["inline", "by-reference"])
def test_a_viewframe_by_reference_reads_as_its_entry_and_row(by_reference: bool) -> None:
    """A viewframe posted by reference to a cache entry shows the entry's key and its row, not the
    pixel fields it leaves out; an inline one its scalar fields as any post."""
    entry = "/cache/mapinterp/430201c04bb23e34b89d8db100d61ceb489f8c8fb4851def4e034a2024cb6ec1"
    body = {"index": 7, "entry": entry, "entry_count": 10, "image": None} if by_reference else {"index": 7}
    text = render_timeline([_post(1, "map-renderer", "viewframe", "vf-000007", **body)])
    if by_reference:
        assert "index=7 pixels in cache entry 430201c04bb23e34 (row 7 of 10)" in text and "image" not in text
    else:
        assert "index=7" in text and "cache entry" not in text
