"""bench/tracking_data.py: what the offline tracker observes, with viewframes between the route points."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.tracking_data import observed, per_point


def _drive(views: int) -> dict:
    """Two frames over a route of 3 points with ``views`` viewframes a leg (errors per viewframe)."""
    from models.route_views import view_route

    route = np.array([[0.0, 0.0], [30.0, 0.0], [60.0, 0.0]])
    rp = view_route(route, views)[2]
    rng = np.random.default_rng(5)
    return {"route": route, "route_points": rp, "variances": rng.uniform(1.0, 2.0, (2, rp.size)), "skyline": None}


def test_per_point_is_the_identity_with_a_viewframe_per_point():
    d = _drive(1)
    assert np.array_equal(per_point(d, d["variances"], nats=False), d["variances"])


def test_per_point_takes_each_points_best_viewframe_or_its_total_probability():
    d = _drive(3)
    v, rp = d["variances"], d["route_points"]
    best = per_point(d, v, nats=False)
    total = per_point(d, v, nats=True)
    assert best.shape == total.shape == (2, 3)
    for k in range(3):
        mine = v[:, rp == k]
        assert best[:, k] == pytest.approx(mine.min(axis=1))
        assert total[:, k] == pytest.approx([-math.log(np.exp(-row).sum()) for row in mine])


def test_the_observation_of_a_drive_with_viewframes_between_points_is_per_route_point():
    d = _drive(3)
    assert observed(d, "associative").shape == (2, 3)
    fused = observed(d, "fused")
    assert fused.shape == (2, 3) and np.isfinite(fused).all()


def test_a_points_best_viewframe_is_never_above_its_viewframes_total_probability():
    """A route point's total probability (the tracker's rule) is at least its best viewframe's
    (the scene analysis's): in nats the total is never above the best; one a point, the same."""
    d = _drive(3)
    total, best = observed(d, "fused", point="total"), observed(d, "fused", point="best")
    assert (total <= best + 1e-12).all() and (total < best - 1e-9).any()
    one = _drive(1)
    assert np.array_equal(observed(one, "fused", point="total"), observed(one, "fused", point="best"))
    with pytest.raises(ValueError, match="point"):
        observed(d, "fused", point="mean")


def test_a_verified_frame_is_observed_re_scored_as_the_tracker_does():
    """A drive ranked with the verification on carries each frame's correlations (NaN where not
    verified): the fused observation raises each verified viewframe by the weight times its
    shortfall from the best correlation (models.verify.verified_ranking), the other frames and
    viewframes stay; ``verify=False`` is the fusion alone."""
    d = _drive(3)
    plain = observed(d, "fused", point="view")
    d["verified"] = np.full_like(d["variances"], np.nan)
    d["verified"][1, [0, 2, 4]] = [0.50, 0.40, 0.45]
    d["verify_weight"] = 20.0
    got = observed(d, "fused", point="view")
    assert np.array_equal(got[0], plain[0])  # not verified
    assert got[1, 0] == pytest.approx(plain[1, 0])  # the best correlation keeps its score
    assert got[1, 2] == pytest.approx(plain[1, 2] + 20.0 * 0.10)
    assert got[1, 4] == pytest.approx(plain[1, 4] + 20.0 * 0.05)
    others = [k for k in range(plain.shape[1]) if k not in (0, 2, 4)]
    assert got[1, others] == pytest.approx(plain[1, others])
    assert np.array_equal(observed(d, "fused", point="view", verify=False), plain)
