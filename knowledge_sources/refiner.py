"""The pose refiner: after a decision, the camera's pose between route points, and its heading."""

from __future__ import annotations

import logging
from typing import Any, ClassVar

from blackboard.hypothesis import Hypothesis
from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels
from knowledge_sources.map_views import MapViews, skyline_profile
from models.scenario import RefineSpec

__all__ = ["PoseRefiner"]

log = logging.getLogger(__name__)


class PoseRefiner(KnowledgeSource):
    """Owns a camera emulator of the map (it loads the scenario the ``map`` names, as the map
    renderer does) and, for every ``position`` with a viewframe, refines the pose from that
    viewframe's route point against the frame's camera image (:func:`models.refine.refine_pose`:
    heading and pitch from the skyline shift, then position along and across the route by
    rendering views around the point, coarse to fine). Posts a ``pose`` linked to the position
    and the camera frame; the results' ``position`` and ``heading_deg`` are the pose's.

    The view at the chosen viewframe's pose is the viewframe's own: when the ``map`` names a
    viewframe cache entry that holds what this refiner's emulator renders (the entry's name is
    the refiner's world's cache key, :meth:`models.world.World.renders_entry`), its image and
    depth are read from the entry instead of rendered again (the same pixels); otherwise rendered.

    Options (the scenario's ``refine`` block and skyline matching settings): ``along_m``,
    ``across_m``, ``levels``, ``grid``, ``edge_weight``, ``step_deg``, ``max_heading_deg``,
    ``max_pitch_deg``, ``truncate_deg``, ``max_roll_deg``, ``position`` (search the position too,
    or refine heading and pitch only), ``recheck`` (score the heading and pitch found again in a
    view rendered at them), ``memory_heading`` (where the skyline's match is not trusted, the
    heading and pitch from the memory's alignment of the camera image with the view, with the
    patterns, shift window and rolls of the scenario's ``memory`` block: :func:`models.refine.refine_pose`'s
    ``pattern``). Positions that arrive before the map wait.
    """

    consumes: ClassVar[tuple[str, ...]] = (levels.MAP, levels.POSITION)
    produces: ClassVar[tuple[str, ...]] = (levels.POSE,)
    exclusive: ClassVar[tuple[str, ...]] = (levels.POSE,)

    def __init__(
        self,
        name: str,
        *,
        along_m: float,
        across_m: float,
        levels: int,
        grid: int,
        edge_weight: float,
        step_deg: float,
        max_heading_deg: float,
        max_pitch_deg: float,
        truncate_deg: float,
        max_roll_deg: float = RefineSpec().max_roll_deg,
        position: bool,
        recheck: bool = RefineSpec().recheck,
        memory_heading: bool = RefineSpec().memory_heading,
        **options: Any,
    ) -> None:
        super().__init__(name, **options)
        if int(levels) < 1 or int(grid) < 2 or float(along_m) < 0 or float(across_m) < 0:
            raise ValueError(
                f"refiner options out of range: levels={levels}, grid={grid}, along_m={along_m}, across_m={across_m}"
            )
        self.search: dict[str, Any] = {
            "along_m": float(along_m),
            "across_m": float(across_m),
            "levels": int(levels),
            "grid": int(grid),
            "edge_weight": float(edge_weight),
            "step_deg": float(step_deg),
            "max_heading_deg": float(max_heading_deg),
            "max_pitch_deg": float(max_pitch_deg),
            "truncate_deg": float(truncate_deg),
            "max_roll_deg": float(max_roll_deg),
            "position": bool(position),
            "recheck": bool(recheck),
        }
        self.memory_heading = bool(memory_heading)
        #: the map's world, emulator and cache entry, once the map is posted
        self.views: MapViews | None = None
        self._waiting: list[Hypothesis] = []

    def precondition(self, event: Event) -> float | None:
        if event.kind is not EventKind.POSTED:
            return None
        return 2.0 if event.hypothesis.level == levels.MAP else 1.0

    def act(self, event: Event, board: Board) -> None:
        try:
            self._act(event, board)
        finally:
            if self.views is not None:
                self.views.release()

    def _act(self, event: Event, board: Board) -> None:
        h = event.hypothesis
        if h.level == levels.MAP:
            self._open(levels.Map.from_hypothesis(h))
            waiting, self._waiting = self._waiting, []
            for pos in waiting:
                self._refine(pos, board)
        elif h.level == levels.POSITION:
            if self.views is None:
                self._waiting.append(h)
            else:
                self._refine(h, board)

    def _open(self, mp: levels.Map) -> None:
        self.views = MapViews(mp)

    def _refine(self, hypothesis: Hypothesis, board: Board) -> None:
        from models.refine import refine_pose

        assert self.views is not None
        position = levels.Position.from_hypothesis(hypothesis)
        if position.viewframe is None:
            return
        got = board.get(levels.frame_id(position.frame))
        if got is None:
            log.warning("%s: frame %d: camera frame not on the blackboard: not refined", self.name, position.frame)
            return
        image = levels.SensorFrame.from_hypothesis(got).image
        start = self.views.start_pose(position.viewframe)
        memory: dict[str, Any] = {}
        if self.memory_heading:
            mem = self.views.world.scenario.memory
            memory = {"pattern": self.views.pattern, "rolls_deg": mem.roll_search_deg, "align_shift": mem.max_shift}
        r = refine_pose(
            image,
            self.views.emulator,
            start,
            query_skyline=skyline_profile(board, position.frame),
            start_view=self.views.own_view(position.viewframe, start),
            **self.search,
            **memory,
        )
        levels.post(
            board,
            levels.Pose(
                frame=position.frame,
                position=hypothesis.id,
                viewframe=position.viewframe,
                x=r.x,
                y=r.y,
                heading_deg=r.heading_deg,
                pitch_deg=r.pitch_deg,
                sigma_along_m=r.sigma_along_m,
                sigma_across_m=r.sigma_across_m,
                sigma_heading_deg=r.sigma_heading_deg,
                score=r.score,
                start_score=r.start_score,
                renders=r.renders,
                route_position=[start.x, start.y],
                route_heading_deg=start.heading_deg,
            ),
            links=(hypothesis.id, got.id),
            credibility=hypothesis.credibility,
        )

    def shutdown(self) -> None:
        if self.views is not None:
            self.views.close()
            self.views = None
