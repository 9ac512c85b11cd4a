"""The verifier: render-and-compare scores of a frame's first candidates, before the scene analysis."""

from __future__ import annotations

import logging
from typing import Any, ClassVar

from blackboard.hypothesis import Hypothesis
from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels
from knowledge_sources.map_views import MapViews, skyline_profile

__all__ = ["Verifier"]

log = logging.getLogger(__name__)


class Verifier(KnowledgeSource):
    """Owns a camera emulator of the map (it loads the scenario the ``map`` names, as the pose
    refiner does) and answers each ``verify_query`` addressed to it: for each candidate
    viewframe, the view at its place aligned with the camera image (by the memory's shift search
    over the scenario's ``memory.max_shift`` and by the skyline), and the camera image's
    memory-pattern correlation with it (:func:`models.verify.verify_candidates`, the patterns of
    the scenario's memory settings);
    posts a ``verification`` linked to the query and the camera frame.

    The candidate's own view (its viewframe's image and depth) is read from the map's viewframe
    cache entry when that entry holds what this verifier's emulator renders (as the refiner
    does), otherwise rendered. The camera frame's skyline profile is the skyline ranker's when
    it posted one. Options: the skyline matching settings ``step_deg``, ``max_heading_deg``,
    ``max_pitch_deg``, ``truncate_deg``; ``rolls_deg``, the rolls of the memory's alignment, and
    ``max_roll_deg``, the skyline alignment's roll bound (:func:`models.verify.verify_candidates`). Queries that arrive before the map wait.
    """

    consumes: ClassVar[tuple[str, ...]] = (levels.MAP, levels.VERIFY_QUERY)
    produces: ClassVar[tuple[str, ...]] = (levels.VERIFICATION,)
    exclusive: ClassVar[tuple[str, ...]] = (levels.VERIFICATION,)

    def __init__(
        self,
        name: str,
        *,
        step_deg: float,
        max_heading_deg: float,
        max_pitch_deg: float,
        truncate_deg: float,
        rolls_deg: list[float] | tuple[float, ...] = (0.0,),
        max_roll_deg: float = 0.0,
        **options: Any,
    ) -> None:
        super().__init__(name, **options)
        self.rolls_deg = tuple(float(a) for a in rolls_deg)
        self.max_roll_deg = float(max_roll_deg)
        self.match: dict[str, float] = {
            "step_deg": float(step_deg),
            "max_heading_deg": float(max_heading_deg),
            "max_pitch_deg": float(max_pitch_deg),
            "truncate_deg": float(truncate_deg),
        }
        #: the map's world, emulator and cache entry, once the map is posted
        self.views: MapViews | None = None
        self._waiting: list[Hypothesis] = []

    def precondition(self, event: Event) -> float | None:
        h = event.hypothesis
        if event.kind is not EventKind.POSTED:
            return None
        if h.level == levels.MAP:
            return 2.0
        return 1.0 if h.addressed_to == self.name else None

    def act(self, event: Event, board: Board) -> None:
        try:
            h = event.hypothesis
            if h.level == levels.MAP:
                self._open(levels.Map.from_hypothesis(h))
                waiting, self._waiting = self._waiting, []
                for q in waiting:
                    self._verify(q, board)
            elif self.views is None:
                self._waiting.append(h)
            else:
                self._verify(h, board)
        finally:
            if self.views is not None:
                self.views.release()

    def _open(self, mp: levels.Map) -> None:
        self.views = MapViews(mp)

    def _verify(self, hypothesis: Hypothesis, board: Board) -> None:
        from models.verify import verify_candidates

        assert self.views is not None
        query = levels.VerifyQuery.from_hypothesis(hypothesis)
        got = board.get(levels.frame_id(query.frame))
        if got is None:
            log.warning("%s: frame %d: camera frame not on the blackboard: not verified", self.name, query.frame)
            return
        image = levels.SensorFrame.from_hypothesis(got).image
        profile = skyline_profile(board, query.frame)
        mem = self.views.world.scenario.memory
        starts, views = [], []
        for vf in query.viewframes:
            start = self.views.start_pose(int(vf))
            starts.append(start)
            views.append(self.views.own_view(int(vf), start))
        r = verify_candidates(
            image,
            self.views.emulator,
            starts,
            pattern=self.views.pattern,
            start_views=views,
            query_skyline=profile,
            step_deg=self.match["step_deg"],
            max_heading_deg=self.match["max_heading_deg"],
            max_pitch_deg=self.match["max_pitch_deg"],
            truncate_deg=self.match["truncate_deg"],
            align_shift=mem.max_shift,
            rolls_deg=self.rolls_deg,
            max_roll_deg=self.max_roll_deg,
        )
        levels.post(
            board,
            levels.Verification(
                frame=query.frame,
                query=hypothesis.id,
                viewframes=[int(v) for v in query.viewframes],
                correlations=[float(c) for c in r.correlations],
                headings_deg=[float(h) for h in r.headings_deg],
                renders=int(r.renders),
            ),
            links=(hypothesis.id, got.id),
        )

    def shutdown(self) -> None:
        if self.views is not None:
            self.views.close()
            self.views = None
