"""The tracker: the vehicle's place on the route from the sequence of camera frames.

It consumes, per camera frame, the associative rankings (every shard's) and the scene
analysis's decision (the landmark answers it got, and its single-frame answer), strictly in
frame order, and keeps a :class:`~models.tracking.RouteFilter` (the model and its calibration
are documented in :mod:`models.tracking`). For each frame it posts a ``track`` hypothesis: the
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
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels

if TYPE_CHECKING:
    from models.tracking import RouteFilter

__all__ = ["Tracker", "FrameOrder"]

log = logging.getLogger(__name__)


@dataclass
class _Pending:
    rankings: dict[int, tuple[list[int], list[float]]] = field(default_factory=dict)
    shards: int = 1
    time: float | None = None
    position: levels.Position | None = None
    links: list[str] = field(default_factory=list)

    @property
    def ready(self) -> bool:
        return len(self.rankings) >= self.shards and self.position is not None


class FrameOrder:
    """Buffers per-frame evidence and releases frames in order, each once it is complete
    (every shard's ranking and the scene analysis's position)."""

    def __init__(self) -> None:
        self.pending: dict[int, _Pending] = {}
        self.next = 0

    def ranking(self, frame: int, shard: int, shards: int, viewframes, variances, time: float | None, hid: str) -> None:
        p = self.pending.setdefault(frame, _Pending())
        p.shards = shards
        p.rankings[shard] = (list(viewframes), list(variances))
        p.time = time if time is not None else p.time
        p.links.append(hid)

    def position(self, frame: int, position: levels.Position, hid: str) -> None:
        p = self.pending.setdefault(frame, _Pending())
        p.position = position
        p.links.append(hid)

    def ready(self) -> list[tuple[int, _Pending]]:
        """The frames that can be processed now, in order (removed from the buffer)."""
        out = []
        while (p := self.pending.get(self.next)) is not None and p.ready:
            out.append((self.next, self.pending.pop(self.next)))
            self.next += 1
        return out


def answers_of(steps: list[dict[str, Any]]) -> list[tuple[str, bool]]:
    """The landmark answers (landmark, present) of a position's steps; undecided ones left out."""
    return [(s["landmark"], bool(s["present"])) for s in steps if s.get("present") is not None]


class Tracker(KnowledgeSource):
    """Options: the scenario's ``tracking`` block as a dict (``spec``), ``min_pixels`` (a landmark
    counts as visible in a viewframe from this many pixels, as the scheduler's)."""

    consumes: ClassVar[tuple[str, ...]] = (levels.MAP, levels.RANKING, levels.POSITION)
    produces: ClassVar[tuple[str, ...]] = (levels.TRACK,)
    exclusive: ClassVar[tuple[str, ...]] = (levels.TRACK,)

    def __init__(
        self, name: str, *, spec: dict[str, Any] | None = None, min_pixels: int | None = None, **options: Any
    ) -> None:
        super().__init__(name, **options)
        from models.scenario import SchedulerSpec, TrackingSpec

        self.spec = TrackingSpec(**(spec or {}))
        self.min_pixels = int(SchedulerSpec().min_pixels if min_pixels is None else min_pixels)
        self._filter: RouteFilter | None = None
        self._visible: dict[int, frozenset[str]] = {}
        self._order = FrameOrder()
        self._last_time: float | None = None

    def precondition(self, event: Event) -> float | None:
        if event.kind is not EventKind.POSTED:
            return None
        return 2.0 if event.hypothesis.level == levels.MAP else 1.0

    def act(self, event: Event, board: Board) -> None:
        h = event.hypothesis
        if h.level == levels.MAP:
            self._set_map(levels.Map.from_hypothesis(h))
            return
        if h.level == levels.RANKING:
            rk = levels.Ranking.from_hypothesis(h)
            if rk.source != "associative":  # its observation model is calibrated on the memory's variances
                return
            self._order.ranking(rk.frame, rk.shard, rk.shards, rk.viewframes, rk.variances, rk.time, h.id)
        elif h.level == levels.POSITION:
            pos = levels.Position.from_hypothesis(h)
            self._order.position(pos.frame, pos, h.id)
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
        self._filter = RouteFilter(mp.route, spec=self.spec)
        self._visible = {
            int(k): frozenset(lm for lm, px in v.items() if px >= self.min_pixels) for k, v in mp.visible.items()
        }

    def _step(self, frame: int, p: _Pending, board: Board) -> None:
        f = self._filter
        assert f is not None and p.position is not None
        viewframes = [k for b in sorted(p.rankings) for k in p.rankings[b][0]]
        variances = [v for b in sorted(p.rankings) for v in p.rankings[b][1]]
        ll = f.route_loglik(viewframes, variances, answers=answers_of(p.position.steps), visible=self._visible)
        dt = None
        if p.time is not None and self._last_time is not None:
            dt = float(p.time) - self._last_time
        self._last_time = None if p.time is None else float(p.time)
        est = f.step(ll, dt=dt)
        assert est.belief is not None
        prior_next = f.grid.point_mass(f.prior(dt)).astype(np.float32)
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
                loglik=None if ll is None else ll.astype(np.float32),
                dt=dt,
            ),
            links=tuple(dict.fromkeys(p.links)),
            credibility=float(min(1.0, max(0.0, est.confidence))),
        )
