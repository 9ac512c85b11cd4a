"""Viewframes at and between the route points (models.route_views)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.route_views import (
    first_per_point,
    route_points_of,
    shown_view,
    view_count,
    view_on_point,
    view_route,
    views_of_points,
)
from models.viewframes import route_headings

ROUTE = [[0.0, 0.0], [30.0, 0.0], [30.0, 40.0], [-10.0, 40.0], [-10.0, 50.0]]


def test_one_view_per_leg_is_the_route_points():
    xy, heading, point = view_route(ROUTE, 1)
    assert xy.tolist() == ROUTE
    assert heading.tolist() == pytest.approx(route_headings(ROUTE))
    assert point.tolist() == list(range(len(ROUTE)))


@pytest.mark.parametrize("views", [2, 3, 4, 5])
def test_views_between_the_points_stand_on_the_legs_and_look_along_them(views):
    xy, heading, point = view_route(ROUTE, views)
    pts, heads = np.asarray(ROUTE), route_headings(ROUTE)
    assert len(xy) == len(heading) == len(point) == view_count(len(ROUTE), views) == views * (len(ROUTE) - 1) + 1
    for k in range(len(ROUTE)):
        assert xy[view_on_point(k, views)].tolist() == pytest.approx(ROUTE[k])  # view F k stands on route point k
    for v in range(len(xy)):
        leg = min(v // views, len(ROUTE) - 2)
        a, b = pts[leg], pts[leg + 1]
        # on its leg, looking along it
        (ux, uy), (wx, wy) = b - a, xy[v] - a
        assert abs(ux * wy - uy * wx) < 1e-9 and 0 <= ux * wx + uy * wy <= ux * ux + uy * uy + 1e-9
        assert heading[v] == pytest.approx(heads[leg])
        # its route point is the nearer end of the leg (the first at exactly half)
        da, db = math.dist(xy[v], a), math.dist(xy[v], b)
        assert point[v] == (leg if da <= db else leg + 1)
    assert (np.diff(point) >= 0).all()


@pytest.mark.parametrize("views", [1, 3])
def test_the_views_of_route_points_are_theirs_and_cover_them(views):
    _, _, point = view_route(ROUTE, views)
    for first in range(len(ROUTE)):
        for last in range(first, len(ROUTE)):
            lo, hi = views_of_points(point, first, last)
            assert set(point[lo : hi + 1].tolist()) == set(range(first, last + 1))
            assert (lo == 0 or point[lo - 1] < first) and (hi == len(point) - 1 or point[hi + 1] > last)


def test_a_views_per_leg_below_one_is_refused():
    with pytest.raises(ValueError, match="views_per_leg"):
        view_route(ROUTE, 0)


@pytest.mark.parametrize(
    "record, views, shown",
    [
        ({"viewframe": 2, "view": 7, "frame_only": {"viewframe": 2}}, 3, 7),  # the decision's own view
        ({"viewframe": 3, "view": 7, "frame_only": {"viewframe": 2}}, 3, 9),  # the track's point: the view on it
        ({"viewframe": 4, "view": 4}, 1, 4),
        ({"viewframe": None, "view": None}, 3, None),
    ],
)
def test_the_view_shown_for_an_answer(record, views, shown):
    assert shown_view(record, views) == shown


def test_the_first_viewframe_of_each_route_point_in_ranking_order():
    _, _, point = view_route(ROUTE, 3)  # 0 0 1 1 1 2 2 2 3 3 3 4 4
    ranking = [(4, 0.1), (3, 0.2), (0, 0.3), (12, 0.4), (1, 0.5), (9, 0.6)]
    assert first_per_point(ranking, point) == [(4, 0.1), (0, 0.3), (12, 0.4), (9, 0.6)]


@pytest.mark.parametrize("views, expected", [(1, None), (3, view_route(ROUTE, 3)[2].tolist())])
def test_a_scenarios_route_points_are_none_with_a_viewframe_a_point(views, expected):
    from models.scenario import scenario_from_dict

    sc = scenario_from_dict(
        {
            "name": "rp",
            "terrain": {"cell_size": 10.0, "procedural": {"size": 32, "relief": 10.0, "seed": 1}},
            "route": [[x + 100, y + 100] for x, y in ROUTE],
            "camera": {"width": 32, "height": 24, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 900.0},
            "render": {"views_per_leg": views},
        }
    )
    assert route_points_of(sc) == expected
