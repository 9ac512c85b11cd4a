"""Viewframes between the route points (render.views_per_leg): the rankings of viewframes made
rankings of route points for the tracker and the results, and a whole mission with them."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from knowledge_sources import levels
from knowledge_sources.mission import run_mission
from knowledge_sources.results import frame_record
from knowledge_sources.tracker import by_route_point
from models.route_views import view_count, view_route

POINTS = np.array([0, 0, 1, 1, 1, 2, 2])  # view_route of 3 route points, 3 views a leg


def test_a_route_point_takes_its_viewframes_total_probability_in_nats():
    labels, scores = by_route_point([3, 2, 6, 0], [0.0, 1.0, 2.0, 5.0], POINTS, nats=True)
    assert labels == [1, 2, 0]  # in order of first appearance
    assert scores[0] == pytest.approx(-math.log(math.exp(0.0) + math.exp(-1.0)))
    assert scores[1:] == pytest.approx([2.0, 5.0])


def test_a_route_point_takes_its_best_viewframe_for_scores_without_a_scale():
    labels, scores = by_route_point([3, 2, 6, 5], [0.5, 0.2, 2.0, 1.0], POINTS, nats=False)
    assert dict(zip(labels, scores)) == {1: 0.2, 2: 1.0}


def test_a_results_entry_names_the_route_point_of_the_chosen_viewframe():
    position = levels.Position(
        frame=0,
        viewframe=4,
        position=[20.0, 0.0],
        heading_deg=0.0,
        confidence=0.9,
        queries=1,
        backtracks=0,
        latency_ms=5.0,
        ranking=[[4, 0.0], [3, 0.1], [2, 0.3], [6, 0.4], [0, 0.5]],
        reason="accepted",
        degraded=[],
        steps=[],
        strategy="associative",
    )
    route = [[0.0, 0.0], [30.0, 0.0], [60.0, 0.0]]
    truth = levels.Truth(frame=0, pose=[25.0, 0.0, 0.0])
    rec = frame_record(position, frame=0, truth=truth, route_xy=route, route_points=POINTS.tolist())
    assert rec["viewframe"] == 1 and rec["view"] == 4 and rec["truth_viewframe"] == 1 and rec["correct"]
    assert [k for k, _ in rec["ranking"]] == [1, 2, 0]  # each point once, at its best viewframe's place
    assert rec["error_m"] == pytest.approx(5.0)  # the chosen viewframe's place, not its route point's
    plain = frame_record(position, frame=0, truth=truth, route_xy=route)
    assert plain["viewframe"] == plain["view"] == 4


@pytest.mark.slow
def test_a_mission_with_viewframes_between_the_route_points(small_data, tmp_path):
    """Three viewframes a leg through the whole blackboard (tracking on): the map renderer posts
    every viewframe, each answer is a route point and its position a viewframe's place."""
    views = 3
    data = dict(small_data, render={"views_per_leg": views})  # SMALL has one a point
    path = tmp_path / "views.yaml"
    path.write_text(yaml.safe_dump(data))
    results = run_mission(path, trace_path=tmp_path / "run.trace")
    route = small_data["route"]
    n_views = view_count(len(route), views)
    xy, _, points = view_route(route, views)
    frames = results["frames"]
    assert len(frames) == len(route)
    judged = 0
    for f in frames:
        only = f["frame_only"]
        assert f["view"] is not None and 0 <= f["view"] < n_views
        assert only["viewframe"] == points[f["view"]]  # the decision's route point is its view's
        assert f["route_position"] == pytest.approx(xy[f["view"]].tolist(), abs=1e-6)
        assert 0 <= f["viewframe"] < len(route) and f["state"] in ("tracking", "lost")
        judged += f["correct"] is not None
    assert judged == len(route)
    assert results["summary"]["top1_frame_only"] >= 0.5  # frames at the route points, as the scenario simulates
    from blackboard.trace import read_trace

    posted = {
        r["id"] for r in read_trace(tmp_path / "run.trace") if r["kind"] == "post" and r.get("level") == "viewframe"
    }
    assert len(posted) == n_views
