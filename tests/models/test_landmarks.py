"""Landmark boxes: footprint geometry, base on the terrain, F* raised to the box tops."""

from __future__ import annotations

import numpy as np
import pytest

from models.landmarks import Landmark, place_landmarks, raised_dem
from models.scenario import LandmarkSpec
from models.terrain import Terrain


def _plane(a: float, b: float, n: int = 41, cell: float = 5.0) -> Terrain:
    y, x = np.mgrid[0:n, 0:n] * cell
    return Terrain(heights=100 + a * x + b * y, cell_size=cell)


@pytest.mark.parametrize(
    ("yaw", "expected"),
    [
        (0.0, [[90, 94], [110, 94], [110, 106], [90, 106]]),
        (90.0, [[106, 90], [106, 110], [94, 110], [94, 90]]),
        (180.0, [[110, 106], [90, 106], [90, 94], [110, 94]]),
    ],
)
def test_corners_follow_width_depth_and_ccw_yaw(yaw, expected):
    lm = Landmark("H", "house", 100.0, 100.0, 20.0, 12.0, 8.0, yaw, 3.0)
    np.testing.assert_allclose(lm.corners(), expected, atol=1e-9)
    v = lm.box_vertices()
    assert v.shape == (8, 3)
    np.testing.assert_allclose(v[:4, 2], 3.0)
    np.testing.assert_allclose(v[4:, 2], 11.0)
    assert lm.top == 11.0


@pytest.mark.parametrize(("a", "b", "yaw"), [(0.1, 0.0, 0.0), (-0.2, 0.05, 30.0), (0.0, 0.3, 75.0)])
def test_base_is_the_lowest_of_corners_and_centre(a, b, yaw):
    t = _plane(a, b)
    (lm,) = place_landmarks(
        t, [LandmarkSpec(id="H", kind="house", x=100, y=90, width=20, depth=12, height=8, yaw_deg=yaw)]
    )
    pts = np.vstack([lm.corners(), [[100, 90]]])
    expected = min(100 + a * x + b * y for x, y in pts)
    assert lm.z0 == pytest.approx(expected)
    assert lm.top == pytest.approx(expected + 8)


def test_raised_dem_lifts_exactly_the_cells_inside_footprints():
    t = _plane(0.0, 0.0, n=21, cell=10.0)
    lms = place_landmarks(
        t,
        [
            LandmarkSpec(id="A", kind="house", x=100, y=100, width=30, depth=10, height=5),
            LandmarkSpec(id="B", kind="tower", x=40, y=150, width=4, depth=4, height=40, yaw_deg=45),
        ],
    )
    f = raised_dem(t, lms)
    raised = f.heights > t.heights
    # A covers x 85..115, y 95..105: cell centres x 90, 100, 110 at y 100
    assert set(zip(*np.nonzero(raised))) >= {(10, 9), (10, 10), (10, 11)}
    assert f.heights[10, 10] == pytest.approx(105.0)
    assert f.heights[15, 4] == pytest.approx(140.0)  # B's centre cell
    # A: x 85..115, y 95..105 holds centres (x 90, 100, 110; y 100); B (4 m) only its own centre
    assert raised.sum() == 4
    assert not raised[10, 8] and not raised[9, 10]
