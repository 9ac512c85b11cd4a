"""Tracking along the route: a grid (histogram) filter over arc length.

A vehicle drives its route, so where it was one frame ago bounds where it is now. The state is
the arc length ``s`` (metres along the route polyline from route point 0), discretised into
cells of ``cell_m`` metres; the belief is a probability per cell. Each frame:

Prediction (motion model)
    A convolution of the belief with a transition kernel over the displacement ``d`` (cells):
    forward motion of unknown speed, uniform on ``(0, D]`` (cruising: ``D`` is ``cruise_points``
    mean route spacings, or ``max_speed_mps * dt`` when the frames carry times and that is
    more) and, with
    probability ``p_skip``, uniform on ``(0, max_skip_points]`` spacings (frames dropped, route
    points skipped, whatever the times say), a stop (``d = 0``) with probability ``p_stop``, a small reversal,
    uniform on ``[-reverse_m, 0)``, with probability ``p_reverse``. The route ends at its last
    point: the forward moves from a cell are those that stay on the route, renormalised (the
    vehicle's unknown speed, given that it does not drive past the end); at the last point and
    beyond it (the grid's ``tail``, for a camera a little past it) a forward move is a stop, and
    so is a reversal that would pass the first point. (Mass piled on the grid's last cell instead
    drew a vehicle standing at the end of its route half a spacing past the last point.) Then a "kidnapped" mixture: with probability
    ``p_kidnap`` the vehicle may be anywhere (uniform), which is what lets the filter relocalize
    after a wrong start or a jump. The kernel is piecewise constant, so the convolution costs
    O(cells) by cumulative sums (the offline backward pass, the transpose, too).

    *Speed state* (``speed_persistence`` > 0, the default): a vehicle's speed persists from one
    frame to the next, which a kernel drawn afresh every step cannot know (in a stop it pushes
    90 % of the mass forward every frame, and the track drifts ahead of a vehicle standing still
    or driving slowly while weak evidence keeps the right point). The kernel is cut into speed
    classes (the reversal, the stop, :data:`CRUISE_CLASSES` equal parts of the cruise box,
    :data:`SKIP_CLASSES` of the skip box: :meth:`MotionModel.speed_classes`), so that drawing a class
    with the kernel's probabilities and a move uniformly within it is the kernel. The filter
    keeps the posterior probability of the last step's class (:attr:`RouteFilter.speed`: each
    class's prediction times the frame's evidence), and the next step keeps that class with
    probability ``speed_persistence`` (moving to a neighbouring class with probability
    ``speed_walk``), else draws it afresh from the kernel. The speed is one distribution for the
    whole belief (not one per cell: a joint grid over (speed, cell) cost 3 ms a step at 10,000
    cells against this one's ~0.1 ms more than the plain kernel, and tracked within a frame or
    two of it on the tuning drives). ``speed_persistence`` 0 is the plain kernel, exactly.
    Measured on tuning drives only (BENCHMARKS.md, "Tracking along the route", session 9): on
    drives whose speed persists (the simulated drives, stops of several frames) it holds the
    track where the plain kernel drifted ahead; on the evaluation set's generated drives, whose
    speed is drawn afresh every frame, it costs a little; 0.3 is the plateau of the pooled tuning
    drives. The offline smoother uses the plain kernel unless ``smoother: speed`` (:func:`smooth`).

Update (observation model)
    The frame's ranking gives a value ``v_k`` per route point ``k`` (lower is better): the
    knowledge source passes the ranking the single-frame decision uses, every ranking source
    (associative memory, skyline) fused by the scheduler's rule (:mod:`knowledge_sources.fusion`).
    With ``scores: nats`` (the default) ``v_k`` is the calibrated fusion's negative log posterior
    of viewframe k (:func:`knowledge_sources.fusion.fused_log_posterior`, in nats, also for the
    memory alone) and the score is ``z_k = v_k - v_best``, taken as it is: at temperature 1 the
    observation is the fusion's own likelihood. With ``scores: robust`` (raw errors of no fixed
    scale, the tracker before the calibrated fusion) the score is ``z_k = (v_k - v_best) / r``,
    ``r`` a robust spread of all of them (1.4826 times the median absolute deviation about the
    median, as :func:`knowledge_sources.scene_analysis.ranking_weights`). The likelihood of the camera being at arc length
    ``s`` is ``L(s) = eps_f + sum_k exp(gain - z_k / temperature) G(s - s_k)``: each route point's
    evidence falls off exponentially with its score and is spread along the route by a Gaussian
    ``G`` of ``spread`` mean route spacings around the point's arc length ``s_k`` (a camera
    between points i and i+1 often ranks i or i+1 best whichever is nearer: the ranking's own
    along-route error). ``eps_f = min(1, eps + margin_scale / m)`` is a floor that rises when the
    ranking's margin ``m`` is low (the best score among route points more than one point away
    from the best one): a ranking whose best competitor is as good as its best deserves little
    trust. ``L`` is evaluated at :data:`SAMPLES_PER_LEG` samples per leg and interpolated (in
    log) to the cells.

    *Calibration* (bench/tracking_calibrate.py; its numbers and seeds in BENCHMARKS.md): on the
    evaluation set's tuning split only (camera frames from another renderer than the
    viewframes', larger pose errors than the bundled scenarios'), every frame's fused ranking
    gives ``L``; normalised over the route it is the density of where the camera is according to
    that frame alone (from a uniform prior). ``eps``, ``margin_scale`` and ``spread`` maximise
    the mean log of that density at the true arc length (the true position projected on the
    route); ``gain`` is fixed (only its ratio to the floor matters). The maximum-likelihood
    ``temperature`` is over-confident for tracking (consecutive frames' errors are correlated,
    which a single-frame fit cannot see), so the defaults of
    :class:`models.scenario.TrackingSpec` are chosen on the tracked top-1 of the same split over
    a grid of temperatures and spreads around the fit (bench/tracking.py ``--set``); for the
    calibrated fusion's nats temperature 1, the fusion's likelihood as it is, lies on that
    grid's plateau. The script also prints the empirical log
    ratio of the score histograms of true and other route points, and a reliability table (the
    single-frame probability of the chosen route point against how often it is right). A margin
    term did not improve the fit once the spread was modelled, so its default is 0. Refitted
    with three viewframes a leg (``render.views_per_leg`` 3, each route point observed as its
    viewframes' total probability; session 9): the fit's spread fell from 0.33 to 0.26 route
    spacings (temperature 0.65 -> 0.44); ``spread`` 0.3 (was 0.45), on the tracked plateau
    0.25-0.35 of the tuning drives; temperature 1 kept (the fit is over-confident for tracking).

    *Session 10 (issue 9): sharper, an outlier part, each view where it stands.* On the tuning
    drives the tracker was right less often than the frames it observes (simulated drives 78.7 %
    against 80.9 %; the evaluation set's tuning drive 42.9 against 57.1 %). Frame by frame the
    misses it added were a track carried ahead of a vehicle standing or driving slowly while
    the ranking kept the right point at p 0.3-0.4, and a track lagging after gaps of 3-5
    spacings where the ranking named the new point: in both the motion prior outweighed a
    ranking it trusted too little. Measured on the tuning frames the fused posterior at
    temperature 1 is under-confident (route points of probability 0.3-0.5 are right 46-64 % of
    the time, 0.01-0.03 only 0.1-0.3 %); confidently wrong rankings are rare (a best of p >= 0.5
    more than one point from the truth: 2 of 323 frames), so a larger floor does not help (it
    only hurts). With viewframes between the route points (``evidence: views``, the filter's
    ``views_per_leg``) each viewframe's evidence stands at its own arc length
    (:meth:`RouteGrid.view_arcs`) instead of its viewframes' total at the route point, which threw
    away where along a leg the ranking puts the camera. With ``outlier`` w > 0 the likelihood is
    the mixture ``(1 - w) D(s) + w / length`` of the frame's density ``D`` (the weights
    ``exp(gain - z / temperature)`` normalised, each a normalised Gaussian of ``spread`` legs) and
    a uniform part (``eps`` unused; ``margin_scale`` raises w): its maximum-likelihood fit on the
    tuning frames is w 0.01 at temperature 0.33-0.38, over-confident for tracking again, and the
    defaults (temperature 0.67, spread 0.2, w 0.03) are on the tracked plateau of every tuning
    source (BENCHMARKS.md, "Session 10"). ``outlier: 0, evidence: points, temperature: 1,
    spread: 0.3`` is the observation before, exactly.

    Landmark answers of the scene analysis add ``log q`` / ``log (1 - q)`` per route point that
    sees / does not see a landmark reported present, and the converse for one reported absent
    (soft, unlike the scene analysis's hard discard), interpolated between route points. A frame
    without evidence only predicts.

Estimate
    The chosen route point is the one whose cells (those nearest to it in the plane, the
    results' own criterion) hold the most posterior mass; that mass is the ``confidence``. The
    continuous position is the posterior mean over that route point's cells within half a mean
    route spacing of its most probable cell (so position and route point agree); the heading is the route's direction there (degrees
    counterclockwise from +x). State ``tracking`` once the confidence reaches ``enter``, ``lost``
    again below ``exit`` (hysteresis); the filter starts ``lost``.

Smoothing
    :func:`smooth` runs the same model forward and backward over a whole drive (offline, frames
    from files): the posterior of each frame given every frame; with ``smoother: speed`` over the
    joint (speed class, cell) state (the class a step keeps or draws afresh,
    :meth:`MotionModel.class_transition`; each class's move and its transpose,
    :meth:`MotionModel.class_moves` / :meth:`MotionModel.class_adjoint`), by default with the
    plain kernel (measured: :class:`models.scenario.TrackingSpec`).

Cost
    The tracker asks :meth:`RouteFilter.prior` after each step (the next frame's window for the
    ranker); the next :meth:`RouteFilter.step` of the same ``dt`` reuses that prediction instead
    of computing it again (one prediction a frame, not two).

World coordinates are metres, ``(x, y)`` in the map plane.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from models.scenario import TrackingSpec

_log = logging.getLogger(__name__)

__all__ = [
    "RouteGrid",
    "ObservationModel",
    "MotionModel",
    "TrackEstimate",
    "RouteFilter",
    "smooth",
    "ranking_vector",
    "ranking_scores",
    "landmark_loglik",
    "SCORES",
]

#: one frame's likelihood ratio between two cells is capped at exp(this)
_LOG_RATIO_CAP = 200.0
#: beliefs never fall below this (subnormal floats are slow)
_TINY = 1e-250
#: evidence samples per route leg (see RouteGrid.samples)
SAMPLES_PER_LEG = 4
#: the along-route spread of a route point's evidence is cut at this many legs either side
_SPREAD_LEGS = 3
#: what the observed values are (:func:`ranking_scores`; the scenario's ``tracking.scores``)
SCORES = ("nats", "robust")
#: with a speed state (``speed_persistence`` > 0): the cruise box's speed classes, and the skip box's
CRUISE_CLASSES = 8
SKIP_CLASSES = 4
#: the offline smoother with a speed state keeps (frames x speed classes x cells) numbers; above
#: this many it smooths with the plain kernel (and says so)
SMOOTH_JOINT_MAX = 50_000_000


@dataclass(frozen=True)
class RouteGrid:
    """Cells of ``cell_m`` metres along the route polyline.

    Attributes
    ----------
    route : ndarray of shape (N, 2)
        Route points ``(x, y)``.
    arc : ndarray of shape (N,)
        Arc length of each route point.
    centres : ndarray of shape (C,)
        Arc length of each cell centre.
    xy : ndarray of shape (C, 2)
    heading_deg : ndarray of shape (C,)
        Direction of the route at each cell, counterclockwise from +x.
    lo, hi : ndarray of shape (C,) int
        The route points a cell lies between; ``frac`` (C,) in [0, 1] its fraction from ``lo``.
    region : ndarray of shape (C,) int
        The route point nearest each cell in the plane.
    samples : ndarray of shape (S,)
        Arc lengths where the evidence is evaluated: :data:`SAMPLES_PER_LEG` per leg, from route
        point 0 to the end of the grid (the evidence is smooth at that scale; the cells
        interpolate it).
    """

    route: np.ndarray
    cell_m: float
    arc: np.ndarray
    centres: np.ndarray
    xy: np.ndarray
    heading_deg: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    frac: np.ndarray
    region: np.ndarray
    samples: np.ndarray

    @classmethod
    def build(cls, route: Sequence[Sequence[float]] | np.ndarray, *, cell_m: float, tail: float = 0.5) -> RouteGrid:
        """The grid of ``route`` (N >= 2 points), running on past the last point by ``tail`` of the last leg."""
        pts = np.asarray(route, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise ValueError("route must have shape (N, 2) with N >= 2")
        if not cell_m > 0:
            raise ValueError("cell_m must be > 0")
        legs = np.hypot(*np.diff(pts, axis=0).T)
        if np.any(legs <= 0):
            raise ValueError("route points must be distinct")
        arc = np.concatenate([[0.0], np.cumsum(legs)])
        total = arc[-1] + tail * legs[-1]
        n = max(2, int(math.ceil(total / cell_m)))
        centres = (np.arange(n) + 0.5) * (total / n)
        seg = np.clip(np.searchsorted(arc, centres, side="right") - 1, 0, len(pts) - 2)
        frac = (centres - arc[seg]) / legs[seg]
        direction = np.diff(pts, axis=0) / legs[:, None]
        xy = pts[seg] + (centres - arc[seg])[:, None] * direction[seg]
        heading = np.degrees(np.arctan2(direction[seg, 1], direction[seg, 0]))
        beyond = frac > 1.0
        lo = np.where(beyond, len(pts) - 1, seg)
        hi = np.where(beyond, len(pts) - 1, seg + 1)
        frac = np.where(beyond, 0.0, frac)
        d2 = ((xy[:, None, :] - pts[None, :, :]) ** 2).sum(-1) if n * len(pts) <= 4_000_000 else None
        if d2 is not None:
            region = np.argmin(d2, axis=1)
        else:  # long routes: nearest among the few points around each cell's segment
            cand = np.clip(seg[:, None] + np.arange(-3, 5)[None, :], 0, len(pts) - 1)
            region = cand[np.arange(n), np.argmin(((xy[:, None, :] - pts[cand]) ** 2).sum(-1), axis=1)]
        fr = np.arange(SAMPLES_PER_LEG) / SAMPLES_PER_LEG
        samples = np.concatenate([(arc[:-1, None] + fr[None, :] * legs[:, None]).ravel(), [arc[-1]]])
        if total > arc[-1]:
            samples = np.concatenate([samples, [total]])
        return cls(pts, float(total / n), arc, centres, xy, heading, lo, hi, frac, region.astype(np.int64), samples)

    @property
    def cells(self) -> int:
        return int(self.centres.size)

    @property
    def points(self) -> int:
        return int(self.arc.size)

    @property
    def mean_leg(self) -> float:
        return float(self.arc[-1] / (self.points - 1))

    def cell_loglik(self, sample_loglik: np.ndarray) -> np.ndarray:
        """Log-likelihoods at the samples ``(S,)`` interpolated to the cells ``(C,)``."""
        return np.interp(self.centres, self.samples, sample_loglik)

    def from_points(self, point_values: np.ndarray) -> np.ndarray:
        """Per-route-point values ``(N,)`` at the samples ``(S,)``: linear in arc between points,
        the last point's beyond it."""
        return np.interp(self.samples, self.arc, np.asarray(point_values, dtype=np.float64))

    def view_arcs(self, views_per_leg: int) -> np.ndarray:
        """Arc length of each viewframe ``(V,)`` of :func:`models.route_views.view_route` with
        ``views_per_leg`` F: fractions ``0, 1/F, ..., (F-1)/F`` of each leg, then the last point."""
        f = int(views_per_leg)
        if f < 1:
            raise ValueError(f"views_per_leg must be >= 1, got {views_per_leg}")
        if f == 1:
            return self.arc.copy()
        legs = np.diff(self.arc)
        fr = np.arange(f) / f
        return np.append((self.arc[:-1, None] + fr[None, :] * legs[:, None]).ravel(), self.arc[-1])

    def point_mass(self, belief: np.ndarray) -> np.ndarray:
        """Posterior mass per route point ``(N,)``: the cells nearest to it."""
        return np.bincount(self.region, weights=belief, minlength=self.points)


def ranking_vector(viewframes: Sequence[int], variances: Sequence[float], points: int) -> np.ndarray:
    """Variances ``(points,)`` indexed by route point; NaN where the ranking has none."""
    out = np.full(points, np.nan)
    lab = np.asarray(viewframes, dtype=np.int64)
    ok = (lab >= 0) & (lab < points)
    out[lab[ok]] = np.asarray(variances, dtype=np.float64)[ok]
    return out


def ranking_scores(variances: np.ndarray, *, scores: str = "robust") -> tuple[np.ndarray, float]:
    """Scores ``z`` (NaN kept) and the margin.

    ``scores="robust"``: ``z = (v - v_best) / robust spread`` (raw errors of no fixed scale);
    ``"nats"``: ``z = v - v_best`` (the observed values are already negative log-likelihoods in
    nats, the calibrated fusion's). The margin is the best score among route points more than
    one point away from the best one (``inf`` when there are none).
    """
    if scores not in SCORES:
        raise ValueError(f"scores must be one of {SCORES}, not {scores!r}")
    v = np.asarray(variances, dtype=np.float64)
    ok = np.isfinite(v)
    if ok.sum() == 0:
        return np.full(v.shape, np.nan), math.inf
    vv = v[ok]
    spread = 1.0
    if scores == "robust":
        med = float(np.median(vv))
        spread = float(np.median(np.abs(vv - med))) * 1.4826
        if not math.isfinite(spread) or spread <= 0:
            spread = float(np.std(vv)) or 1.0
    z = (v - float(vv.min())) / spread
    best = int(np.nanargmin(z))
    far = np.abs(np.arange(v.size) - best) > 1
    rest = z[far & ok]
    return z, (float(rest.min()) if rest.size else math.inf)


@dataclass(frozen=True)
class ObservationModel:
    """The ranking likelihood of the module docstring; parameters from :class:`TrackingSpec`."""

    temperature: float
    gain: float
    eps: float
    margin_scale: float = 0.0
    spread: float = 0.0
    scores: str = "robust"
    #: the uniform part of the likelihood (0: the floor ``eps_f`` instead; see the module docstring)
    outlier: float = 0.0
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def from_spec(cls, spec: TrackingSpec) -> ObservationModel:
        return cls(spec.temperature, spec.gain, spec.eps, spec.margin_scale, spec.spread, spec.scores, spec.outlier)

    def floor(self, margin: float) -> float:
        """The likelihood floor ``eps_f`` for a ranking of margin ``margin``."""
        if self.margin_scale <= 0 or not math.isfinite(margin):
            return self.eps
        return min(1.0, self.eps + self.margin_scale / max(margin, 1e-3))

    def peaks(self, variances: np.ndarray) -> tuple[np.ndarray, float]:
        """``exp(gain - z_k / temperature)`` per route point ``(N,)`` (0 where no score) and the floor."""
        z, margin = ranking_scores(variances, scores=self.scores)
        return np.exp(self.gain - np.nan_to_num(z, nan=np.inf) / self.temperature), self.floor(margin)

    def _spread_matrix(self, grid: RouteGrid, at: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(index (S, W), weight (S, W))``: the evidence places near each sample (the route
        points, or the arc lengths ``at`` (P,), non-decreasing: the viewframes') and their Gaussian
        weights ``exp(-d**2 / (2 (spread * leg)**2))`` (d: arc distance), within
        :data:`_SPREAD_LEGS` legs either side."""
        arcs = grid.arc if at is None else at
        key = (id(grid), None if at is None else id(at))
        got = self._cache.get(key)
        if got is not None and got[0] is grid and got[1] is arcs:
            return got[2], got[3]
        per_leg = max(1, int(math.ceil((arcs.size - 1) / max(grid.points - 1, 1))))
        seg = np.clip(np.searchsorted(arcs, grid.samples, side="right") - 1, 0, arcs.size - 1)
        offsets = np.arange(-_SPREAD_LEGS * per_leg, _SPREAD_LEGS * per_leg + 2)
        index = np.clip(seg[:, None] + offsets[None, :], 0, arcs.size - 1)
        d = grid.samples[:, None] - arcs[index]
        sigma = max(self.spread, 1e-6) * grid.mean_leg
        weight = np.exp(-0.5 * (d / sigma) ** 2)
        # a place clipped at either end appears several times: count it once
        dup = np.zeros_like(index, dtype=bool)
        dup[:, 1:] = index[:, 1:] == index[:, :-1]
        weight[dup] = 0.0
        self._cache[key] = (grid, arcs, index, weight)
        return index, weight

    def loglik(self, variances: np.ndarray, grid: RouteGrid, *, at: np.ndarray | None = None) -> np.ndarray:
        """Log-likelihood at the grid's samples ``(S,)`` from variances per route point ``(N,)``,
        or per evidence place ``(P,)`` at the arc lengths ``at`` (the viewframes')."""
        peaks, eps = self.peaks(variances)
        arcs = grid.arc if at is None else at
        if self.outlier > 0:
            return self._mixture(peaks, eps - self.eps, grid, arcs, at)
        if self.spread <= 0:
            return np.log(eps + np.interp(grid.samples, arcs, peaks))
        index, weight = self._spread_matrix(grid, at)
        return np.log(eps + (peaks[index] * weight).sum(axis=1))

    def _mixture(
        self, peaks: np.ndarray, margin_floor: float, grid: RouteGrid, arcs: np.ndarray, at: np.ndarray | None
    ) -> np.ndarray:
        """``log((1 - w) D + w / length)`` at the samples: ``D`` the frame's density over arc length
        (the peaks normalised, each a Gaussian of ``spread`` legs, or without a spread spread
        linearly over its share of the route), ``w`` the outlier weight (raised by the margin term)."""
        total = float(peaks.sum())
        if not total > 0:
            return np.zeros(grid.samples.size)
        q = peaks / total
        if self.spread > 0:
            index, weight = self._spread_matrix(grid, at)
            sigma = max(self.spread, 1e-6) * grid.mean_leg
            density = (q[index] * weight).sum(axis=1) * (1.0 / (sigma * math.sqrt(2.0 * math.pi)))
        else:
            density = np.interp(grid.samples, arcs, q) * ((arcs.size - 1) / max(float(arcs[-1] - arcs[0]), 1e-9))
        w = min(1.0, self.outlier + max(margin_floor, 0.0))
        return np.log((1.0 - w) * density + w / float(grid.cells * grid.cell_m))


def landmark_loglik(
    answers: Sequence[tuple[str, bool]],
    visible: Mapping[int, frozenset[str] | set[str]],
    points: int,
    *,
    reliability: float,
) -> np.ndarray:
    """Log-likelihood per route point ``(points,)`` of landmark answers ``(landmark, present)``.

    A landmark reported present: ``log q`` where it is visible, ``log (1 - q)`` elsewhere; absent:
    the converse (``q`` = ``reliability``). Unanswered questions are not passed in.
    """
    ll = np.zeros(points)
    if not answers:
        return ll
    lq, lnq = math.log(reliability), math.log(1.0 - reliability)
    for landmark, present in answers:
        sees = np.array([landmark in visible.get(k, ()) for k in range(points)])
        hit, miss = (lq, lnq) if present else (lnq, lq)
        ll += np.where(sees, hit, miss)
    return ll


@dataclass(frozen=True)
class MotionModel:
    """The transition kernel of the module docstring, per time step."""

    cell_m: float
    mean_leg: float
    max_speed_mps: float
    cruise_points: float
    max_skip_points: float
    p_skip: float
    p_stop: float
    p_reverse: float
    reverse_m: float
    p_kidnap: float
    #: the cell of the route's last point: forward moves that would pass it end there
    end_cell: int
    #: probability that a step keeps the previous step's speed class (then moves to a neighbouring
    #: class with probability ``speed_walk``); else the class is drawn afresh from the kernel
    persistence: float = 0.0
    speed_walk: float = 0.25
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def from_spec(cls, spec: TrackingSpec, grid: RouteGrid) -> MotionModel:
        return cls(
            grid.cell_m,
            grid.mean_leg,
            spec.max_speed_mps,
            spec.cruise_points,
            spec.max_skip_points,
            spec.p_skip,
            spec.p_stop,
            spec.p_reverse,
            spec.reverse_m,
            spec.p_kidnap,
            min(grid.cells - 1, int(grid.arc[-1] / grid.cell_m)),
            spec.speed_persistence,
            spec.speed_walk,
        )

    def cruise_m(self, dt: float | None) -> float:
        """The largest forward displacement of a normal step: ``cruise_points`` mean route
        spacings, or ``max_speed_mps * dt`` when the frames carry times and that is more (a
        speed bound never narrows the step below the route's own scale: the set of frames a
        vehicle's camera delivers is not known to follow its clock)."""
        base = max(self.cruise_points * self.mean_leg, self.cell_m)
        if dt is None:
            return base
        return max(self.max_speed_mps * max(float(dt), 0.0), base)

    def reach_m(self, dt: float | None) -> float:
        """The largest forward displacement in one step (a skip: frames dropped, whatever their times)."""
        return max(self.max_skip_points * self.mean_leg, self.cruise_m(dt))

    def kernel(self, dt: float | None) -> tuple[np.ndarray, int]:
        """``(K, back)``: probabilities of displacements ``-back .. len(K) - back - 1`` cells (sums to 1)."""
        key = None if dt is None else round(float(dt), 3)
        got = self._cache.get(key)
        if got is not None:
            return got[0], got[1]
        cruise = max(1, int(round(self.cruise_m(dt) / self.cell_m)))
        fwd = max(cruise, int(round(self.reach_m(dt) / self.cell_m)))
        back = int(round(self.reverse_m / self.cell_m)) if self.p_reverse > 0 else 0
        k = np.zeros(back + 1 + fwd)
        k[back] = self.p_stop
        move = 1.0 - self.p_stop - (self.p_reverse if back else 0.0)
        skip = self.p_skip if fwd > cruise else 0.0
        k[back + 1 : back + 1 + cruise] += move * (1.0 - skip) / cruise
        k[back + 1 :] += move * skip / fwd
        if back:
            k[:back] = self.p_reverse / back
        k /= k.sum()
        self._cache[key] = (k, back, cruise)
        return k, back

    def _boxes(self, dt: float | None) -> tuple[float, list[tuple[int, float]], int, float]:
        """The kernel as boxes: ``(stop, [(width, weight per cell) of the forward boxes], back,
        weight per cell of the reverse box)``."""
        k, back = self.kernel(dt)
        cruise = self._cache[None if dt is None else round(float(dt), 3)][2]
        fwd = k.size - back - 1
        a_skip = k[-1] if fwd > cruise else 0.0
        boxes = [(w, float(a)) for w, a in ((fwd, a_skip), (cruise, k[back + 1] - a_skip)) if a > 0]
        return float(k[back]), boxes, back, float(k[0]) if back else 0.0

    def _ahead(self, n: int, width: int) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        """``(e, reach, scale, lo)`` of a forward box of ``width`` cells on ``n`` cells (cached):
        ``e`` the cell of the route's last point; from cell j the box's moves reach ``reach[j]``
        cells ahead, up to it, each of them ``scale[j] = width / reach[j]`` times as likely as on
        open route (0 from ``e`` on: there the box's moves are a stop); ``lo[i] = max(i - width,
        0)`` for the cells up to ``e``."""
        key = ("ahead", n, width)
        got = self._cache.get(key)
        if got is None:
            e = min(self.end_cell, n - 1)
            reach = np.clip(e - np.arange(n), 0, width)
            scale = np.divide(float(width), reach, out=np.zeros(n), where=reach > 0)
            got = (e, reach, scale, np.maximum(np.arange(e + 1) - width, 0))
            self._cache[key] = got
        return got

    def _behind(self, n: int, back: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(hi, lo, stay)`` of the reverse box of ``back`` cells on ``n`` cells (cached): cell i
        receives from cells i + 1 .. ``hi[i] - 1`` and sends to ``lo[i]`` .. i - 1; ``stay[i]``
        of its moves would pass the first point (a stop)."""
        key = ("behind", n, back)
        got = self._cache.get(key)
        if got is None:
            idx = np.arange(n)
            got = (np.minimum(idx + back + 1, n), np.maximum(idx - back, 0), np.maximum(back - idx, 0).astype(float))
            self._cache[key] = got
        return got

    def predict(self, belief: np.ndarray, dt: float | None) -> np.ndarray:
        """One prediction step of ``belief`` ``(C,)`` (sums to 1).

        The kernel is piecewise constant (stop, two forward boxes: cruise and skip, a reverse
        box), so the convolution is computed exactly from cumulative sums in O(cells), whatever
        the kernel's length. The route ends at its last point: a forward box's moves from a cell
        are the ones that stay on the route, renormalised (the vehicle's speed, given that it
        does not drive past the end); at the last point and beyond (the grid's tail) they are a
        stop, and a reversal past the first point is a stop. :meth:`adjoint` computes the
        transpose the same way, and the tests check one against the other.
        """
        stop, boxes, back, a_back = self._boxes(dt)
        n = belief.size
        out = stop * belief
        c = np.zeros(n + 1)
        for width, weight in boxes:
            e, _, scale, lo = self._ahead(n, width)
            # a cell up to the last point's receives from cells i - width .. i - 1 (their moves all
            # reach it); the cells beyond it from none
            np.cumsum(belief * scale, out=c[1:])
            out[: e + 1] += weight * (c[: e + 1] - c[lo])
            out[e:] += weight * width * belief[e:]  # at the last point and beyond, a forward move is a stop
        if back:
            hi, _, stay = self._behind(n, back)
            np.cumsum(belief, out=c[1:])
            out += a_back * (c[hi] - c[1:])  # from cells i + 1 .. i + back
            out += a_back * stay * belief  # a reversal past the first point is a stop
        out *= (1.0 - self.p_kidnap) / max(out.sum(), 1e-300)
        out += self.p_kidnap / n
        return out

    def adjoint(self, message: np.ndarray, dt: float | None) -> np.ndarray:
        """The transpose of :meth:`predict` applied to a backward message ``(C,)`` (not normalised)."""
        stop, boxes, back, a_back = self._boxes(dt)
        n = message.size
        idx = np.arange(n)
        m = np.zeros(n + 1)
        np.cumsum(message, out=m[1:])
        out = stop * message
        for width, weight in boxes:
            e, reach, scale, _ = self._ahead(n, width)
            out += weight * scale * (m[idx + reach + 1] - m[idx + 1])  # cells j + 1 .. j + reach
            out[e:] += weight * width * message[e:]
        if back:
            _, lo, stay = self._behind(n, back)
            out += a_back * (m[:n] - m[lo])  # cells j - back .. j - 1
            out += a_back * stay * message
        return (1.0 - self.p_kidnap) * out + self.p_kidnap * message.mean()

    def speed_classes(self, dt: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(a, b, pi)`` of the speed classes of a step (cached): class j moves uniformly by
        ``a[j] .. b[j]`` cells (inclusive) and ``pi[j]`` is the kernel's probability of those
        displacements, so drawing a class from ``pi`` and a move within it is :meth:`kernel`.
        Classes, slowest first: the reversal, the stop, the cruise box in :data:`CRUISE_CLASSES`
        equal parts and the skip box beyond it in :data:`SKIP_CLASSES` (a class is a fraction of
        the step's largest move, so with times it scales with ``dt``)."""
        key = ("classes", None if dt is None else round(float(dt), 3))
        got = self._cache.get(key)
        if got is not None:
            return got
        k, back = self.kernel(dt)
        cruise = self._cache[None if dt is None else round(float(dt), 3)][2]
        fwd = k.size - back - 1
        edges = np.unique(np.round(np.linspace(0, cruise, CRUISE_CLASSES + 1)).astype(int))
        if fwd > cruise:
            edges = np.unique(np.r_[edges, np.round(np.linspace(cruise, fwd, SKIP_CLASSES + 1)).astype(int)])
        a = [-back, 0] if back else [0]
        b = [-1, 0] if back else [0]
        a += [int(x) + 1 for x in edges[:-1]]
        b += [int(x) for x in edges[1:]]
        aa, bb = np.asarray(a), np.asarray(b)
        c = np.r_[0.0, np.cumsum(k)]
        pi = c[bb + back + 1] - c[aa + back]
        got = (aa, bb, pi / pi.sum())
        self._cache[key] = got
        return got

    def class_rows(self, belief: np.ndarray, dt: float | None) -> np.ndarray:
        """``(J, C)``: ``belief`` ``(C,)`` moved by each speed class of :meth:`speed_classes` alone
        (each row sums to the belief's mass; cumulative sums, O(J C)). The route ends at its last
        point, as in :meth:`predict`: a class's forward moves from a cell are those that stay on
        the route, renormalised; from a cell nearer to the last point than the class's shortest
        move it ends on the last point, and on the last point or beyond it (the grid's tail) it
        is a stop; reversals that would pass the first point stop there."""
        a, b, _ = self.speed_classes(dt)
        n = belief.size
        c = np.zeros(n + 1)
        np.cumsum(belief, out=c[1:])
        rows = np.empty((a.size, n))
        for j, (lo, hi) in enumerate(zip(a.tolist(), b.tolist())):
            self._class_move(belief, c, lo, hi, rows[j])
        return rows

    def class_moves(self, beliefs: np.ndarray, dt: float | None) -> np.ndarray:
        """``(J, C)``: row j of ``beliefs`` ``(J, C)`` moved by speed class j alone (each its own
        belief, unlike :meth:`class_rows`: the joint (class, cell) prediction of :func:`smooth`)."""
        a, b, _ = self.speed_classes(dt)
        if beliefs.shape[0] != a.size:
            raise ValueError(f"{beliefs.shape[0]} rows for {a.size} speed classes")
        n = beliefs.shape[1]
        c = np.zeros(n + 1)
        rows = np.empty_like(beliefs, dtype=np.float64)
        for j, (lo, hi) in enumerate(zip(a.tolist(), b.tolist())):
            np.cumsum(beliefs[j], out=c[1:])
            self._class_move(beliefs[j], c, lo, hi, rows[j])
        return rows

    def _class_move(self, belief: np.ndarray, c: np.ndarray, lo: int, hi: int, o: np.ndarray) -> None:
        """``o`` ``(C,)`` := ``belief`` moved uniformly by ``lo .. hi`` cells (``c`` its cumulative
        sums, ``(C + 1,)`` from 0), with the route's ends of :meth:`class_rows`."""
        n = belief.size
        e = min(self.end_cell, n - 1)
        lo, hi = min(lo, n - 1), min(hi, n - 1)
        if lo == 0 and hi == 0:
            o[:] = belief
        elif lo > 0:  # forward: o[i] = sum of belief[i - hi .. i - lo] / width
            o[:lo] = 0.0
            o[lo:] = c[1 : n - lo + 1]
            o[hi:] -= c[: n - hi]
            w = hi - lo + 1
            o *= 1.0 / w
            o[e + 1 :] = 0.0
            # the cells nearer the end than the class's longest move: their moves renormalised
            k0, k1 = max(0, e - hi + 1), e - lo
            if k1 >= k0:
                count = (e - lo + 1) - np.arange(k0, k1 + 1)
                o[k0 + lo : e + 1] += np.cumsum((1.0 / count - 1.0 / w) * belief[k0 : k1 + 1])
            s0 = max(0, e - lo + 1)
            o[e] += float(belief[s0:e].sum())  # nearer than its shortest move: to the last point
            o[e:] += belief[e:]  # on the last point or past it: a stop
        else:  # a reversal: o[i] = sum of belief[i + 1 .. i + back] / back
            back = -lo
            o[: n - back] = c[back + 1 :]
            o[n - back :] = c[n]
            o -= c[1:]
            o *= 1.0 / back
            o[0] += float(c[n]) - float(o.sum())

    def class_adjoint(self, messages: np.ndarray, dt: float | None) -> np.ndarray:
        """The transpose of :meth:`class_moves` applied to backward messages ``(J, C)`` (row j
        through class j's move; not normalised)."""
        a, b, _ = self.speed_classes(dt)
        if messages.shape[0] != a.size:
            raise ValueError(f"{messages.shape[0]} rows for {a.size} speed classes")
        n = messages.shape[1]
        e = min(self.end_cell, n - 1)
        m = np.zeros(n + 1)
        out = np.empty_like(messages, dtype=np.float64)
        for j, (lo, hi) in enumerate(zip(a.tolist(), b.tolist())):
            msg, o = messages[j], out[j]
            lo, hi = min(lo, n - 1), min(hi, n - 1)
            np.cumsum(msg, out=m[1:])
            if lo == 0 and hi == 0:
                o[:] = msg
            elif lo > 0:  # cell k sends to k + lo .. min(k + hi, e), evenly; nearer the end: to e; from e on: stays
                o[:] = msg
                k = np.arange(max(0, e - lo + 1))
                top = np.minimum(k + hi, e)
                o[: k.size] = (m[top + 1] - m[k + lo]) / (top - k - lo + 1)
                o[k.size : e] = msg[e]
            else:  # cell k sends to k - back .. k - 1, those before the first cell to cell 0
                back = -lo
                k = np.arange(n)
                o[:] = (m[k] - m[np.maximum(k - back, 0)] + np.maximum(back - k, 0) * msg[0]) / back
        return out

    def class_transition(self, previous: int, dt: float | None) -> np.ndarray:
        """``(J, J')``: the next step's class probabilities given the last step's class, as
        :meth:`class_weights` (``M @ q`` is ``class_weights(q, dt)`` for a distribution ``q``
        over the ``previous`` (J') classes; drawn afresh when the classes differ)."""
        pi = self.speed_classes(dt)[2]
        if previous != pi.size:
            return np.repeat(pi[:, None], previous, axis=1)
        return np.stack([self.class_weights(np.eye(pi.size)[j], dt) for j in range(pi.size)], axis=1)

    def class_weights(self, q: np.ndarray | None, dt: float | None) -> np.ndarray:
        """The next step's speed-class probabilities ``(J,)`` given this step's posterior ``q``
        (None: the kernel's): kept with probability ``persistence`` (moving to a neighbouring
        class with probability ``speed_walk``), else drawn afresh from the kernel's."""
        pi = self.speed_classes(dt)[2]
        if q is None or q.size != pi.size:
            return pi.copy()
        walk = self.speed_walk
        k = (1.0 - walk) * q
        k[1:] += 0.5 * walk * q[:-1]
        k[:-1] += 0.5 * walk * q[1:]
        k[0] += 0.5 * walk * q[0]
        k[-1] += 0.5 * walk * q[-1]
        return self.persistence * k + (1.0 - self.persistence) * pi

    def mix(self, rows: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """The prediction ``(C,)`` of class rows ``(J, C)`` mixed by ``weights`` ``(J,)``, with the kidnap mixture."""
        out = weights @ rows
        out *= (1.0 - self.p_kidnap) / max(float(out.sum()), 1e-300)
        out += self.p_kidnap / out.size
        return out


@dataclass(frozen=True)
class TrackEstimate:
    """The track at one frame.

    ``route_point`` (most probable route point), ``arc_m`` (continuous arc length), ``x``, ``y``
    (metres), ``heading_deg``, ``confidence`` (posterior mass on ``route_point``), ``state``
    (``"tracking"`` or ``"lost"``), ``evidence`` (whether the frame had any), ``belief`` (the
    posterior mass of every route point, ``(N,)``; not in :meth:`to_dict`).
    """

    route_point: int
    arc_m: float
    x: float
    y: float
    heading_deg: float
    confidence: float
    state: str
    evidence: bool = True
    belief: np.ndarray | None = field(default=None, compare=False, repr=False)

    def to_dict(self) -> dict:
        return {
            "route_point": self.route_point,
            "arc_m": self.arc_m,
            "position": [self.x, self.y],
            "heading_deg": self.heading_deg,
            "confidence": self.confidence,
            "state": self.state,
            "evidence": self.evidence,
        }


def _estimate(grid: RouteGrid, belief: np.ndarray, state: str, evidence: bool) -> TrackEstimate:
    mass = grid.point_mass(belief)
    k = int(np.argmax(mass))
    # the most probable cell among those nearest to the chosen route point: the position and the
    # route point agree (the point with the most mass need not hold the single most probable cell)
    c = int(np.argmax(np.where(grid.region == k, belief, -1.0)))
    half = max(1, int(round(0.5 * grid.mean_leg / grid.cell_m)))
    lo, hi = max(0, c - half), min(grid.cells, c + half + 1)
    w = belief[lo:hi] * (grid.region[lo:hi] == k)
    s = float((w * grid.centres[lo:hi]).sum() / max(w.sum(), 1e-300))
    j = int(np.clip(round(s / grid.cell_m - 0.5), 0, grid.cells - 1))
    x, y = _position_at(grid, s)
    return TrackEstimate(k, s, x, y, float(grid.heading_deg[j]), float(mass[k]), state, evidence, mass)


def _position_at(grid: RouteGrid, s: float) -> tuple[float, float]:
    """(x, y) at arc length ``s`` along the grid's own polyline of cell centres: ``np.interp``'s
    value (clamped at the ends, the same formula), without its pass over the whole grid."""
    c, xy = grid.centres, grid.xy
    if not s > c[0]:
        return float(xy[0, 0]), float(xy[0, 1])
    if not s < c[-1]:
        return float(xy[-1, 0]), float(xy[-1, 1])
    j = int(np.searchsorted(c, s, side="right")) - 1
    dx = float(c[j + 1] - c[j])
    a, b = xy[j], xy[j + 1]
    return (
        float((b[0] - a[0]) / dx * (s - c[j]) + a[0]),
        float((b[1] - a[1]) / dx * (s - c[j]) + a[1]),
    )


class RouteFilter:
    """The online filter: :meth:`step` once per frame, in frame order.

    Example::

        >>> f = RouteFilter([[0, 0], [40, 0], [80, 0]], spec=TrackingSpec())
        >>> est = f.step(f.grid.from_points(np.log([1.0, 0.01, 0.01])))   # evidence for route point 0
        >>> est.route_point
        0
    """

    def __init__(
        self, route: Sequence[Sequence[float]] | np.ndarray, *, spec: TrackingSpec, views_per_leg: int = 1
    ) -> None:
        self.spec = spec
        self.grid = RouteGrid.build(route, cell_m=spec.cell_m, tail=spec.tail)
        self.motion = MotionModel.from_spec(spec, self.grid)
        self.observation = ObservationModel.from_spec(spec)
        #: the arc length of each viewframe the rankings name, when they are observed where they
        #: stand (``evidence: views`` with viewframes between the route points); else None: the
        #: rankings name route points
        self.view_arcs: np.ndarray | None = (
            self.grid.view_arcs(views_per_leg) if views_per_leg > 1 and spec.evidence == "views" else None
        )
        self.reset()

    @property
    def observes_views(self) -> bool:
        """Whether :meth:`route_loglik` takes rankings of viewframes (labels ``0 .. V - 1``, each
        observed at its own arc length) rather than of route points."""
        return self.view_arcs is not None

    def reset(self) -> None:
        """Back to a blind start: uniform belief, ``lost``, no frame yet."""
        self.belief = np.full(self.grid.cells, 1.0 / self.grid.cells)
        #: with a speed state: the posterior probability of each speed class of the last step ``(J,)``
        #: (None before the first step)
        self.speed: np.ndarray | None = None
        self.state = "lost"
        self.frames = 0
        self._predicted: tuple | None = None

    @property
    def speed_state(self) -> bool:
        """Whether the filter keeps a speed state (``speed_persistence`` > 0)."""
        return self.motion.persistence > 0

    def _predict(self, dt: float | None) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
        """``(rows (J, C), weights (J,), prediction (C,))`` of the next frame (rows and weights None
        without a speed state), kept for the same belief and ``dt``: the tracker asks
        :meth:`prior` after each step (the next frame's window) and :meth:`step` predicts the
        same again when the next frame comes ``dt`` later."""
        key = (self.frames, None if dt is None else float(dt))
        got = self._predicted
        if got is not None and got[0] == key and got[1] is self.belief:
            return got[2]
        if self.speed_state:
            rows = self.motion.class_rows(self.belief, dt)
            weights = self.motion.class_weights(self.speed, dt)
            out: tuple[np.ndarray | None, np.ndarray | None, np.ndarray] = (
                rows,
                weights,
                self.motion.mix(rows, weights),
            )
        else:
            out = (None, None, self.motion.predict(self.belief, dt))
        self._predicted = (key, self.belief, out)
        return out

    def route_loglik(
        self,
        viewframes: Sequence[int] | None = None,
        variances: Sequence[float] | None = None,
        *,
        answers: Sequence[tuple[str, bool]] = (),
        visible: Mapping[int, frozenset[str] | set[str]] | None = None,
    ) -> np.ndarray | None:
        """Log-likelihood of one frame's evidence at the grid's samples ``(S,)``, or None when it has
        none. ``viewframes`` are route points, or with :attr:`observes_views` viewframes."""
        ll = None
        if viewframes is not None and variances is not None and len(viewframes):
            at = self.view_arcs
            n = self.grid.points if at is None else at.size
            ll = self.observation.loglik(ranking_vector(viewframes, variances, n), self.grid, at=at)
        if answers and visible is not None:
            la = self.grid.from_points(
                landmark_loglik(answers, visible, self.grid.points, reliability=self.spec.reliability)
            )
            ll = la if ll is None else ll + la
        return ll

    def prior(self, dt: float | None = None) -> np.ndarray:
        """The predicted belief ``(C,)`` of the next frame, before its evidence."""
        if self.frames == 0:
            return self.belief.copy()
        return self._predict(dt)[2].copy()

    def window_next(self, prediction: np.ndarray, *, tail: float) -> tuple[int, int] | None:
        """The route points ``(first, last)`` holding all but ``tail`` of ``prediction`` (``(C,)``, from
        :meth:`prior`) without its kidnap part, the ``p_kidnap`` spread evenly over the cells (that
        even part would widen any such interval to nearly the whole route); ``tail / 2`` is left
        out at each end. None: no mass outside the kidnap part (before the first frame)."""
        if self.frames == 0:
            return None
        moved = np.maximum(prediction - self.motion.p_kidnap / prediction.size, 0.0)
        p = self.grid.point_mass(moved)
        total = float(p.sum())
        if not total > 0:
            return None
        cdf = np.cumsum(p) / total
        first = int(np.searchsorted(cdf, tail / 2, side="right"))
        last = int(np.searchsorted(cdf, 1.0 - tail / 2, side="left"))
        return min(first, len(p) - 1), min(max(first, last), len(p) - 1)

    def step(self, route_loglik: np.ndarray | None, *, dt: float | None = None) -> TrackEstimate:
        """Predict (``dt`` seconds since the previous frame, or None: no time) and update."""
        if self.frames == 0:
            self.belief = _update(self.grid, self.belief, route_loglik)
        else:
            mass = float(self.belief.sum())  # every class row's
            rows, weights, pred = self._predict(dt)
            like = None if route_loglik is None else _cell_likelihood(self.grid, route_loglik)
            self.belief = _posterior(pred, like)
            if rows is not None and weights is not None:
                self.speed = _speed_posterior(rows, weights, like, self.motion.p_kidnap, mass=mass)
        self._predicted = None
        self.frames += 1
        est = _estimate(self.grid, self.belief, self.state, route_loglik is not None)
        self.state = _next_state(self.state, est.confidence, self.spec)
        return dataclasses.replace(est, state=self.state)


def _cell_likelihood(grid: RouteGrid, route_loglik: np.ndarray) -> np.ndarray:
    """A frame's likelihood at the cells ``(C,)``, relative to its largest (capped below)."""
    ll = grid.cell_loglik(route_loglik)
    return np.exp(np.maximum(ll - ll.max(), -_LOG_RATIO_CAP))


def _posterior(pred: np.ndarray, like: np.ndarray | None) -> np.ndarray:
    if like is None:
        return pred
    post = pred * like
    np.maximum(post, _TINY, out=post)  # no subnormal numbers: they make numpy 50x slower
    total = post.sum()
    return post / total if total > 0 else pred


def _update(grid: RouteGrid, pred: np.ndarray, route_loglik: np.ndarray | None) -> np.ndarray:
    return _posterior(pred, None if route_loglik is None else _cell_likelihood(grid, route_loglik))


def _speed_posterior(
    rows: np.ndarray, weights: np.ndarray, like: np.ndarray | None, p_kidnap: float, *, mass: float
) -> np.ndarray:
    """The posterior probability of each speed class of the step ``(J,)``: its prior ``weights``
    times the evidence's likelihood ``like`` ``(C,)`` under its prediction ``rows[j]`` (each row
    of mass ``mass``; the kidnap part alike for all)."""
    if like is None:
        return weights / weights.sum()
    ev = (1.0 - p_kidnap) * (rows @ like) / max(mass, 1e-300) + p_kidnap * float(like.mean())
    post = weights * ev
    total = float(post.sum())
    return post / total if total > 0 else weights / weights.sum()


def _next_state(state: str, confidence: float, spec: TrackingSpec) -> str:
    if state == "lost":
        return "tracking" if confidence >= spec.enter else "lost"
    return "lost" if confidence < spec.exit else "tracking"


def smooth(
    route: Sequence[Sequence[float]],
    logliks: Sequence[np.ndarray | None],
    *,
    spec: TrackingSpec,
    dts: Sequence[float | None] | None = None,
) -> list[TrackEstimate]:
    """Forward-backward smoothing of a whole drive: one estimate per frame given every frame.

    ``logliks[t]`` is frame t's log-likelihood at the grid's samples (None: no evidence), ``dts[t]``
    the time since frame t - 1 (ignored for t = 0; None: no time). The state (tracking/lost)
    follows the same hysteresis over the smoothed confidences. With ``smoother: speed`` and a
    speed state (``speed_persistence`` > 0) it runs over the joint state (speed class, cell): the
    class of a step kept from the last one's or drawn afresh as in the online filter
    (:meth:`MotionModel.class_transition`), the cell moved by its class
    (:meth:`MotionModel.class_moves`, the backward pass its transpose), exact where the online
    filter keeps one class distribution for the whole belief; O(J C) a frame, J C T numbers kept
    (above :data:`SMOOTH_JOINT_MAX` the plain kernel, with a warning). Otherwise (the default,
    ``smoother: plain``; why: :class:`models.scenario.TrackingSpec`) the plain kernel.
    """
    f = RouteFilter(route, spec=spec)
    grid, motion = f.grid, f.motion
    n = len(logliks)
    dts = list(dts) if dts is not None else [None] * n
    if len(dts) != n:
        raise ValueError("dts must have one entry per frame")
    likes = [np.ones(grid.cells) if ll is None else _cell_likelihood(grid, ll) for ll in logliks]
    joint = spec.smoother == "speed" and motion.persistence > 0 and n > 1
    if joint and n * grid.cells * len(motion.speed_classes(dts[1])[2]) > SMOOTH_JOINT_MAX:
        _log.warning(
            "smoothing %d frames of %d cells with the plain kernel: the speed state's joint grid would hold "
            "more than %d numbers",
            n,
            grid.cells,
            SMOOTH_JOINT_MAX,
        )
        joint = False
    posts = _smooth_joint(grid, motion, likes, dts) if joint else _smooth_plain(grid, motion, likes, dts)
    out: list[TrackEstimate] = []
    state = "lost"
    for t, post in enumerate(posts):
        est = _estimate(grid, post, state, logliks[t] is not None)
        state = _next_state(state, est.confidence, spec)
        out.append(dataclasses.replace(est, state=state))
    return out


def _smooth_plain(
    grid: RouteGrid, motion: MotionModel, likes: list[np.ndarray], dts: list[float | None]
) -> list[np.ndarray]:
    """Smoothed beliefs ``(C,)`` per frame under the plain kernel."""
    alphas = []
    belief = np.full(grid.cells, 1.0 / grid.cells)
    for t, like in enumerate(likes):
        pred = belief if t == 0 else motion.predict(belief, dts[t])
        belief = np.maximum(pred * like, _TINY)
        belief /= max(belief.sum(), 1e-300)
        alphas.append(belief)
    beta = np.ones(grid.cells)
    posts = []
    for t in range(len(likes) - 1, -1, -1):
        post = alphas[t] * beta
        posts.append(post / max(post.sum(), 1e-300))
        if t > 0:
            beta = motion.adjoint(likes[t] * beta, dts[t])
            beta /= max(beta.max(), 1e-300)
    posts.reverse()
    return posts


def _smooth_joint(
    grid: RouteGrid, motion: MotionModel, likes: list[np.ndarray], dts: list[float | None]
) -> list[np.ndarray]:
    """Smoothed beliefs ``(C,)`` per frame over the joint (speed class, cell) state: frame 0 has
    no class; frame t >= 1 the class of the step into it (frame 1's drawn from the kernel's)."""
    pk = motion.p_kidnap
    cells = grid.cells
    first = np.full(cells, 1.0 / cells) * likes[0]
    first /= max(first.sum(), 1e-300)
    alphas: list[np.ndarray] = [first]
    trans: list[np.ndarray | None] = [None, None]
    for t in range(1, len(likes)):
        pi = motion.speed_classes(dts[t])[2]
        if t == 1:
            m = pi[:, None] * first[None, :]
        else:
            trans.append(motion.class_transition(alphas[-1].shape[0], dts[t]))
            m = trans[t] @ alphas[-1]
        pred = (1.0 - pk) * motion.class_moves(m, dts[t]) + pk * m.sum(axis=1, keepdims=True) / cells
        a = np.maximum(pred * likes[t][None, :], _TINY)
        a /= max(float(a.sum()), 1e-300)
        alphas.append(a)
    beta = np.ones_like(alphas[-1])
    posts = []
    for t in range(len(likes) - 1, -1, -1):
        post = alphas[t] * beta
        post = post if post.ndim == 1 else post.sum(axis=0)
        posts.append(post / max(float(post.sum()), 1e-300))
        if t > 0:
            g = likes[t][None, :] * beta
            h = (1.0 - pk) * motion.class_adjoint(g, dts[t]) + pk * g.mean(axis=1, keepdims=True)
            pi = motion.speed_classes(dts[t])[2]
            beta = pi @ h if t == 1 else trans[t].T @ h  # type: ignore[union-attr]
            beta /= max(float(beta.max()), 1e-300)
    posts.reverse()
    return posts
