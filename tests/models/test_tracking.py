"""The route filter on synthetic rankings: the variances a ranking would give for a known path."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from knowledge_sources.fusion import fused_log_posterior
from models.scenario import MemorySpec, TrackingSpec
from models.tracking import MotionModel, RouteFilter, RouteGrid, ranking_scores, smooth

SPACING = 40.0
_WEIGHT = {"associative": MemorySpec().weight}


def _route(n: int = 30) -> np.ndarray:
    """An L-shaped route: east, then north, 40 m between points."""
    east = [(i * SPACING, 0.0) for i in range(n // 2)]
    north = [(east[-1][0], (j + 1) * SPACING) for j in range(n - n // 2)]
    return np.array(east + north)


def _variances(true_s: float, grid: RouteGrid, rng: np.random.Generator, *, wrong: int | None = None) -> np.ndarray:
    """Variances of a ranking for a camera at arc ``true_s``: low near it, noisy elsewhere; with
    ``wrong``, a confident wrong best at that route point (the true one still low-ish)."""
    d = np.abs(grid.arc - true_s) / SPACING
    v = 1.0 + 0.3 * rng.standard_normal(grid.points) * 0.3 - 0.8 * np.exp(-(d**2))
    if wrong is not None:
        v[wrong] = v.min() - 0.3
    return v


def _true_point(grid: RouteGrid, s: float) -> int:
    """The route point nearest the true position at arc ``s`` (the results' criterion)."""
    return int(grid.region[int(np.clip(s / grid.cell_m, 0, grid.cells - 1))])


def _loglik(f: RouteFilter, v: np.ndarray) -> np.ndarray:
    """The filter's evidence from a ranking's variances ``v``, as the tracker agent observes them: under
    the default ``scores: nats`` the fusion's negative log posterior of the memory's ranking (its robust
    z-scores at the memory's weight), under ``robust`` the variances themselves."""
    if f.spec.scores == "nats":
        labels, log_p = fused_log_posterior({"associative": (list(range(v.size)), list(v))}, weights=_WEIGHT)
        return f.route_loglik(labels, -log_p)
    return f.route_loglik(np.arange(v.size), v)


def test_grid_cells_between_route_points():
    grid = RouteGrid.build(_route(), cell_m=2.0, tail=0.5)
    assert grid.cells == pytest.approx((grid.arc[-1] + 20.0) / 2.0, abs=1)
    # a cell in the middle of the first leg lies between points 0 and 1, halfway, at y = 0
    c = int(np.argmin(np.abs(grid.centres - 20.0)))
    assert (grid.lo[c], grid.hi[c]) == (0, 1) and grid.frac[c] == pytest.approx(0.5, abs=0.05)
    assert grid.xy[c, 1] == 0.0 and grid.heading_deg[c] == 0.0
    # on the northward leg the heading is 90 degrees
    assert grid.heading_deg[-1] == pytest.approx(90.0)
    assert grid.region[c] in (0, 1)


def test_known_path_is_recovered():
    rng = np.random.default_rng(1)
    f = RouteFilter(_route(), spec=TrackingSpec())
    true_s = 5.0
    errors, points = [], []
    for _ in range(25):
        true_s += rng.uniform(10.0, 45.0)
        est = f.step(_loglik(f, _variances(true_s, f.grid, rng)))
        errors.append(abs(est.arc_m - true_s))
        points.append(est.route_point == _true_point(f.grid, true_s))
    assert np.median(errors[3:]) < 10.0
    assert np.mean(points[3:]) >= 0.9
    assert est.state == "tracking"


def test_a_confidently_wrong_frame_does_not_break_the_track():
    rng = np.random.default_rng(2)
    spec = TrackingSpec()
    f = RouteFilter(_route(), spec=spec)
    true_s, ok = 0.0, []
    for t in range(20):
        true_s += 30.0
        wrong = 25 if t == 8 else None  # a frame whose best is 10 points away
        est = f.step(_loglik(f, _variances(true_s, f.grid, rng, wrong=wrong)))
        if t >= 3:
            ok.append(abs(est.arc_m - true_s) < SPACING)
    assert all(ok)


def test_kidnapping_is_recovered():
    rng = np.random.default_rng(3)
    f = RouteFilter(_route(40), spec=TrackingSpec())
    true_s = 0.0
    for _ in range(10):
        true_s += 30.0
        f.step(_loglik(f, _variances(true_s, f.grid, rng)))
    assert abs(f.step(_loglik(f, _variances(true_s + 30, f.grid, rng))).arc_m - (true_s + 30)) < 20
    true_s = 1200.0  # the jump: 900 m further on, far beyond the motion model's reach
    recovered = None
    for t in range(10):
        true_s += 30.0
        est = f.step(_loglik(f, _variances(true_s, f.grid, rng)))
        if recovered is None and abs(est.arc_m - true_s) < SPACING / 2:
            recovered = t + 1
    assert recovered is not None and recovered <= 5


def test_a_stop_holds_the_position():
    rng = np.random.default_rng(4)
    f = RouteFilter(_route(), spec=TrackingSpec())
    true_s = 200.0
    for _ in range(6):
        est = f.step(_loglik(f, _variances(true_s, f.grid, rng)), dt=1.0)
    for _ in range(10):  # stopped: the same place, frame after frame; no drift accumulates
        est = f.step(_loglik(f, _variances(true_s, f.grid, rng)), dt=1.0)
        assert est.route_point == 5  # 200 m is route point 5
        assert abs(est.arc_m - true_s) < SPACING / 2  # the forward-only prior pulls ahead a little
        assert est.state == "tracking"


@pytest.mark.parametrize("end", ["last", "first"])
def test_a_stop_at_an_end_of_the_route_holds_the_position(end):
    """A vehicle standing at the route's last (or first) point stays there: moves that would
    leave the grid are stops, not mass piled on the end cell half a spacing past the point."""
    rng = np.random.default_rng(7)
    spec = TrackingSpec(p_reverse=0.2, reverse_m=30.0)  # reversals push mass past the first point too
    f = RouteFilter(_route(), spec=spec)
    true_s = float(f.grid.arc[-1] if end == "last" else f.grid.arc[0])
    for _ in range(15):
        est = f.step(_loglik(f, _variances(true_s, f.grid, rng)), dt=1.0)
    assert est.route_point == (f.grid.points - 1 if end == "last" else 0)
    assert abs(est.arc_m - true_s) < SPACING / 5


def test_the_route_ends_at_its_last_point():
    """Forward moves that would pass the last route point end on its cell; beyond it (the grid's
    tail) a forward move is a stop; no mass is moved onto the grid's last cell."""
    grid = RouteGrid.build(_route(8), cell_m=5.0, tail=0.5)
    motion = MotionModel.from_spec(TrackingSpec(p_kidnap=0.0, p_reverse=0.0), grid)
    n, e = grid.cells, motion.end_cell
    assert grid.centres[e] - grid.cell_m / 2 <= grid.arc[-1] <= grid.centres[e] + grid.cell_m / 2 and e < n - 2
    for cell in (e, n - 1):  # on the last point's cell, or beyond it: the belief stays
        b = np.zeros(n)
        b[cell] = 1.0
        np.testing.assert_allclose(motion.predict(b, None), b, atol=1e-12)
    b = np.zeros(n)
    b[e - 1] = 1.0
    out = motion.predict(b, None)
    k, back = motion.kernel(None)
    assert out[e - 1] == pytest.approx(k[back], rel=1e-9)  # the stop
    assert out[e] == pytest.approx(1.0 - k[back], rel=1e-9)  # every move ends on the last point
    assert out[e + 1 :].sum() == 0.0


@pytest.mark.parametrize("persistence", [0.0, None])
def test_a_frame_without_evidence_keeps_the_belief(persistence):
    rng = np.random.default_rng(5)
    spec = TrackingSpec() if persistence is None else TrackingSpec(speed_persistence=persistence)
    f = RouteFilter(_route(), spec=spec)
    true_s = 0.0
    for _ in range(6):
        true_s += 30.0
        f.step(_loglik(f, _variances(true_s, f.grid, rng)), dt=1.0)
    before = f.belief.copy()
    predicted = f.prior(1.0)
    if not f.speed_state:
        np.testing.assert_allclose(predicted, f.motion.predict(before, 1.0))
    speed = None if f.speed is None else f.speed.copy()
    est = f.step(None, dt=1.0)
    assert not est.evidence
    np.testing.assert_allclose(f.belief, predicted)  # propagated only
    if speed is not None:  # the speed state too: its prediction, no evidence for or against a class
        np.testing.assert_allclose(f.speed, f.motion.class_weights(speed, 1.0))
    # the mass moved forward, not sideways: the mean arc length advances by less than the reach
    mean_before = float(before @ f.grid.centres)
    mean_after = float(f.belief @ f.grid.centres)
    assert 0.0 < mean_after - mean_before < f.motion.reach_m(1.0)


def test_smoothing_fixes_the_warm_up_and_is_no_worse():
    rng = np.random.default_rng(6)
    spec = TrackingSpec()
    route = _route()
    f = RouteFilter(route, spec=spec)
    truth, lls = [], []
    s = 10.0
    for t in range(20):
        s += rng.uniform(20.0, 40.0)
        truth.append(s)
        wrong = 20 if t == 0 else None  # a confidently wrong first frame, far away
        lls.append(_loglik(f, _variances(s, f.grid, rng, wrong=wrong)))
    online = [f.step(ll) for ll in lls]
    smoothed = smooth(route, lls, spec=spec)
    err_on = np.array([abs(e.arc_m - s) for e, s in zip(online, truth)])
    err_sm = np.array([abs(e.arc_m - s) for e, s in zip(smoothed, truth)])
    assert err_sm[0] < SPACING / 2
    assert err_sm.mean() <= err_on.mean() + 1.0


def test_adjoint_is_the_transpose_of_predict():
    grid = RouteGrid.build(_route(8), cell_m=5.0)
    spec = TrackingSpec()
    motion = MotionModel.from_spec(spec, grid)
    n = grid.cells
    eye = np.eye(n)
    for dt in (None, 0.5):
        P = np.stack([motion.predict(eye[j], dt) for j in range(n)], axis=1)  # column j: from cell j
        g = np.random.default_rng(0).random(n)
        np.testing.assert_allclose(motion.adjoint(g, dt), P.T @ g, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("scale", [1.0, 10.0])
def test_nats_scores_are_taken_as_they_are_robust_ones_are_standardised(scale):
    """``scores: nats``: a route point 1 nat above the best has exp(-1 / temperature) of its
    likelihood, whatever the others; ``robust``: scaling every error changes nothing."""
    v = np.array([0.0, 1.0, 3.0, 5.0, 9.0]) * scale
    z, _ = ranking_scores(v, scores="nats")
    np.testing.assert_allclose(z, v)
    zr, _ = ranking_scores(v, scores="robust")
    np.testing.assert_allclose(zr, ranking_scores(v / scale, scores="robust")[0])
    route = np.c_[np.arange(5) * SPACING, np.zeros(5)]
    spec = TrackingSpec(temperature=2.0, spread=0.0, eps=0.0, outlier=0.0)  # no floor, no outlier part
    assert spec.scores == "nats"  # the default: the tracker observes the calibrated fusion
    f = RouteFilter(route, spec=spec)
    at = f.observation.loglik(v, f.grid)[np.searchsorted(f.grid.samples, f.grid.arc)]
    np.testing.assert_allclose(at - at[0], -v / 2.0, atol=1e-9)
    # with the outlier part the same ratios, up to the uniform share that bounds them below
    g = RouteFilter(route, spec=spec.model_copy(update={"outlier": 0.03}))
    mixed = g.observation.loglik(v, g.grid)[np.searchsorted(g.grid.samples, g.grid.arc)]
    assert np.all(np.diff(mixed) < 0) and np.all(mixed - mixed[0] >= -v / 2.0 - 1e-9)
    with pytest.raises(ValueError, match="scores must be one of"):
        ranking_scores(v, scores="z")


def test_low_margin_rankings_are_trusted_less():
    spec = TrackingSpec(margin_scale=2.0)
    f = RouteFilter(_route(), spec=spec)
    v = np.linspace(1.0, 2.0, f.grid.points)
    sharp = v.copy()
    sharp[10] = 0.0
    ambiguous = sharp.copy()
    ambiguous[25] = 0.01  # a far-away competitor as good as the best
    _, m_sharp = ranking_scores(sharp)
    _, m_amb = ranking_scores(ambiguous)
    assert m_amb < m_sharp
    assert f.observation.floor(m_amb) > f.observation.floor(m_sharp)


def test_cost_per_frame_for_10000_cells():
    spec = TrackingSpec()
    points = int(10_000 * spec.cell_m / SPACING) + 1
    route = np.c_[np.arange(points) * SPACING, np.zeros(points)]
    f = RouteFilter(route, spec=spec)
    assert 9_500 <= f.grid.cells <= 10_500
    rng = np.random.default_rng(7)
    lls = [f.route_loglik(np.arange(points), rng.random(points)) for _ in range(5)]
    f.step(lls[0])
    t0 = time.thread_time()  # CPU time of this thread: waiting for a core on a loaded machine not counted
    for i in range(50):
        f.step(lls[i % 5], dt=None)
    per_frame_ms = (time.thread_time() - t0) / 50 * 1e3
    # the goal is 1 ms (bench/tracking.py measures it); here a loose bound
    assert per_frame_ms < 10.0, per_frame_ms
    assert math.isfinite(f.belief.sum())


def test_the_next_window_holds_the_motions_prediction_without_the_kidnap_part():
    """On a long route, after frames of evidence near one point, the interval of the prediction
    without its kidnap part is a few route points wide, and holds where the vehicle goes next;
    with the kidnap part (spread over the route) the same interval covers nearly the whole route."""
    from models.index import WINDOW_TAIL, track_window

    n = 3000
    route = [[25.0 * i, 0.0] for i in range(n)]
    f = RouteFilter(route, spec=TrackingSpec())
    assert f.window_next(f.prior(2.0), tail=WINDOW_TAIL) is None  # no frame yet
    for t in range(6):
        est = f.step(f.grid.from_points(-0.5 * np.abs(np.arange(n) - (1000.0 + t))), dt=2.0)
    assert est.route_point == 1005
    pred = f.prior(2.0)
    first, last = f.window_next(pred, tail=WINDOW_TAIL)
    assert first <= 1005 < 1007 <= last and last - first < 60
    assert track_window(f.grid.point_mass(pred), margin=0, widest=1.0)[1] - first > n // 2


def test_the_position_along_the_grid_is_numpys_interpolation_bit_for_bit():
    """The estimate's (x, y) at arc length s: what np.interp gives along the cell centres
    (clamped at the ends), found without a pass over the whole grid."""
    from models.tracking import _position_at

    rng = np.random.default_rng(3)
    route = np.cumsum(rng.uniform(5, 40, (120, 2)) * rng.choice([-1, 1], (120, 2)), axis=0)
    grid = RouteGrid.build(route, cell_m=4.0)
    c = grid.centres
    arcs = np.concatenate([rng.uniform(c[0] - 10, c[-1] + 10, 3000), c[::7], [c[0], c[-1], c[-1] + 1.0]])
    for s in arcs:
        want = (float(np.interp(s, c, grid.xy[:, 0])), float(np.interp(s, c, grid.xy[:, 1])))
        assert _position_at(grid, float(s)) == want, s


def _slow_then_stopped(f: RouteFilter, rng: np.random.Generator, *, wrong_every: int) -> list[tuple[float, object]]:
    """A drive of 30 frames at 0.4 route spacings a frame for 10 frames, then stopped; from the stop
    on, every ``wrong_every``-th frame's ranking is confidently wrong two route points ahead (the
    same view, frame after frame: correlated errors). Returns (true arc, estimate) per frame."""
    s, out = 40.0, []
    for t in range(30):
        if t < 10:
            s += 0.4 * SPACING
        d = np.abs(f.grid.arc - s) / SPACING
        v = 1.0 + 0.09 * rng.standard_normal(f.grid.points) - 0.8 * np.exp(-(d**2))
        if t >= 10 and t % wrong_every == 0:
            v[_true_point(f.grid, s) + 2] = v.min() - 0.1
        out.append((s, f.step(_loglik(f, v), dt=1.0)))
    return out


def test_a_slow_drive_and_a_stop_with_wrong_frames_hold_the_position():
    """The speed state: a vehicle that drove slowly and then stands still, with every third
    ranking confidently two points ahead, stays where it is; the filter without a speed state
    (each step's speed drawn afresh: 90 % of the mass forward by up to two spacings every frame)
    drifts ahead onto the wrong frames' point (what this test guards against)."""
    old = TrackingSpec(speed_persistence=0.0, spread=0.45)  # the filter before the speed state
    right: dict[str, list[float]] = {"new": [], "old": []}
    for seed in range(6):
        for label, spec in (("new", TrackingSpec()), ("old", old)):
            f = RouteFilter(_route(40), spec=spec)
            frames = _slow_then_stopped(f, np.random.default_rng(seed), wrong_every=3)
            right[label].append(float(np.mean([e.route_point == _true_point(f.grid, s) for s, e in frames[13:]])))
    assert np.mean(right["new"]) >= 0.85, right
    assert all(n >= o for n, o in zip(right["new"], right["old"])), right
    assert np.mean(right["old"]) <= 0.75, right  # the old filter loses it: the test can fail


def test_the_speed_state_learns_that_the_vehicle_stands_still():
    rng = np.random.default_rng(8)
    f = RouteFilter(_route(40), spec=TrackingSpec())
    assert f.speed_state
    s = 200.0
    for _ in range(12):
        f.step(_loglik(f, _variances(s, f.grid, rng)), dt=1.0)
    a, b, pi = f.motion.speed_classes(1.0)
    stop = int(np.flatnonzero((a == 0) & (b == 0))[0])
    assert f.speed is not None and int(np.argmax(f.speed)) == stop
    assert f.speed[stop] > 2 * pi[stop]  # more than the kernel's stop probability


@pytest.mark.parametrize("dt", [None, 1.0, 4.0])
def test_speed_classes_are_the_kernel(dt):
    """Drawing a speed class with the kernel's class probabilities and a move within it is the
    kernel; the class rows mixed by those probabilities are the prediction away from the ends."""
    grid = RouteGrid.build(_route(40), cell_m=2.0)
    spec = TrackingSpec(p_kidnap=0.0)
    motion = MotionModel.from_spec(spec, grid)
    k, back = motion.kernel(dt)
    a, b, pi = motion.speed_classes(dt)
    assert a[0] == -back and b[-1] == k.size - back - 1 and np.all(a[1:] == b[:-1] + 1)  # they tile the kernel
    np.testing.assert_allclose(pi.sum(), 1.0)
    rebuilt = np.zeros_like(k)
    for lo, hi, p in zip(a, b, pi):
        rebuilt[lo + back : hi + back + 1] += p / (hi - lo + 1)
    np.testing.assert_allclose(rebuilt[1:-1], k[1:-1], atol=1e-12)  # uniform within a class
    belief = np.zeros(grid.cells)
    belief[100:140] = np.hanning(40)
    belief /= belief.sum()
    mixed = motion.mix(motion.class_rows(belief, dt), pi)
    np.testing.assert_allclose(mixed, motion.predict(belief, dt), atol=1e-12)


def test_speed_classes_end_at_the_last_point():
    """Each class row keeps the belief's mass; a class's moves that would pass the last point are
    renormalised over those that do not (none past it); nearer to it than its shortest move, the
    class ends on the last point; on it or beyond, it is a stop."""
    grid = RouteGrid.build(_route(8), cell_m=2.0, tail=0.5)
    motion = MotionModel.from_spec(TrackingSpec(p_kidnap=0.0), grid)
    n, e = grid.cells, motion.end_cell
    a, b, _ = motion.speed_classes(None)
    rng = np.random.default_rng(9)
    belief = rng.random(n)
    belief /= belief.sum()
    rows = motion.class_rows(belief, None)
    np.testing.assert_allclose(rows.sum(axis=1), 1.0, rtol=1e-12)
    for j in np.flatnonzero(a > 0):
        lo, hi = int(a[j]), int(b[j])
        one = np.zeros(n)
        one[e - (lo + hi) // 2] = 1.0  # within the class's reach of the end: renormalised, up to the end
        r = motion.class_rows(one, None)[j]
        reach = (lo + hi) // 2
        assert r[e + 1 :].sum() == 0.0 and r.sum() == pytest.approx(1.0)
        np.testing.assert_allclose(r[e - reach + lo : e + 1], 1.0 / (reach - lo + 1))
        for cell in (e, n - 1):  # on the last point, or past it: the class stands there
            one[:] = 0.0
            one[cell] = 1.0
            np.testing.assert_allclose(motion.class_rows(one, None)[j], one)
        if lo > 1:  # nearer than its shortest move: onto the last point
            one[:] = 0.0
            one[e - lo + 1] = 1.0
            np.testing.assert_allclose(motion.class_rows(one, None)[j], np.eye(n)[e])


#: the tracker's observation before session 10: the fused posterior at temperature 1, each route
#: point's viewframes lumped at the point, no outlier part (its floor eps)
_BEFORE = {"temperature": 1.0, "spread": 0.3, "outlier": 0.0, "evidence": "points"}
_PER_LEG = 3


def _view_scores(f: RouteFilter, s: float, rng: np.random.Generator, *, margin: float) -> np.ndarray:
    """A fused negative log posterior per viewframe ``(V,)`` (3 a leg) for a camera at arc ``s``:
    the views nearest it lower by about ``margin`` nats, noise of 0.5 nats on every view: a flat,
    under-confident posterior like the evaluation set's fused one."""
    arcs = f.grid.view_arcs(_PER_LEG)
    d = np.abs(arcs - s) / (SPACING / _PER_LEG)
    return 0.5 * rng.standard_normal(arcs.size) - margin * np.exp(-0.5 * d**2)


def _points_of(f: RouteFilter, scores: np.ndarray) -> tuple[list[int], list[float]]:
    from knowledge_sources.tracker import by_route_point
    from models.route_views import view_points

    return by_route_point(list(range(scores.size)), list(scores), view_points(f.grid.points, _PER_LEG), nats=True)


def test_a_flat_ranking_observed_sharper_where_its_views_stand_tracks_better_than_its_frames():
    """Session 10 (issue 9): a drive whose speed persists (0.2-1 spacings a frame, stops of 3-6
    frames; the simulated tuning drives') observed through flat, under-confident rankings of three
    viewframes a leg (the measured fused posterior's: its points of probability 0.3-0.5 are right
    about half the time). The observation before (temperature 1, each point's views lumped at it)
    lets the forward motion carry the track ahead of a slow or standing vehicle: it is right less
    often than the frames it observes. The defaults (sharper, each view's evidence where it
    stands, a uniform outlier part) are right more often than the frames, and on no seed worse
    than before."""
    rows: dict[str, list[float]] = {"single": [], "before": [], "now": []}
    for seed in range(8):
        rng = np.random.default_rng(100 + seed)
        route = _route(40)
        filters = {
            "before": RouteFilter(route, spec=TrackingSpec(**_BEFORE), views_per_leg=_PER_LEG),
            "now": RouteFilter(route, spec=TrackingSpec(), views_per_leg=_PER_LEG),
        }
        assert filters["now"].observes_views and not filters["before"].observes_views
        s, speed, stopped = 20.0, 0.6, 0
        right: dict[str, list[bool]] = {k: [] for k in rows}
        for t in range(40):
            if t and stopped:
                stopped -= 1
            elif t and rng.random() < 0.1:
                stopped = int(rng.integers(3, 7))
            elif t:
                speed = float(np.clip(speed + 0.15 * rng.standard_normal(), 0.2, 1.0))
                s = min(s + speed * SPACING, filters["now"].grid.arc[-1])
            scores = _view_scores(filters["now"], s, rng, margin=1.5)
            truth = _true_point(filters["now"].grid, s)
            labels, values = _points_of(filters["now"], scores)
            right["single"].append(labels[int(np.argmin(values))] == truth)
            est = filters["before"].step(filters["before"].route_loglik(labels, values), dt=1.0)
            right["before"].append(est.route_point == truth)
            est = filters["now"].step(filters["now"].route_loglik(list(range(scores.size)), scores), dt=1.0)
            right["now"].append(est.route_point == truth)
        for k in rows:
            rows[k].append(float(np.mean(right[k][3:])))
    single, before, now = (float(np.mean(rows[k])) for k in ("single", "before", "now"))
    assert before < single - 0.1, rows  # the mis-specified observation: what this test guards against
    assert now > single and now > before + 0.2, rows
    assert all(n >= b for n, b in zip(rows["now"], rows["before"])), rows


def test_the_evidence_of_a_view_stands_where_the_view_stands():
    """With viewframes between the route points a frame whose best view stands a third of the way
    along leg k puts the camera there, not on route point k (its route point)."""
    f = RouteFilter(_route(), spec=TrackingSpec(), views_per_leg=_PER_LEG)
    arcs = f.grid.view_arcs(_PER_LEG)
    np.testing.assert_allclose(arcs[::_PER_LEG], f.grid.arc)
    assert arcs.size == _PER_LEG * (f.grid.points - 1) + 1
    scores = np.full(arcs.size, 8.0)
    scores[3 * _PER_LEG + 1] = 0.0  # a third of the way from route point 3 to 4
    est = f.step(f.route_loglik(list(range(scores.size)), scores))
    assert est.arc_m == pytest.approx(arcs[3 * _PER_LEG + 1], abs=3.0)
    lumped = RouteFilter(_route(), spec=TrackingSpec(evidence="points"), views_per_leg=_PER_LEG)
    assert not lumped.observes_views
    labels, values = _points_of(lumped, scores)
    assert lumped.step(lumped.route_loglik(labels, values)).arc_m == pytest.approx(f.grid.arc[3], abs=3.0)


def test_the_outlier_part_bounds_what_one_frame_can_say():
    """``outlier`` w: no place is less likely than w / length under a frame, however confident
    its ranking (a frame whose ranking is wrong cannot rule out the truth)."""
    spec = TrackingSpec()
    f = RouteFilter(_route(), spec=spec)
    v = np.full(f.grid.points, 60.0)
    v[7] = 0.0
    ll = f.route_loglik(list(range(v.size)), v)
    length = f.grid.cells * f.grid.cell_m
    assert ll.min() >= math.log(spec.outlier / length) - 1e-9
    assert ll.min() == pytest.approx(math.log(spec.outlier / length), rel=1e-6)
    assert np.argmax(ll) == np.argmin(np.abs(f.grid.samples - f.grid.arc[7]))


def test_the_joint_smoothers_backward_pass_is_the_transpose_of_its_prediction():
    """Each speed class's move (:meth:`MotionModel.class_moves`) against its transpose
    (:meth:`MotionModel.class_adjoint`, the joint smoother's backward pass), cell by cell with
    the route's ends; the class transition is :meth:`MotionModel.class_weights`."""
    grid = RouteGrid.build(_route(8), cell_m=5.0)
    motion = MotionModel.from_spec(TrackingSpec(), grid)
    n = grid.cells
    rng = np.random.default_rng(3)
    for dt in (None, 2.0):
        j_count = motion.speed_classes(dt)[2].size
        msg = rng.random((j_count, n))
        for j in range(j_count):
            cols = []
            for k in range(n):
                one = np.zeros((j_count, n))
                one[j, k] = 1.0
                cols.append(motion.class_moves(one, dt)[j])
            move = np.stack(cols, axis=1)  # column k: from cell k
            np.testing.assert_allclose(move.sum(axis=0), 1.0)  # nothing lost at either end
            np.testing.assert_allclose(motion.class_adjoint(msg, dt)[j], move.T @ msg[j], rtol=1e-9, atol=1e-12)
        q = rng.random(j_count)
        q /= q.sum()
        np.testing.assert_allclose(motion.class_transition(j_count, dt) @ q, motion.class_weights(q, dt))


def _persisting_drive(f: RouteFilter, rng: np.random.Generator, frames: int) -> tuple[list, list[int], list[bool]]:
    """A drive whose speed persists (0.2-1 spacings a frame, stops of 3-6 frames) seen through flat
    rankings of three viewframes a leg: ``(logliks, true route points, stopped)`` per frame."""
    s, speed, stopped = 20.0, 0.6, 0
    lls, truth, stops = [], [], []
    for t in range(frames):
        stop = False
        if t and stopped:
            stopped, stop = stopped - 1, True
        elif t and rng.random() < 0.1:
            stopped, stop = int(rng.integers(3, 7)), True
        elif t:
            speed = float(np.clip(speed + 0.15 * rng.standard_normal(), 0.2, 1.0))
            s = min(s + speed * SPACING, f.grid.arc[-1])
        scores = _view_scores(f, s, rng, margin=1.5)
        lls.append(f.route_loglik(list(range(scores.size)), scores))
        truth.append(_true_point(f.grid, s))
        stops.append(stop)
    return lls, truth, stops


def test_a_smoothed_stop_holds_with_the_speed_state():
    """``smoother: speed`` smooths over the joint (speed class, cell) state: on drives whose speed
    persists, with stops of several frames, its stops hold (>= 0.9 of the stopped frames right)
    and it is right at least as often as the plain kernel's smoother, which itself beats the
    online filter."""
    rows: dict[str, list[float]] = {"online": [], "plain": [], "speed": []}
    stops: dict[str, list[bool]] = {k: [] for k in rows}
    for seed in range(8):
        rng = np.random.default_rng(200 + seed)
        route = _route(40)
        f = RouteFilter(route, spec=TrackingSpec(), views_per_leg=_PER_LEG)
        lls, truth, stopped = _persisting_drive(f, rng, 40)
        dts = [None] + [1.0] * (len(lls) - 1)
        points = {
            "online": [f.step(ll, dt=dt).route_point for ll, dt in zip(lls, dts)],
            "plain": [e.route_point for e in smooth(route, lls, spec=TrackingSpec(smoother="plain"), dts=dts)],
            "speed": [e.route_point for e in smooth(route, lls, spec=TrackingSpec(smoother="speed"), dts=dts)],
        }
        for k, pts in points.items():
            right = np.array(pts) == np.array(truth)
            rows[k].append(float(right[3:].mean()))
            stops[k].extend(right[np.array(stopped)].tolist())
    mean = {k: float(np.mean(v)) for k, v in rows.items()}
    assert mean["speed"] >= mean["plain"] > mean["online"], mean
    assert np.mean(stops["speed"]) >= 0.9 and np.mean(stops["speed"]) >= np.mean(stops["plain"]), stops
    # without a speed state the choice makes no difference: the plain kernel
    a = smooth(route, lls, spec=TrackingSpec(smoother="speed", speed_persistence=0.0), dts=dts)
    b = smooth(route, lls, spec=TrackingSpec(smoother="plain", speed_persistence=0.0), dts=dts)
    assert [e.arc_m for e in a] == [e.arc_m for e in b]


def _measured_moves(rng: np.random.Generator, s: float, end: float) -> tuple[float, bool]:
    """One move of the tuning drives' measured kind (bench: 66 % at 0.4-1.2 spacings, 12-16 % stops,
    12 % gaps of 2.5-5 spacings): ``(new arc, a gap)``, turned back a little at the route's end."""
    u = rng.random()
    gap = 0.12 <= u < 0.27
    if u >= 0.12:
        s += rng.uniform(2.5, 5.0) * SPACING if gap else rng.uniform(0.4, 1.2) * SPACING
    if s > end:
        s = end - rng.uniform(0.0, 0.3) * SPACING
    return s, gap


def test_the_skip_model_follows_gaps_of_several_route_points():
    """Frames that skip 2.5-5 route points (the tuning drives' measured gaps) under a flat
    ranking: the skip model measured on the tuning drives (p_skip 0.3 up to 5 spacings) follows
    them more often than the one before (0.15 up to 6), and is right more often on every seed."""
    before = TrackingSpec(p_skip=0.15, max_skip_points=6.0)
    right: dict[str, list[float]] = {"now": [], "before": []}
    at_gaps: dict[str, list[bool]] = {"now": [], "before": []}
    for seed in range(8):
        for name, spec in (("now", TrackingSpec()), ("before", before)):
            rng = np.random.default_rng(300 + seed)
            f = RouteFilter(_route(40), spec=spec, views_per_leg=_PER_LEG)
            s, r, g = 20.0, [], []
            for t in range(30):
                gap = False
                if t:
                    s, gap = _measured_moves(rng, s, f.grid.arc[-1])
                scores = _view_scores(f, s, rng, margin=1.5)
                est = f.step(f.route_loglik(list(range(scores.size)), scores), dt=1.0)
                r.append(est.route_point == _true_point(f.grid, s))
                g.append(gap)
            right[name].append(float(np.mean(r[3:])))
            at_gaps[name].extend(np.array(r)[np.array(g)].tolist())
    assert np.mean(right["now"]) > np.mean(right["before"]) + 0.03, right
    assert all(a >= b for a, b in zip(right["now"], right["before"])), right
    assert np.mean(at_gaps["now"]) > np.mean(at_gaps["before"]), at_gaps


def test_strong_frames_after_gaps_are_followed():
    """Session 11 (issue 9): on the held-out drives the single frame is strong and the track was
    right less often than its frames. Drives of the tuning drives' measured moves (12 % gaps of
    2.5-5 spacings) observed through strong rankings (the frame right about 93 % of the time):
    with the skip part before (p_skip 0.3) the track stays behind or lands short after the gaps
    and is right less often than the frames it observes; the default skip part follows the gaps,
    is right more often than before (on no seed less) and about as often as the frames."""
    before = TrackingSpec(p_skip=0.3)
    assert TrackingSpec().p_skip > before.p_skip
    right: dict[str, list[float]] = {"single": [], "now": [], "before": []}
    at_gaps: dict[str, list[bool]] = {"now": [], "before": []}
    for seed in range(16):
        for name, spec in (("now", TrackingSpec()), ("before", before)):
            rng = np.random.default_rng(600 + seed)
            f = RouteFilter(_route(40), spec=spec, views_per_leg=_PER_LEG)
            s, r, single, g = 20.0, [], [], []
            for t in range(30):
                gap = False
                if t:
                    s, gap = _measured_moves(rng, s, f.grid.arc[-1])
                scores = _view_scores(f, s, rng, margin=2.5)
                truth = _true_point(f.grid, s)
                labels, values = _points_of(f, scores)
                single.append(labels[int(np.argmin(values))] == truth)
                est = f.step(f.route_loglik(list(range(scores.size)), scores), dt=1.0)
                r.append(est.route_point == truth)
                g.append(gap)
            right[name].append(float(np.mean(r[3:])))
            at_gaps[name].extend(np.array(r)[np.array(g)].tolist())
            if name == "now":
                right["single"].append(float(np.mean(single[3:])))
    single, now, was = (float(np.mean(right[k])) for k in ("single", "now", "before"))
    assert single > 0.9, right  # strong frames, as on the held-out drives
    assert was < single - 0.025, right  # the symptom: the track below its frames
    assert now > was + 0.025 and now >= single - 0.01, right
    assert all(a >= b for a, b in zip(right["now"], right["before"])), right
    assert np.mean(at_gaps["now"]) > np.mean(at_gaps["before"]) + 0.15, at_gaps


def test_a_track_near_the_routes_end_does_not_overshoot():
    """A drive up to the route's end (the vehicle turned back a little there, as the evaluation
    set's drives are) under flat rankings: the track is never more than two route points ahead of
    the truth and two ahead on at most one frame in fifty (the heavier skip part of session 11
    follows a flat ranking's noise a gap ahead now and then: 1 frame of these 104, none with
    ``p_skip`` 0.3; on 40 more seeds 1 of 520, with the same top-1), ahead on at most a fifth of
    the frames before the last point, and holds the last point once the vehicle stands there; no
    mass is lost at the end."""
    ahead, sign = [], []
    for seed in range(8):
        rng = np.random.default_rng(400 + seed)
        f = RouteFilter(_route(20), spec=TrackingSpec(), views_per_leg=_PER_LEG)
        end = f.grid.arc[-1]
        s = end - 8 * SPACING
        at_end = []
        for t in range(16):
            if t:
                s = s + rng.uniform(0.4, 1.2) * SPACING
                if s > end:
                    s = end - rng.uniform(0.0, 0.3) * SPACING
            scores = _view_scores(f, s, rng, margin=1.5)
            prior = f.prior(1.0)
            assert prior.sum() == pytest.approx(1.0)
            est = f.step(f.route_loglik(list(range(scores.size)), scores), dt=1.0)
            truth = _true_point(f.grid, s)
            if t >= 3:
                ahead.append(est.route_point - truth)
                if truth < f.grid.points - 1:
                    sign.append(est.route_point > truth)
                else:
                    at_end.append(est.route_point == truth)
        assert np.mean(at_end[2:]) >= 0.9, at_end
    assert max(ahead) <= 2 and np.mean(np.array(ahead) >= 2) <= 0.02, ahead
    assert np.mean(sign) <= 0.2, np.mean(sign)


def test_the_prediction_asked_after_a_step_serves_the_next_step():
    """:meth:`RouteFilter.prior` after a step (the tracker's next window) and the next step with
    the same ``dt`` predict once, not twice, and give the same beliefs bit for bit as a filter
    never asked; asked for another ``dt`` it predicts afresh."""
    rng = np.random.default_rng(9)
    asked, plain = (RouteFilter(_route(), spec=TrackingSpec()) for _ in range(2))
    calls = []
    rows = asked.motion.class_rows
    object.__setattr__(asked.motion, "class_rows", lambda *a, **k: calls.append(1) or rows(*a, **k))
    s = 10.0
    for t in range(12):
        s += 30.0
        ll = _loglik(plain, _variances(s, plain.grid, rng))
        dt = 1.0 if t % 3 else 2.0
        a, b = asked.step(ll, dt=dt), plain.step(ll, dt=dt)
        assert np.array_equal(asked.belief, plain.belief) and a == b
        before = len(calls)
        pred = asked.prior(1.0)
        pred[:] = 0.0  # a caller's change does not reach the filter
        assert len(calls) == before + 1
    assert len(calls) == 12 + 3  # 12 priors, and a fresh prediction for each of the steps after 2 s (t 3, 6, 9)


def test_the_joint_smoother_takes_steps_whose_times_change_the_speed_classes():
    """Frames whose times give another number of speed classes (a long step's cruise box is the
    whole route) are smoothed too: a fresh class draw across the change, decisive frames where
    their evidence says."""
    route = np.c_[np.arange(6) * 3.0, np.zeros(6)]
    spec = TrackingSpec(smoother="speed", cell_m=1.0)
    f = RouteFilter(route, spec=spec)
    dts = [None, 0.01, 50.0, None, 1.0, 0.01]
    assert len({f.motion.speed_classes(dt)[2].size for dt in dts}) == 2
    points = [0, 1, None, 4, 5, 5]
    lls = [None if k is None else f.grid.from_points(np.log(np.where(np.arange(6) == k, 1.0, 1e-3))) for k in points]
    out = smooth(route, lls, spec=spec, dts=dts)
    assert [e.route_point for t, e in enumerate(out) if points[t] is not None] == [0, 1, 4, 5, 5]
    assert all(e.belief is not None and e.belief.sum() == pytest.approx(1.0) for e in out)


def test_a_joint_smoothing_too_large_to_keep_is_the_plain_one_and_says_so(monkeypatch, caplog):
    import logging

    import models.tracking as tracking

    route = _route(8)
    f = RouteFilter(route, spec=TrackingSpec())
    rng = np.random.default_rng(4)
    lls = [_loglik(f, _variances(20.0 + 30.0 * t, f.grid, rng)) for t in range(6)]
    monkeypatch.setattr(tracking, "SMOOTH_JOINT_MAX", 10)
    with caplog.at_level(logging.WARNING, logger="models.tracking"):
        big = smooth(route, lls, spec=TrackingSpec(smoother="speed"))
    assert "plain kernel" in caplog.text and "6 frames" in caplog.text
    assert [e.arc_m for e in big] == [e.arc_m for e in smooth(route, lls, spec=TrackingSpec(smoother="plain"))]
