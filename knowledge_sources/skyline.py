"""The skyline ranker: ranks every viewframe for each camera frame by the shape of its horizon."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from blackboard.hypothesis import Hypothesis
from blackboard.knowledge_source import Board
from knowledge_sources import levels
from knowledge_sources.ranker import RouteRanker
from models.scenario import SkylineSpec
from models.skyline import DEFAULT_MAX_ROLL_DEG, DEFAULT_ROLL_CANDIDATES

if TYPE_CHECKING:
    from models.scenario import MemorySpec
    from models.skyline_coarse import CoarseSkylines

__all__ = ["SkylineRanker", "SKYLINE_SOURCE"]

log = logging.getLogger(__name__)

#: the ``source`` of this agent's rankings
SKYLINE_SOURCE = "skyline"


class SkylineRanker(RouteRanker):
    """Keeps each viewframe's skyline (from the map renderer's depth buffer, carried by the
    ``viewframe`` hypothesis), extracts the skyline of every camera frame
    (:func:`models.skyline.skyline_from_image`), matches it with all of them over heading and
    pitch shifts (:func:`models.skyline.match_skylines`) and posts a ``ranking`` with
    ``source: "skyline"``: errors in degrees (truncated L1), and each viewframe's best
    ``[heading_deg, pitch_deg]`` shift. The scheduler fuses it with the associative rankings
    (:mod:`knowledge_sources.fusion`).

    Options (from the scenario's ``skyline`` block and camera): ``fov_y_deg``, ``step_deg``,
    ``max_heading_deg``, ``max_pitch_deg``, ``truncate_deg``, ``max_roll_deg``, ``roll_candidates``,
    ``coarse_candidates``; ``tracked`` (a tracker runs; default False); ``keep_profiles`` (see
    below; default None: decided from this process's viewframe cache). Camera frames that arrive
    before the map is complete wait; viewframes missed as events are read back from the blackboard.

    Where the skylines come from: when the ``map`` names the viewframe cache entry its viewframes
    came from, from the entry's stacked skylines (the same arrays the viewframe messages carry),
    and with ``keep_profiles`` False this ranker does not consume the viewframe level at all (as
    the associative indexers: no message of it is received, which on a long route is most of
    the messages posted); else from each viewframe message as it comes (``keep_profiles`` True,
    the default without a viewframe cache), or read back from the blackboard.

    The track's neighbourhood: when ``tracked``, the ranking of a frame holds the viewframes of
    the associative indexers' track window (the same rule, :class:`models.index.TrackWindows`,
    with the map's ``memory`` settings), so the two sources rank the same route points.

    The coarse stage: with ``coarse_candidates`` M (not None), the viewframes to rank (all, or
    the window's) are first compared coarsely (:mod:`models.skyline_coarse`) and only the M best
    are matched in full; the ranking holds those M, as a window's ranking holds the window's
    viewframes, and the fusion gives the others the skyline's largest evidence
    (:mod:`knowledge_sources.fusion`). Fewer viewframes than M, or None: all are matched in full.
    """

    produces: ClassVar[tuple[str, ...]] = (levels.RANKING,)

    def __init__(
        self,
        name: str,
        *,
        fov_y_deg: float,
        step_deg: float,
        max_heading_deg: float,
        max_pitch_deg: float,
        truncate_deg: float,
        max_roll_deg: float = DEFAULT_MAX_ROLL_DEG,
        roll_candidates: int | None = DEFAULT_ROLL_CANDIDATES,
        coarse_candidates: int | None = SkylineSpec().coarse_candidates,
        tracked: bool = False,
        keep_profiles: bool | None = None,
        **options: Any,
    ) -> None:
        keep = self.from_messages_default(keep_profiles)
        super().__init__(name, tracked=tracked, from_messages=keep, **options)
        if not 0 < float(fov_y_deg) < 180:
            raise ValueError(f"fov_y_deg must be in (0, 180), got {fov_y_deg}")
        if not float(step_deg) > 0 or not float(truncate_deg) > 0:
            raise ValueError(f"step_deg and truncate_deg must be > 0, got {step_deg}, {truncate_deg}")
        self.fov_y_deg = float(fov_y_deg)
        self.match = {
            "step_deg": float(step_deg),
            "max_heading_deg": float(max_heading_deg),
            "max_pitch_deg": float(max_pitch_deg),
            "truncate_deg": float(truncate_deg),
            "max_roll_deg": float(max_roll_deg),
        }
        if roll_candidates is not None and int(roll_candidates) < 1:
            raise ValueError(f"roll_candidates must be >= 1 or None, got {roll_candidates}")
        self.roll_candidates = None if roll_candidates is None else int(roll_candidates)
        if coarse_candidates is not None and int(coarse_candidates) < 1:
            raise ValueError(f"coarse_candidates must be >= 1 or None, got {coarse_candidates}")
        self.coarse_candidates = None if coarse_candidates is None else int(coarse_candidates)
        self._profiles: dict[int, np.ndarray] = {}
        self._refs: np.ndarray | None = None
        self._labels: np.ndarray | None = None
        self._coarse: CoarseSkylines | None = None
        #: the skylines are kept as their messages arrive (else read from the map's cache entry, or back from the board)
        self.keep_profiles = keep

    def keep(self, viewframe: levels.Viewframe) -> None:
        if self.keep_profiles:
            self._profiles[viewframe.index] = np.asarray(viewframe.skyline, dtype=np.float32)

    def build(self, mp: levels.Map, board: Board) -> MemorySpec:
        import mmap

        from models.index import memory_settings
        from models.viewframe_cache import entry_field, release_pages

        stacked = None if mp.entry is None else entry_field(mp.entry, "skyline", count=mp.viewframes)
        if stacked is not None and stacked.ndim == 2:  # every viewframe's skyline, row k: viewframe k
            self._labels = np.arange(mp.viewframes, dtype=np.int64)
            self._refs = np.array(stacked, dtype=np.float32)  # a copy: 460 bytes a viewframe at 115 bins
            release_pages([stacked], advice=mmap.MADV_DONTNEED)  # the entry's pages, read once
        else:
            for k in range(mp.viewframes):
                if k not in self._profiles:
                    self._profiles[k] = np.asarray(levels.Viewframe.read(board, k).skyline, dtype=np.float32)
            labels = sorted(self._profiles)
            sizes = {self._profiles[k].size for k in labels}
            if len(sizes) != 1:
                raise RuntimeError(f"{self.name}: viewframe skylines differ in length ({sorted(sizes)})")
            self._labels = np.asarray(labels, dtype=np.int64)
            self._refs = np.stack([self._profiles[k] for k in labels])
        self._profiles.clear()
        if self.coarse_candidates is not None and self.coarse_candidates < len(self._labels):
            from models.skyline_coarse import CoarseSkylines

            self._coarse = CoarseSkylines.prepare(self._refs)
        log.info("%s: %d viewframe skylines of %d bins", self.name, len(self._labels), self._refs.shape[1])
        return memory_settings(mp.memory)

    def rank(self, hypothesis: Hypothesis, board: Board) -> None:
        from models.associative import reliability
        from models.skyline import skyline_from_image
        from models.skyline_coarse import ranked_references

        assert self._refs is not None and self._labels is not None
        frame = levels.SensorFrame.from_hypothesis(hypothesis)
        query = skyline_from_image(
            frame.image, fov_y_deg=self.fov_y_deg, step_deg=self.match["step_deg"], columns=frame.columns
        )
        if query.size != self._refs.shape[1]:
            raise RuntimeError(
                f"{self.name}: frame {frame.frame}: camera skyline has {query.size} bins, "
                f"viewframes {self._refs.shape[1]} (another field of view?)"
            )
        window = self.window(frame.frame)
        refs, labels, coarse = self._refs, self._labels, self._coarse
        if window is not None:
            lo, hi = np.searchsorted(labels, window[0], side="left"), np.searchsorted(labels, window[1], side="right")
            refs, labels = refs[lo:hi], labels[lo:hi]
            coarse = None if coarse is None else coarse.rows(int(lo), int(hi))
        ranked, m = ranked_references(
            query, refs, coarse, candidates=self.coarse_candidates, roll_candidates=self.roll_candidates, **self.match
        )
        labels = labels[ranked]
        order = np.lexsort((labels, m.error))
        rel = reliability(m.error)
        levels.post(
            board,
            levels.Ranking(
                frame=frame.frame,
                frame_time=hypothesis.timestamp,
                shard=0,
                shards=1,
                viewframes=[int(k) for k in labels[order]],
                variances=[float(e) for e in m.error[order]],
                reliability=float(rel),
                source=SKYLINE_SOURCE,
                shifts=[[float(m.heading_deg[i]), float(m.pitch_deg[i])] for i in order],
                profile=np.asarray(query, dtype=np.float32),  # the refiner matches the same profile
            ),
            links=(hypothesis.id,),
            credibility=float(min(1.0, max(0.0, rel / (1.0 + rel)))),
        )
