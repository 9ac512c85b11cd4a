"""The tracker: the vehicle's place on the route from the sequence of camera frames.

It consumes, per camera frame, the rankings of every ranking source the single-frame decision
uses (option ``sources``, the scheduler's: the associative memory's shards and the skyline) and
the scene analysis's decision (the landmark answers it got, and its single-frame answer),
strictly in frame order, and keeps a :class:`~models.tracking.RouteFilter` (the model and its
calibration are documented in :mod:`models.tracking`). It observes the sources fused by the
scheduler's own rule (same weights): with ``tracking.scores: nats`` (the default) the calibrated
fusion's negative log posterior of each viewframe
(:func:`knowledge_sources.fusion.shards_log_posterior`), with ``robust`` the fused scores of
:func:`knowledge_sources.fusion.fuse_shards` as the scheduler has them, so the track and the
single-frame decision rest on the same ranking. With viewframes between the route points
and ``tracking.evidence: views`` (the default) each viewframe's evidence stands at its own arc
length (:attr:`models.tracking.RouteFilter.observes_views`), else its route point's total
(:func:`by_route_point`). For each frame it posts a ``track`` hypothesis: the
route point, arc length, ``(x, y)``, heading, confidence, ``tracking``/``lost`` state, the
posterior mass of each route point (``belief``), the predicted probability of each route point for the next frame (``prior_next``, which the
scheduler uses to condition the next frame's questions), the frame's per-route-point evidence
log-likelihood and time step (so the drive can be smoothed offline), linked to the rankings and
the position it used.

Ordering: evidence may arrive in any order and faster than the filter runs; frames are buffered
and the filter steps through them in frame order only. The track of frame t uses frames <= t;
the prior the scheduler gets for frame t comes from the track of frame t - 1 (frames < t).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels

if TYPE_CHECKING:
    from models.tracking import RouteFilter

__all__ = ["Tracker", "FrameOrder", "by_route_point", "views_per_leg_of"]

log = logging.getLogger(__name__)


@dataclass
class _Pending:
    rankings: dict[tuple[str, int], tuple[list[int], list[float]]] = field(default_factory=dict)  # (source, shard)
    shards: dict[str, int] = field(default_factory=dict)  # source -> its number of shards
    time: float | None = None
    position: levels.Position | None = None
    queried: bool = False  # the scheduler's track query of the frame is in
    links: list[str] = field(default_factory=list)

    def complete(self, sources: tuple[str, ...], *, await_query: bool = False) -> bool:
        """Every source's every shard, and the position (and with ``await_query`` the track query), are in."""
        return (
            self.position is not None
            and (self.queried or not await_query)
            and all(
                src in self.shards and sum(1 for s, _ in self.rankings if s == src) >= self.shards[src]
                for src in sources
            )
        )

    def by_source(self) -> dict[str, list[tuple[list[int], list[float]]]]:
        """Each source's shards ``(viewframes, errors)``, in shard order."""
        out: dict[str, list[tuple[list[int], list[float]]]] = {}
        for src, b in sorted(self.rankings):
            out.setdefault(src, []).append(self.rankings[(src, b)])
        return out


class FrameOrder:
    """Buffers per-frame evidence and releases frames in order, each once it is complete
    (every shard's ranking of every source in ``sources``, the scene analysis's position, and
    with ``await_query`` the scheduler's track query, which the track must link: it may arrive
    after the position). Rankings of other sources are ignored."""

    def __init__(self, sources: tuple[str, ...] = ("associative",), *, await_query: bool = False) -> None:
        if not sources:
            raise ValueError("FrameOrder needs at least one ranking source")
        self.sources = tuple(sources)
        self.await_query = bool(await_query)
        self.pending: dict[int, _Pending] = {}
        self.next = 0

    def ranking(
        self,
        frame: int,
        shard: int,
        shards: int,
        viewframes,
        variances,
        time: float | None,
        hid: str,
        *,
        source: str = "associative",
    ) -> None:
        if source not in self.sources:
            return
        p = self.pending.setdefault(frame, _Pending())
        p.shards[source] = shards
        p.rankings[(source, shard)] = (list(viewframes), list(variances))
        p.time = time if time is not None else p.time
        p.links.append(hid)

    def position(self, frame: int, position: levels.Position, hid: str) -> None:
        p = self.pending.setdefault(frame, _Pending())
        p.position = position
        p.links.append(hid)

    def query(self, frame: int, hid: str) -> None:
        """The scheduler's track query of ``frame`` (the track links it)."""
        if frame >= self.next:  # a frame already tracked cannot link it any more
            p = self.pending.setdefault(frame, _Pending())
            p.queried = True
            p.links.append(hid)

    def ready(self) -> list[tuple[int, _Pending]]:
        """The frames that can be processed now, in order (removed from the buffer)."""
        out = []
        while (p := self.pending.get(self.next)) is not None and p.complete(self.sources, await_query=self.await_query):
            out.append((self.next, self.pending.pop(self.next)))
            self.next += 1
        return out


def by_route_point(
    viewframes: Sequence[int], scores: Sequence[float], route_points: np.ndarray, *, nats: bool
) -> tuple[list[int], list[float]]:
    """A ranking of viewframes (labels, scores: lower is better) as one of route points, given each
    viewframe's route point ``route_points`` (the map's). ``nats``: the scores are negative log
    posteriors, and a route point's is that of its viewframes' total probability,
    ``-log sum_v exp(-s_v)``; else a point takes its best viewframe's score. Points in order of
    first appearance (best first when the ranking is sorted)."""
    best: dict[int, list[float]] = {}
    for v, e in zip(viewframes, scores):
        best.setdefault(int(route_points[int(v)]), []).append(float(e))
    if nats:
        out = {k: float(-np.logaddexp.reduce(-np.asarray(es))) for k, es in best.items()}
    else:
        out = {k: min(es) for k, es in best.items()}
    return list(out), list(out.values())


def views_per_leg_of(mp: levels.Map) -> int:
    """The map's viewframes per leg F (:func:`models.route_views.view_route`: V = F (N - 1) + 1
    viewframes, their route points :func:`models.route_views.view_points`); 1 when they are the
    route points or do not stand on the route that way (then the tracker observes route points,
    by :func:`by_route_point`)."""
    from models.route_views import view_points

    rp, n = mp.route_points, len(mp.route)
    if rp is None or n < 2 or (rp.size - 1) % (n - 1):
        return 1
    f = (rp.size - 1) // (n - 1)
    if f < 2 or not np.array_equal(view_points(n, f), rp):
        return 1
    return f


def answers_of(steps: list[dict[str, Any]]) -> list[tuple[str, bool]]:
    """The landmark answers (landmark, present) of a position's steps; undecided ones left out."""
    return [(s["landmark"], bool(s["present"])) for s in steps if s.get("present") is not None]


class Tracker(KnowledgeSource):
    """Options: the scenario's ``tracking`` block as a dict (``spec``), ``min_pixels`` (a landmark
    counts as visible in a viewframe from this many pixels, as the scheduler's), ``sources``
    (``{source: weight}``, the scheduler's: the ranking sources a frame waits for and their
    fusion weights; default the associative memory alone), ``await_query`` (a frame is tracked
    once the scheduler's ``track_query`` for it is in as well, and its track links it: the
    scheduler's blind fallback waits for that answer; on when the scheduler is tracked),
    ``verify_weight`` (nats per unit of correlation, the scenario's ``verify.weight``; 0: not
    used): when the frame's candidates were verified by render and compare (the position says
    so; its ``verification`` is on the board before the position), the tracker
    observes them re-scored as the scheduler does (:func:`models.verify.verified_ranking`: each
    verified viewframe's negative log posterior raised by ``verify_weight`` times its
    correlation's shortfall from the best), so the track and the single-frame decision rest on
    the same evidence."""

    consumes: ClassVar[tuple[str, ...]] = (levels.MAP, levels.RANKING, levels.POSITION, levels.TRACK_QUERY)
    produces: ClassVar[tuple[str, ...]] = (levels.TRACK,)
    exclusive: ClassVar[tuple[str, ...]] = (levels.TRACK,)

    def __init__(
        self,
        name: str,
        *,
        spec: dict[str, Any] | None = None,
        min_pixels: int | None = None,
        sources: dict[str, float] | None = None,
        await_query: bool = False,
        verify_weight: float = 0.0,
        **options: Any,
    ) -> None:
        super().__init__(name, **options)
        self.verify_weight = float(verify_weight)
        if not self.verify_weight >= 0:
            raise ValueError(f"{name}: verify_weight must be >= 0, got {verify_weight!r}")
        from models.scenario import SchedulerSpec, TrackingSpec

        self.spec = TrackingSpec(**(spec or {}))
        self.min_pixels = int(SchedulerSpec().min_pixels if min_pixels is None else min_pixels)
        self.sources = {"associative": 1.0} if sources is None else {str(k): float(v) for k, v in sources.items()}
        if not self.sources or any(not w >= 0 for w in self.sources.values()) or not any(self.sources.values()):
            raise ValueError(f"{name}: sources must map ranking sources to weights >= 0, one > 0, got {sources!r}")
        self._filter: RouteFilter | None = None
        self._visible: dict[int, frozenset[str]] = {}
        self._route_points: np.ndarray | None = None  # the map's route point of each viewframe (None: the same)
        self._order = FrameOrder(tuple(self.sources), await_query=await_query)
        self._last_time: float | None = None

    def precondition(self, event: Event) -> float | None:
        if event.kind is not EventKind.POSTED:
            return None
        # the map first; then the scheduler's track queries (the frames waiting for them go on)
        return {levels.MAP: 2.0, levels.TRACK_QUERY: 1.5}.get(event.hypothesis.level, 1.0)

    def act(self, event: Event, board: Board) -> None:
        h = event.hypothesis
        if h.level == levels.MAP:
            self._set_map(levels.Map.from_hypothesis(h))
            return
        if h.level == levels.RANKING:
            rk = levels.Ranking.from_hypothesis(h)
            if rk.source not in self.sources:
                return
            self._order.ranking(
                rk.frame, rk.shard, rk.shards, rk.viewframes, rk.variances, rk.time, h.id, source=rk.source
            )
        elif h.level == levels.POSITION:
            pos = levels.Position.from_hypothesis(h)
            self._order.position(pos.frame, pos, h.id)
        elif h.level == levels.TRACK_QUERY:
            if h.addressed_to == self.name:  # the scheduler waits for this frame's track: it links the query
                self._order.query(levels.TrackQuery.from_hypothesis(h).frame, h.id)
        if self._filter is None:
            got = board.get(levels.map_id())
            if got is None:
                return  # the map event is on its way; frames wait in the buffer
            self._set_map(levels.Map.from_hypothesis(got))
        for frame, pending in self._order.ready():
            self._step(frame, pending, board)

    def _set_map(self, mp: levels.Map) -> None:
        from models.tracking import RouteFilter

        if self._filter is not None:
            return
        self._filter = RouteFilter(mp.route, spec=self.spec, views_per_leg=views_per_leg_of(mp))
        self._route_points = mp.route_points
        visible = mp.visible_sets(min_pixels=self.min_pixels)
        if mp.route_points is not None:  # viewframes between the route points: a point sees what its views see
            points: dict[int, set[str]] = {k: set() for k in range(len(mp.route))}
            for v, k in enumerate(mp.route_points.tolist()):
                points[k] |= visible.get(v, frozenset())
            visible = {k: frozenset(s) for k, s in points.items()}
        self._visible = visible

    def _verified(
        self, frame: int, viewframes: list[int], scores: list[float], p: _Pending, board: Board
    ) -> tuple[list[int], list[float]]:
        """The frame's fused scores re-scored by its verification, when there is one (class docstring)."""
        from models.verify import verified_ranking

        got = board.get(levels.verification_id(frame))
        if got is None:
            return viewframes, scores
        v = levels.Verification.from_hypothesis(got)
        p.links.append(got.id)
        out = verified_ranking(list(zip(viewframes, scores)), v.viewframes, v.correlations, weight=self.verify_weight)
        return [int(k) for k, _ in out], [float(e) for _, e in out]

    def _step(self, frame: int, p: _Pending, board: Board) -> None:
        from knowledge_sources.fusion import fuse_shards, shards_log_posterior
        from models.associative import Ranking as MemoryRanking
        from models.index import WINDOW_TAIL

        f = self._filter
        assert f is not None and p.position is not None
        shards = {
            src: [MemoryRanking.from_dict({"viewframes": k, "variances": v, "reliability": 0.0}) for k, v in parts]
            for src, parts in p.by_source().items()
        }
        if self.spec.scores == "nats":  # the scheduler's fused ranking, as negative log posteriors (nats)
            labels, log_p = shards_log_posterior(shards, weights=self.sources)
            viewframes, scores = labels.tolist(), (-log_p).tolist()
        else:  # the scheduler's fused ranking as it is (scores standardised by the filter)
            fused = fuse_shards(shards, weights=self.sources)
            viewframes, scores = [k for k, _ in fused], [e for _, e in fused]
        if self.verify_weight > 0 and p.position.verified:
            viewframes, scores = self._verified(frame, viewframes, scores, p, board)
        if self._route_points is not None and not f.observes_views:
            viewframes, scores = by_route_point(viewframes, scores, self._route_points, nats=self.spec.scores == "nats")
        ll = f.route_loglik(
            viewframes,
            scores,
            answers=answers_of(p.position.steps),
            visible=self._visible,
        )
        dt = None
        if p.time is not None and self._last_time is not None:
            dt = float(p.time) - self._last_time
        self._last_time = None if p.time is None else float(p.time)
        est = f.step(ll, dt=dt)
        assert est.belief is not None
        prediction = f.prior(dt)
        prior_next = f.grid.point_mass(prediction).astype(np.float32)
        window = f.window_next(prediction, tail=WINDOW_TAIL)
        levels.post(
            board,
            levels.Track(
                frame=frame,
                route_point=est.route_point,
                arc_m=est.arc_m,
                position=[est.x, est.y],
                heading_deg=est.heading_deg,
                confidence=est.confidence,
                state=est.state,
                evidence=est.evidence,
                belief=est.belief.astype(np.float32),
                prior_next=prior_next,
                # the evidence only for the offline smoothing: 4 samples a leg, 160 KB a frame at 10,000 points
                loglik=None if ll is None or not self.spec.smoothing else ll.astype(np.float32),
                dt=dt,
                window_next=None if window is None else [int(window[0]), int(window[1])],
            ),
            links=tuple(dict.fromkeys(p.links)),
            credibility=float(min(1.0, max(0.0, est.confidence))),
        )
