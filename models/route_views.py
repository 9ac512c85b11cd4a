"""Where the viewframes of a route stand: at the route points, and optionally between them.

A viewframe is the view from a place on the route looking along it. With one per leg (the seed
paper's) they stand on the route points, viewframe k looking at route point k + 1. A camera
between two route points looks along the leg it drives on, so it sees what viewframe k sees from
a little further on, and with one viewframe per point it matches the point behind it best even
when it is nearer the one ahead. ``render.views_per_leg`` F > 1 adds F - 1 viewframes on each leg,
evenly along it and looking along it; each viewframe belongs to the route point nearest it along
its leg, which is what the answer names (:func:`view_route`).

World coordinates ``(x, y)`` in metres; headings counterclockwise from +x, degrees.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from models.camera_emulator import Pose
    from models.scenario import Scenario
    from models.terrain import Terrain

__all__ = [
    "view_count",
    "view_route",
    "view_points",
    "view_poses",
    "route_points_of",
    "view_on_point",
    "views_of_points",
    "first_per_point",
    "shown_view",
]


def view_count(points: int, views_per_leg: int = 1) -> int:
    """The number of viewframes of a route of ``points`` route points (:func:`view_route`'s V)."""
    return int(views_per_leg) * (int(points) - 1) + 1 if points > 1 else int(points)


def view_route(route: ArrayLike, views_per_leg: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The viewframes' places on ``route`` (N, 2): ``(xy (V, 2), heading_deg (V,), route_point (V,) int)``.

    ``views_per_leg`` F: on each leg from route point k to k + 1, views at fractions
    ``0, 1/F, ..., (F-1)/F`` of it, all looking along the leg (route point k's heading), then the
    last route point with the last leg's heading; V = F (N - 1) + 1, and with F = 1 the route
    points themselves with :func:`models.viewframes.route_headings`. ``route_point[v]``: the route
    point nearest view v along its leg (k up to half the leg, k + 1 beyond), non-decreasing; view
    ``F k`` stands on route point k.
    """
    from models.viewframes import route_headings  # (it imports the renderer: not at module import)

    pts = np.asarray(route, dtype=np.float64).reshape(-1, 2)
    f = int(views_per_leg)
    if f < 1:
        raise ValueError(f"views_per_leg must be >= 1, got {views_per_leg}")
    heads = np.asarray(route_headings(pts), dtype=np.float64)
    if f == 1 or len(pts) < 2:
        return pts.copy(), heads, np.arange(len(pts), dtype=np.int64)
    t = np.arange(f, dtype=np.float64) / f
    xy = (pts[:-1, None, :] + t[None, :, None] * (pts[1:] - pts[:-1])[:, None, :]).reshape(-1, 2)
    xy = np.vstack([xy, pts[-1:]])
    heading = np.append(np.repeat(heads[:-1], f), heads[-1])
    return xy, heading, view_points(len(pts), f)


def view_points(points: int, views_per_leg: int = 1) -> np.ndarray:
    """The route point of each viewframe ``(V,)`` of a route of ``points`` route points
    (:func:`view_route`'s third array, without the route: on the leg from k to k + 1 the views up
    to half of it are k's, those beyond k + 1's)."""
    f, legs = int(views_per_leg), int(points) - 1
    if f < 1:
        raise ValueError(f"views_per_leg must be >= 1, got {views_per_leg}")
    if f == 1 or legs < 1:
        return np.arange(max(int(points), 0), dtype=np.int64)
    t = np.arange(f, dtype=np.float64) / f
    return np.append((np.arange(legs)[:, None] + (t[None, :] > 0.5)).ravel(), legs).astype(np.int64)


def view_poses(scenario: Scenario, terrain: Terrain) -> list[Pose]:
    """The camera pose of each viewframe of ``scenario``: :func:`view_route` of its route with its
    ``render.views_per_leg``, standing ``camera.eye_height`` above the terrain (with one view per
    leg, :func:`models.viewframes.route_poses`)."""
    from models.camera_emulator import Pose

    cam = scenario.camera
    xy, heading, _ = view_route(scenario.route, scenario.views_per_leg)
    return [
        Pose(float(x), float(y), float(terrain.height_at(x, y)) + cam.eye_height, float(h), cam.pitch_deg)
        for (x, y), h in zip(xy.tolist(), heading.tolist())
    ]


def route_points_of(scenario: Scenario) -> list[int] | None:
    """The route point of each viewframe of ``scenario`` (:func:`view_route`), or None when the
    viewframes are the route points (one a leg): the map's ``route_points``."""
    if scenario.views_per_leg == 1:
        return None
    return view_route(scenario.route, scenario.views_per_leg)[2].tolist()


def view_on_point(point: int, views_per_leg: int = 1) -> int:
    """The viewframe standing on route point ``point`` (:func:`view_route`: ``views_per_leg`` times it)."""
    return int(point) * int(views_per_leg)


def first_per_point(ranking: Sequence[Sequence[float]], route_points: ArrayLike) -> list[tuple[int, float]]:
    """The entries ``(viewframe, score)`` of ``ranking`` that are the first of their route point
    (``route_points``: each viewframe's), in the ranking's order: a best-first ranking's best
    viewframe of each route point."""
    rp = np.asarray(route_points)
    seen: set[int] = set()
    out = []
    for k, v in ranking:
        point = int(rp[int(k)])
        if point not in seen:
            seen.add(point)
            out.append((int(k), float(v)))
    return out


def views_of_points(route_points: ArrayLike, first: int, last: int) -> tuple[int, int]:
    """The viewframes ``(first, last)`` (inclusive) of the route points ``first..last``, given each
    viewframe's route point ``route_points`` (V,), non-decreasing (:func:`view_route`'s)."""
    rp = np.asarray(route_points)
    lo = int(np.searchsorted(rp, int(first), side="left"))
    hi = int(np.searchsorted(rp, int(last), side="right")) - 1
    return min(lo, len(rp) - 1), max(min(hi, len(rp) - 1), 0)


def shown_view(record: Mapping[str, Any], views_per_leg: int = 1) -> int | None:
    """The viewframe that shows a results ``record``'s answer: the single-frame decision's own view
    when the answer is its route point, else the view standing on the answer's route point
    (``views_per_leg`` times it); None when the frame was not localized."""
    point = record.get("viewframe")
    if point is None:
        return None
    view = record.get("view")
    if view is not None and (record.get("frame_only") or {}).get("viewframe", point) == point:
        return int(view)
    return view_on_point(point, views_per_leg)
