"""The verifier: render-and-compare scores of a frame's first candidates, before the scene analysis."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from blackboard.hypothesis import Hypothesis
from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels

if TYPE_CHECKING:
    from models.camera_emulator import CameraEmulator, View
    from models.world import World

__all__ = ["Verifier"]

log = logging.getLogger(__name__)


class Verifier(KnowledgeSource):
    """Owns a camera emulator of the map (it loads the scenario the ``map`` names, as the pose
    refiner does) and answers each ``verify_query`` addressed to it: for each candidate
    viewframe, the view at its place aligned with the camera image by the skyline's heading and
    pitch, and the camera image's memory-pattern correlation with it
    (:func:`models.verify.verify_candidates`, the patterns of the scenario's memory settings);
    posts a ``verification`` linked to the query and the camera frame.

    The candidate's own view (its viewframe's image and depth) is read from the map's viewframe
    cache entry when that entry holds what this verifier's emulator renders (as the refiner
    does), otherwise rendered. The camera frame's skyline profile is the skyline ranker's when
    it posted one. Options: the skyline matching settings ``step_deg``, ``max_heading_deg``,
    ``max_pitch_deg``, ``truncate_deg``; ``rolls_deg``, the rolls the camera image is also compared
    at, and ``max_roll_deg``, the skyline match's roll bound (:func:`models.verify.verify_candidates`). Queries that arrive before the map wait.
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
        self._world: World | None = None
        self._emulator: CameraEmulator | None = None
        self._map: levels.Map | None = None
        self._depths: np.ndarray | None = None
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
            elif self._emulator is None:
                self._waiting.append(h)
            else:
                self._verify(h, board)
        finally:
            if self._emulator is not None:
                self._emulator.release()

    def _open(self, mp: levels.Map) -> None:
        from models.viewframe_cache import entry_field
        from models.world import World

        self._world = World.from_scenario(mp.path)
        self._emulator = self._world.emulator
        self._map = mp
        if mp.entry is not None and self._world.renders_entry(mp.entry):
            depths = entry_field(mp.entry, "depth", count=mp.viewframes)
            if depths is not None and depths.ndim == 3:
                self._depths = depths

    def _own_view(self, viewframe: int, start: Any) -> View | None:
        """The candidate ``viewframe``'s own view from the map's cache entry, or None (rendered)."""
        import mmap

        from models.camera_emulator import View
        from models.viewframe_cache import read_pixels, release_pages

        if self._depths is None or self._map is None or self._map.entry is None:
            return None
        pixels = read_pixels(self._map.entry, viewframe, count=self._map.viewframes)
        depth = np.array(self._depths[viewframe], dtype=np.float32)
        release_pages([self._depths[viewframe]], advice=mmap.MADV_DONTNEED)
        return View(image=pixels.image, depth=depth, mask=pixels.mask.astype(np.int32), pose=start)

    def _verify(self, hypothesis: Hypothesis, board: Board) -> None:
        from knowledge_sources.skyline import SKYLINE_SOURCE
        from models.preprocess import preprocess
        from models.verify import verify_candidates

        assert self._emulator is not None and self._map is not None and self._world is not None
        query = levels.VerifyQuery.from_hypothesis(hypothesis)
        got = board.get(levels.frame_id(query.frame))
        if got is None:
            log.warning("%s: frame %d: camera frame not on the blackboard: not verified", self.name, query.frame)
            return
        image = levels.SensorFrame.from_hypothesis(got).image
        sky = board.get(levels.ranking_id(query.frame, 0, SKYLINE_SOURCE))
        profile = None if sky is None else levels.Ranking.from_hypothesis(sky).profile
        mem = self._world.scenario.memory
        starts, views = [], []
        for vf in query.viewframes:
            x, y, _, heading, pitch = self._map.pose(int(vf))
            start = self._emulator.pose_at(float(x), float(y), float(heading), pitch_deg=float(pitch))
            starts.append(start)
            views.append(self._own_view(int(vf), start))
        r = verify_candidates(
            image,
            self._emulator,
            starts,
            pattern=lambda im: preprocess(
                im, size=mem.size, edge=mem.edge, blur_sigma=mem.blur_sigma, whiten=mem.whiten
            ),
            start_views=views,
            query_skyline=profile,
            step_deg=self.match["step_deg"],
            max_heading_deg=self.match["max_heading_deg"],
            max_pitch_deg=self.match["max_pitch_deg"],
            truncate_deg=self.match["truncate_deg"],
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
        if self._world is not None:
            self._world.close()
            self._world, self._emulator = None, None
