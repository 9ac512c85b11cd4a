"""The scene-analysis scheduler: verifies the associative ranking by asking landmark detectors.

For each camera frame it waits for the rankings of every ranking source (every memory shard, and
the skyline when enabled), fuses them (:mod:`knowledge_sources.fusion`), and runs a
:class:`~knowledge_sources.scene_analysis.SceneAnalysis` (the decision rule is documented
there): each question becomes a ``query`` hypothesis addressed to the detector agent of the
landmark's kind, with a deadline; each ``answer`` advances the analysis; a query that times out
(detector dead or late) counts as no answer, and the frame's result says it was degraded. When
the analysis decides, the scheduler posts the ``position`` hypothesis.

Closing the loop with the tracker (:mod:`knowledge_sources.tracker`, option ``tracked``): the
analysis of frame t starts once the ``track`` of frame t - 1 is on the blackboard (frames may
come faster than the tracker follows; their rankings wait, and the decisions do not depend on
timing). When that track says ``tracking``, the frame's candidates and P(L|A) are conditioned on
its prediction for frame t (``prior_next``); when it says ``lost``, the frame is analysed blind,
from the ranking alone. The track prior for frame t thus comes from frames < t only; the
``position`` says which (``track_prior``).

Blind fallback: with each tracked frame's position the scheduler posts a ``track_query``
addressed to the tracker with a deadline (``track_timeout_s``); the tracker's track of that
frame links it (the answer). When the query times out (the tracker is dead or gone, which the
blackboard's membership reports at once, or its track is late), the next frame is analysed
blind, from the ranking alone, and its position says why in ``degraded`` (naming the tracker);
a track arriving after that is not used for that frame.

Render-and-compare verification (option ``verify_candidates`` >= 2, the scenario's ``verify``
block, :class:`models.scenario.VerifySpec`): when the fused ranking's second route point is
within ``verify_margin`` nats of the first, the scheduler posts a ``verify_query`` of the fused
ranking's first ``verify_candidates`` viewframes (every viewframe, not only each route point's
best: a place between two route points is often the second view of its point) addressed to the
verifier with a deadline (``verify_timeout_s``); the ``verification`` raises each candidate's
fused score by ``verify_weight`` times its correlation's shortfall from the best
(:func:`models.verify.verified_ranking`), and the scene analysis starts from that ranking (each
route point at its best viewframe again). With ``verify_when`` "blind" (the default) only a
frame analysed without a track prior is verified (no tracker, the first frame, or the track
lost: the blind start, where the frame's own answer is the mission's); "always": every such
frame. A verification that does not come leaves the ranking as it is, and the position says so in
``degraded``.
"""

from __future__ import annotations

import logging
import re
import time
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from blackboard.hypothesis import Hypothesis
from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels
from knowledge_sources.scene_analysis import Backtracking, Question, QuestionOrder, SceneAnalysis, Strategy
from models.scenario import SchedulerSpec, VerifySpec

__all__ = ["Scheduler", "detector_name"]

log = logging.getLogger(__name__)

#: the defaults of every option: the scenario schema's ``scheduler`` settings
_DEFAULTS = SchedulerSpec()
#: the verification's: the scenario schema's ``verify`` settings (off unless ``verify_candidates`` is given)
_VERIFY = VerifySpec()


def detector_name(kind: str) -> str:
    """The agent name of the detector for landmark ``kind`` (``detector-<kind>``)."""
    return "detector-" + (re.sub(r"[^A-Za-z0-9_-]+", "_", kind) or "_")


@dataclass
class _Frame:
    frame: int
    frame_time: float
    rankings: dict[tuple[str, int], Any] = field(default_factory=dict)  # (source, shard) -> ranking message
    turns: dict[int, tuple[float, float]] = field(default_factory=dict)  # viewframe -> (heading, pitch), skyline
    shards: dict[str, int] = field(default_factory=dict)  # source -> its number of shards
    analysis: SceneAnalysis | None = None
    question: Question | None = None
    query_id: str | None = None
    queries_posted: int = 0
    links: list[str] = field(default_factory=list)
    degraded: list[str] = field(default_factory=list)
    ranking: list[tuple[int, float]] = field(default_factory=list)  # fused, the best viewframe of each route point
    fused: list[tuple[int, float]] = field(default_factory=list)  # fused, every viewframe
    track_prior: bool = False
    done: bool = False
    verify_id: str | None = None  # the verify query under way
    verified: str = ""  # what the verification did, for the position's reason


class Scheduler(KnowledgeSource):
    """Options: ``strategy`` ("associative" or "prior"), ``candidates``, ``accept``,
    ``reliability`` (assumed detector reliability), ``beta`` (ranking weight sharpness),
    ``min_pixels`` (a landmark is asked about only where it covers at least this many pixels of
    the viewframe: smaller ones cannot be verified reliably), ``query_timeout_s``,
    ``backtracking`` ("hard" or "soft"), ``questions`` ("information" or "probability"),
    ``floor``, ``max_llr``, ``neighbour_visibility``, ``position_evidence``, ``position_spread``, ``position_dof``,
    ``max_position_llr`` (the scene-analysis rule's, :mod:`knowledge_sources.scene_analysis`; the
    position evidence's predictions are the map's ``placements``, the camera's turn against each
    viewframe the ``shifts`` of a ranking source that posts them, the skyline);
    each defaults to the scenario schema's (:class:`models.scenario.SchedulerSpec`). ``sources``
    (``{source: weight}``: the ranking sources a frame waits for, all their shards, before its
    analysis starts, and their weights in the fusion of :mod:`knowledge_sources.fusion`; default
    the associative memory alone).
    each defaults to the scenario schema's (:class:`models.scenario.SchedulerSpec`).
    ``tracked``: a tracker runs (the agent ``tracker``), frames are conditioned on its tracks, and
    a frame whose previous track does not come within ``track_timeout_s`` is analysed blind (see
    the module docstring). ``verify_candidates`` (0: off, the default; else >= 2),
    ``verify_margin``, ``verify_weight``, ``verify_timeout_s``, ``verify_when`` ("blind" or
    "always"), ``verifier`` (the agent asked):
    the render-and-compare verification of the module docstring (the scenario's ``verify``
    block, :class:`models.scenario.VerifySpec`).
    """

    consumes: ClassVar[tuple[str, ...]] = (
        levels.MAP,
        levels.RANKING,
        levels.ANSWER,
        levels.TRACK,
        levels.VERIFICATION,
    )
    produces: ClassVar[tuple[str, ...]] = (levels.QUERY, levels.POSITION, levels.TRACK_QUERY, levels.VERIFY_QUERY)
    exclusive: ClassVar[tuple[str, ...]] = (levels.QUERY, levels.POSITION, levels.TRACK_QUERY, levels.VERIFY_QUERY)

    def __init__(
        self,
        name: str,
        *,
        strategy: str = _DEFAULTS.strategy,
        candidates: int = _DEFAULTS.candidates,
        accept: float = _DEFAULTS.accept,
        reliability: float = _DEFAULTS.reliability,
        beta: float = _DEFAULTS.beta,
        min_pixels: int = _DEFAULTS.min_pixels,
        query_timeout_s: float = _DEFAULTS.query_timeout_s,
        sources: dict[str, float] | None = None,
        tracked: bool = False,
        tracker: str = "tracker",
        track_timeout_s: float = _DEFAULTS.track_timeout_s,
        backtracking: str = _DEFAULTS.backtracking,
        questions: str = _DEFAULTS.questions,
        floor: float = _DEFAULTS.floor,
        max_llr: float = _DEFAULTS.max_llr,
        neighbour_visibility: float = _DEFAULTS.neighbour_visibility,
        position_evidence: bool = _DEFAULTS.position_evidence,
        position_spread: tuple[float, float, float] | list[float] = _DEFAULTS.position_spread,
        position_dof: float = _DEFAULTS.position_dof,
        max_position_llr: float = _DEFAULTS.max_position_llr,
        verify_candidates: int = 0,
        verify_margin: float = _VERIFY.margin,
        verify_weight: float = _VERIFY.weight,
        verify_timeout_s: float = _VERIFY.timeout_s,
        verify_when: str = _VERIFY.when,
        verifier: str = "verifier",
        **options: Any,
    ) -> None:
        super().__init__(name, **options)
        if strategy not in ("associative", "prior"):
            raise ValueError(f"strategy must be 'associative' or 'prior', not {strategy!r}")
        self.strategy: Strategy = strategy  # type: ignore[assignment]  # checked just above
        self.candidates = int(candidates)
        self.accept = float(accept)
        self.reliability = float(reliability)
        self.beta = float(beta)
        self.min_pixels = int(min_pixels)
        self.query_timeout_s = float(query_timeout_s)
        self.sources = {"associative": 1.0} if sources is None else {str(k): float(v) for k, v in sources.items()}
        if not self.sources or any(w < 0 for w in self.sources.values()) or not any(self.sources.values()):
            raise ValueError(f"sources must map ranking sources to weights >= 0, one > 0, got {sources!r}")
        if backtracking not in ("hard", "soft"):
            raise ValueError(f"backtracking must be 'hard' or 'soft', not {backtracking!r}")
        if questions not in ("information", "probability"):
            raise ValueError(f"questions must be 'information' or 'probability', not {questions!r}")
        self.backtracking: Backtracking = backtracking  # type: ignore[assignment]  # checked just above
        self.questions: QuestionOrder = questions  # type: ignore[assignment]  # checked just above
        self.floor = float(floor)
        self.max_llr = float(max_llr)
        self.neighbour_visibility = float(neighbour_visibility)
        self.position_evidence = bool(position_evidence)
        if len(position_spread) != 3:
            raise ValueError(f"position_spread must be three values, got {position_spread!r}")
        self.position_spread = (float(position_spread[0]), float(position_spread[1]), float(position_spread[2]))
        self.position_dof = float(position_dof)
        self.max_position_llr = float(max_position_llr)
        self.verify_candidates = int(verify_candidates)
        if self.verify_candidates == 1 or self.verify_candidates < 0:
            raise ValueError(f"verify_candidates must be 0 (off) or >= 2, got {verify_candidates!r}")
        self.verify_margin = float(verify_margin)
        self.verify_weight = float(verify_weight)
        self.verify_timeout_s = float(verify_timeout_s)
        if verify_when not in ("blind", "always"):
            raise ValueError(f"verify_when must be 'blind' or 'always', not {verify_when!r}")
        self.verify_when = str(verify_when)
        if not (self.verify_weight >= 0 and self.verify_margin >= 0 and self.verify_timeout_s > 0):
            raise ValueError(
                f"verify_weight and verify_margin must be >= 0 and verify_timeout_s > 0, got "
                f"{verify_weight!r}, {verify_margin!r}, {verify_timeout_s!r}"
            )
        self.verifier = str(verifier)
        self._placements: dict[int, dict[str, tuple[float, float, float]]] = {}  # viewframe -> landmark -> place
        self._map: levels.Map | None = None
        self._landmarks: dict[str, dict[str, Any]] = {}  # id -> {kind, index, ...}, from the map
        self._visible: dict[int, frozenset[str]] = {}  # viewframe -> landmarks worth asking about
        self._frames: dict[int, _Frame] = {}
        self.tracked = bool(tracked)
        self.tracker = str(tracker)
        self.track_timeout_s = float(track_timeout_s)
        if not self.track_timeout_s > 0:
            raise ValueError(f"track_timeout_s must be > 0, got {track_timeout_s!r}")
        self._tracks: dict[int, Any] = {}  # frame t -> prior for frame t + 1 from track t (None: lost)
        self._no_track: dict[int, str] = {}  # frame t -> why its track did not come (frame t + 1 is blind)
        self._parked: dict[int, _Frame] = {}  # frame t - 1 -> frame t, ranked, waiting for track t - 1

    def precondition(self, event: Event) -> float | None:
        if event.kind is not EventKind.POSTED:
            return None
        # answers first: they finish frames already under way (focus of attention); then tracks,
        # which release the frame waiting for them
        return {levels.ANSWER: 3.0, levels.VERIFICATION: 3.0, levels.TRACK: 2.5, levels.MAP: 2.0}.get(
            event.hypothesis.level, 1.0
        )

    # -- events ----------------------------------------------------------------------------
    def act(self, event: Event, board: Board) -> None:
        h = event.hypothesis
        if h.level == levels.MAP:
            self._set_map(levels.Map.from_hypothesis(h))
        elif h.level == levels.RANKING:
            self._on_ranking(h, board)
        elif h.level == levels.ANSWER:
            self._on_answer(h, board)
        elif h.level == levels.VERIFICATION:
            self._on_verification(h, board)
        elif h.level == levels.TRACK:
            track = levels.Track.from_hypothesis(h)
            if track.frame in self._no_track:
                return  # late: the next frame was released blind already
            self._tracks[track.frame] = track.prior_next if track.state == "tracking" else None
            parked = self._parked.pop(track.frame, None)
            if parked is not None:
                self._start(parked, board)

    def on_timeout(self, hypothesis: Hypothesis, reason: str, board: Board) -> None:
        if hypothesis.level == levels.TRACK_QUERY:
            self._on_track_timeout(levels.TrackQuery.from_hypothesis(hypothesis), reason, board)
            return
        if hypothesis.level == levels.VERIFY_QUERY:
            vq = levels.VerifyQuery.from_hypothesis(hypothesis)
            st = self._frames.get(vq.frame)
            if st is not None and st.verify_id == hypothesis.id and st.analysis is None:
                log.warning("%s: frame %d: no verification from %s: %s", self.name, st.frame, self.verifier, reason)
                st.degraded.append(f"{self.verifier}: no verification ({reason}), the ranking as fused")
                st.verify_id = None
                self._analyse(st, board)
            return
        if hypothesis.level != levels.QUERY:
            return
        query = levels.Query.from_hypothesis(hypothesis)
        st = self._frames.get(query.frame)
        if st is None or st.done or st.query_id != hypothesis.id or st.analysis is None:
            return
        log.warning("%s: frame %d: query %s unanswered: %s", self.name, st.frame, hypothesis.id, reason)
        st.degraded.append(f"{query.landmark}: {reason}")
        question, st.question, st.query_id = st.question, None, None
        assert question is not None
        st.analysis.answer(question, None)
        self._advance(st, board)

    def _on_track_timeout(self, query: levels.TrackQuery, reason: str, board: Board) -> None:
        """The track of ``query.frame`` did not come (tracker dead, gone or late): the next frame
        goes blind."""
        nxt = self._frames.get(query.frame + 1)
        if (
            query.frame in self._tracks
            or query.frame in self._no_track
            or (nxt is not None and nxt.analysis is not None)
        ):
            return  # the track came (and may have been used already)
        log.warning("%s: frame %d: no track from %s: %s", self.name, query.frame, self.tracker, reason)
        self._no_track[query.frame] = reason
        self._tracks[query.frame] = None
        parked = self._parked.pop(query.frame, None)
        if parked is not None:
            self._start(parked, board)

    def _set_map(self, mp: levels.Map) -> None:
        """Keep the map and what the questions need of it, derived once."""
        self._map = mp
        self._landmarks = {lm["id"]: lm for lm in mp.landmarks}
        self._visible = mp.visible_sets(min_pixels=self.min_pixels)
        self._placements = mp.placement_table()

    def _ensure_map(self, board: Board) -> levels.Map:
        if self._map is None:
            got = board.get(levels.map_id())
            if got is None:
                raise RuntimeError("a ranking arrived but the map is not on the blackboard")
            self._set_map(levels.Map.from_hypothesis(got))
        assert self._map is not None
        return self._map

    def _on_ranking(self, h: Hypothesis, board: Board) -> None:
        rk = levels.Ranking.from_hypothesis(h)
        st = self._frames.setdefault(rk.frame, _Frame(rk.frame, rk.frame_time))
        if st.analysis is not None or rk.source not in self.sources:
            return
        st.shards[rk.source] = rk.shards
        st.rankings[(rk.source, rk.shard)] = rk
        if rk.shifts is not None and not st.turns:  # the first source with shifts (the skyline) gives the turns
            st.turns = {int(k): (float(s[0]), float(s[1])) for k, s in zip(rk.viewframes, rk.shifts)}
        st.links.append(h.id)
        got = {src: sum(1 for s, _ in st.rankings if s == src) for src in self.sources}
        if any(src not in st.shards or got[src] < st.shards[src] for src in self.sources):
            return
        if self.tracked and st.frame > 0 and st.frame - 1 not in self._tracks:
            self._parked[st.frame - 1] = st
            return
        self._start(st, board)

    def _start(self, st: _Frame, board: Board) -> None:
        """Merge each source's shards, fuse the sources and start the frame's scene analysis
        (conditioned on the track)."""
        from knowledge_sources.fusion import fuse_shards

        mp = self._ensure_map(board)
        shards = {src: [st.rankings[(src, b)].ranking() for b in range(st.shards[src])] for src in self.sources}
        st.fused = fuse_shards(shards, weights=self.sources)
        st.ranking = _best_view_per_point(st.fused, mp)
        r = st.ranking
        blind = self._tracks.get(st.frame - 1) is None  # no track prior: no tracker, the first frame, or lost
        if (
            self.verify_candidates >= 2
            and (blind or self.verify_when == "always")
            and len(r) >= 2
            and r[1][1] - r[0][1] < self.verify_margin
        ):
            q = levels.post(
                board,
                levels.VerifyQuery(frame=st.frame, viewframes=[int(k) for k, _ in st.fused[: self.verify_candidates]]),
                links=(levels.frame_id(st.frame),),
                addressed_to=self.verifier,
                deadline_s=self.verify_timeout_s,
            )
            st.verify_id = q.id
            return
        self._analyse(st, board)

    def _on_verification(self, h: Hypothesis, board: Board) -> None:
        """The verifier's scores: the ranking re-scored by them, then the scene analysis."""
        from models.verify import verified_ranking

        v = levels.Verification.from_hypothesis(h)
        st = self._frames.get(v.frame)
        if st is None or st.verify_id is None or st.verify_id != v.query or st.analysis is not None:
            return  # late: the frame went on without it
        st.verify_id = None
        first = st.ranking[0][0]
        st.fused = verified_ranking(st.fused, v.viewframes, v.correlations, weight=self.verify_weight)
        st.ranking = _best_view_per_point(st.fused, self._ensure_map(board))
        st.links.append(h.id)
        st.verified = f"verified {len(v.viewframes)} candidates by render and compare" + (
            "" if st.ranking[0][0] == first else f" (first viewframe {first} -> {st.ranking[0][0]})"
        )
        self._analyse(st, board)

    def _analyse(self, st: _Frame, board: Board) -> None:
        """Start the frame's scene analysis from its ranking (conditioned on the track)."""
        mp = self._ensure_map(board)
        prior = self._tracks.pop(st.frame - 1, None)
        st.track_prior = prior is not None
        missing = self._no_track.get(st.frame - 1)
        if missing is not None:
            st.degraded.append(f"{self.tracker}: no track of frame {st.frame - 1}, analysed blind ({missing})")
        st.analysis = SceneAnalysis(
            st.ranking,
            self._visible,
            strategy=self.strategy,
            candidates=self.candidates,
            accept=self.accept,
            reliability=self.reliability,
            beta=self.beta,
            priors=mp.priors,
            track_prior=None if prior is None else _per_viewframe(np.asarray(prior, dtype=np.float64), mp),
            backtracking=self.backtracking,
            questions=self.questions,
            floor=self.floor,
            max_llr=self.max_llr,
            neighbour_visibility=self.neighbour_visibility,
            placements=self._placements or None,
            turns=st.turns or None,
            position_evidence=self.position_evidence,
            position_spread=self.position_spread,
            position_dof=self.position_dof,
            max_position_llr=self.max_position_llr,
        )
        self._advance(st, board)

    def _on_answer(self, h: Hypothesis, board: Board) -> None:
        answer = levels.Answer.from_hypothesis(h)
        st = self._frames.get(answer.frame)
        if st is None or st.done or st.query_id is None or st.query_id != answer.query or st.analysis is None:
            return  # a late answer to a query already timed out
        question, st.question, st.query_id = st.question, None, None
        assert question is not None
        present = answer.present
        st.links.append(h.id)
        st.analysis.answer(question, present, score=answer.score, llr=answer.llr, where=answer.where)
        if present is None and (answer.llr is None or self.backtracking == "hard"):
            # the detector could not tell: no evidence either way, and not counted as a query
            st.degraded.append(f"{question.landmark}: undecided ({answer.reason})")
        self._advance(st, board)

    # -- the loop --------------------------------------------------------------------------
    def _advance(self, st: _Frame, board: Board) -> None:
        mp = self._map
        assert mp is not None and st.analysis is not None
        question = st.analysis.next_question()
        if question is not None:
            lm = self._landmarks[question.landmark]
            st.queries_posted += 1
            q = levels.post(
                board,
                levels.Query(
                    frame=st.frame,
                    number=st.queries_posted,
                    landmark=question.landmark,
                    landmark_index=int(lm["index"]),
                    kind=lm["kind"],
                    viewframe=question.viewframe,
                    p=question.probability,
                ),
                links=(levels.frame_id(st.frame), levels.viewframe_id(question.viewframe)),
                addressed_to=detector_name(lm["kind"]),
                deadline_s=self.query_timeout_s,
                credibility=float(min(1.0, max(0.0, question.probability))),
            )
            st.question, st.query_id = question, q.id
            return
        d = st.analysis.decision
        assert d is not None
        st.done = True
        position, heading_deg = levels.Position.at(None if d.viewframe is None else mp.pose(d.viewframe))
        if self.tracked:  # the tracker's track of this frame answers it (the tracker waits for it)
            levels.post(
                board,
                levels.TrackQuery(frame=st.frame, position=levels.position_id(st.frame)),
                addressed_to=self.tracker,
                deadline_s=self.track_timeout_s,
            )
        levels.post(
            board,
            levels.Position(
                frame=st.frame,
                viewframe=d.viewframe,
                position=position,
                heading_deg=heading_deg,
                confidence=d.confidence,
                queries=d.queries,
                backtracks=d.backtracks,
                latency_ms=(time.time() - st.frame_time) * 1000.0,
                ranking=[[k, v] for k, v in st.ranking[:5]],
                reason=d.reason
                + (f"; {st.verified}" if st.verified else "")
                + ("; degraded: " + "; ".join(st.degraded) if st.degraded else ""),
                degraded=list(st.degraded),
                steps=[dict(s) for s in d.steps],
                strategy=self.strategy,
                track_prior=st.track_prior,
                verified=bool(st.verified),
            ),
            links=tuple(dict.fromkeys([levels.frame_id(st.frame), *st.links])),
            credibility=float(min(1.0, max(0.0, d.confidence))),
        )


def _per_viewframe(per_point: np.ndarray, mp: levels.Map) -> np.ndarray:
    """The track's prior of each route point ``(N,)`` as one of each viewframe ``(V,)``: a
    viewframe takes its route point's (the map's ``route_points``; the same array when the
    viewframes are the route points)."""
    if mp.route_points is None:
        return per_point
    return per_point[np.clip(mp.route_points, 0, per_point.size - 1)]


def _best_view_per_point(ranking: list[tuple[int, float]], mp: levels.Map) -> list[tuple[int, float]]:
    """The fused ranking with only the best viewframe of each route point (the others dropped),
    when the map has viewframes between the route points; else as it is. The scene analysis then
    weighs, questions and decides between route points, as many as with one viewframe a point,
    each seen from its best viewframe (whose landmarks the questions are about and whose place the
    answer gives). A point is its best viewframe, not the total probability of its viewframes: on
    the evaluation set's tuning split the total gave back the whole gain of the viewframes between
    the points (top-1 0.745 -> 0.690, that of one viewframe a point; BENCHMARKS.md), since views a
    third of a leg apart match a camera alike and the total favours the point with the most of
    them, not the place that matches best. The tracker takes every viewframe (its own fusion of
    the same rankings)."""
    from models.route_views import first_per_point

    if mp.route_points is None:
        return ranking
    return first_per_point(ranking, mp.route_points)
