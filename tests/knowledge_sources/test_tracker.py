"""The tracker knowledge source: frame ordering (pure), and the track through the blackboard."""

from __future__ import annotations

from knowledge_sources.tracker import FrameOrder, answers_of


def test_frames_are_released_in_order_once_complete():
    order = FrameOrder()
    order.position(1, {"frame": 1, "steps": []}, "pos-1")
    order.ranking(1, 0, 2, [0, 2], [0.1, 0.2], 1.0, "rk-1-0")
    order.ranking(1, 1, 2, [1, 3], [0.3, 0.4], 1.0, "rk-1-1")
    assert order.ready() == []  # frame 1 is complete, but frame 0 is not here yet
    order.ranking(0, 0, 2, [0, 2], [0.1, 0.2], 0.0, "rk-0-0")
    order.position(0, {"frame": 0, "steps": []}, "pos-0")
    assert order.ready() == []  # frame 0 still lacks bank 1
    order.ranking(0, 1, 2, [1, 3], [0.3, 0.4], 0.0, "rk-0-1")
    ready = order.ready()
    assert [f for f, _ in ready] == [0, 1]
    assert sorted(ready[0][1].rankings) == [0, 1] and ready[1][1].time == 1.0
    assert ready[0][1].links == ["rk-0-0", "pos-0", "rk-0-1"]
    assert order.ready() == [] and order.next == 2


def test_answers_of_a_position_leave_undecided_out():
    steps = [{"landmark": "H1", "present": True}, {"landmark": "T1", "present": None},
             {"landmark": "H2", "present": False}]
    assert answers_of({"steps": steps}) == [("H1", True), ("H2", False)]
