"""The associative indexer: one shard of the viewframes, ranking every camera frame."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from blackboard.hypothesis import Hypothesis
from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels

if TYPE_CHECKING:
    from models.index import TrackWindows, ViewframeIndex

__all__ = ["AssociativeIndexer"]

log = logging.getLogger(__name__)


class AssociativeIndexer(KnowledgeSource):
    """Stores the viewframes of its shard (``index // block == shard``, consecutive route points,
    or without ``block`` ``index % shards == shard``) in a
    :class:`~models.index.ViewframeIndex` (a banked holographic memory, ``memory.bank_size``
    viewframes per bank, with the scenario's preprocessing)
    and posts ``index`` once its shard is stored, then, for each camera frame, the ranking of
    those viewframes by error variance. The
    scheduler merges the rankings of all shards (variances are comparable across banks and shards).

    Options: ``shard`` (this shard, default 0), ``shards`` (number of shards, default 1),
    ``block`` (route points per shard, consecutive; a mission gives ``memory.shard_size``;
    default None: every ``shards``-th point), ``tracked`` (a tracker runs; default False).
    Consecutive blocks keep a track window on one or two shards: the others post an empty
    ranking without preprocessing the frame, so a windowed frame's cost does not grow with the
    number of shards. Memory parameters (size, edge method, blur, bank
    size, shift search, the track window) come from the scenario through the ``map`` hypothesis.
    Camera frames that arrive before the shard is stored wait; viewframes missed as events are
    read back from the blackboard, so an indexer that joins late or restarts still indexes
    everything.

    The track's neighbourhood: when ``tracked`` and the route has at least
    ``memory.window_route_points`` points, the ranking of frame t holds only the viewframes of
    :func:`models.index.TrackWindows` (the ``window_next`` of the track of frame t - 1, widened), when
    that track is on the blackboard as the frame is ranked and says ``tracking``; otherwise
    (no such track yet, the track ``lost``, every ``memory.window_full_every``-th frame, frame 0)
    the ranking holds every viewframe of the shard (see :class:`models.scenario.MemorySpec`).
    The indexer never waits for a track: a dead or late tracker costs the window, never a
    ranking. So which frames get the window depends on timing: frames paced as a camera's are
    ranked after the previous frame's track, frames posted in a burst mostly before it.
    """

    consumes: ClassVar[tuple[str, ...]] = (levels.VIEWFRAME, levels.MAP, levels.SENSOR_FRAME, levels.TRACK)
    produces: ClassVar[tuple[str, ...]] = (levels.RANKING, levels.INDEX)

    def __init__(
        self,
        name: str,
        *,
        shard: int = 0,
        shards: int = 1,
        block: int | None = None,
        tracked: bool = False,
        **options: Any,
    ) -> None:
        super().__init__(name, **options)
        if shards < 1 or not 0 <= shard < shards:
            raise ValueError(f"shard must be in [0, shards), got shard={shard}, shards={shards}")
        if block is not None and int(block) < 1:
            raise ValueError(f"block must be >= 1 or None, got {block}")
        self.shard = shard
        self.shards = shards
        self.block = None if block is None else int(block)
        self.tracked = bool(tracked)
        self._images: dict[int, np.ndarray] = {}
        self._index: ViewframeIndex | None = None
        self._waiting: list[Hypothesis] = []
        self._windows: TrackWindows | None = None  # the track window rule (set with the map)
        self._early: list[tuple[int, str, list | None]] = []  # tracks that came before the map
        #: per ranking posted: the frame and the (first, last) route points ranked, None: all
        self.windows: dict[int, tuple[int, int] | None] = {}

    def precondition(self, event: Event) -> float | None:
        if event.kind is not EventKind.POSTED:
            return None
        h = event.hypothesis
        if h.level == levels.VIEWFRAME and not self._mine(levels.Viewframe.from_hypothesis(h).index):
            return None
        if h.level == levels.TRACK and not self.tracked:
            return None
        return 2.0 if h.level != levels.SENSOR_FRAME else 1.0

    def act(self, event: Event, board: Board) -> None:
        h = event.hypothesis
        if h.level == levels.VIEWFRAME:
            if self._index is None:
                vf = levels.Viewframe.from_hypothesis(h)
                self._images[vf.index] = vf.image
        elif h.level == levels.MAP:
            self._build(levels.Map.from_hypothesis(h), board)
            waiting, self._waiting = self._waiting, []
            for frame in waiting:
                self._rank(frame, board)
        elif h.level == levels.SENSOR_FRAME:
            if self._index is None:
                self._waiting.append(h)
            else:
                self._rank(h, board)
        elif h.level == levels.TRACK:
            track = levels.Track.from_hypothesis(h)
            if self._windows is None:
                self._early.append((track.frame, track.state, track.window_next))
            else:
                self._windows.add(track.frame, track.state, track.window_next)

    def _mine(self, k: int) -> bool:
        """Viewframe ``k`` is of this shard."""
        if self.block is not None:
            return min(k // self.block, self.shards - 1) == self.shard
        return k % self.shards == self.shard

    def _build(self, mp: levels.Map, board: Board) -> None:
        from models.index import TrackWindows, ViewframeIndex

        mine = [k for k in range(mp.viewframes) if self._mine(k)]
        for k in mine:
            if k not in self._images:
                self._images[k] = levels.Viewframe.read(board, k).image
        index = ViewframeIndex(mp.memory, seed=self.shard)
        # each image is dropped as soon as it is made into a pattern: the images and the banks
        # are never all resident at once
        index.add((self._images.pop(k) for k in mine), mine)
        self._index = index
        self._windows = TrackWindows(index.settings, viewframes=mp.viewframes, tracked=self.tracked)
        for early in self._early:
            self._windows.add(*early)
        self._early.clear()
        self._images.clear()
        levels.post(
            board, levels.Index(shard=self.shard, shards=self.shards, viewframes=len(mine)), links=(levels.map_id(),)
        )
        log.info("%s: shard %d/%d holds %d viewframes", self.name, self.shard, self.shards, len(mine))

    def _rank(self, hypothesis: Hypothesis, board: Board) -> None:
        assert self._index is not None and self._windows is not None  # frames wait until the index is built
        frame = levels.SensorFrame.from_hypothesis(hypothesis)
        window = self._windows.window(frame.frame)
        among = None if window is None else np.arange(window[0], window[1] + 1)
        ranking = self._index.rank(frame.image, among=among)
        self.windows[frame.frame] = window
        levels.post(
            board,
            levels.Ranking.of(
                ranking,
                frame=frame.frame,
                frame_time=hypothesis.timestamp,
                shard=self.shard,
                shards=self.shards,
                time=frame.time,
            ),
            links=(hypothesis.id,),
            credibility=float(min(1.0, max(0.0, ranking.reliability / (1.0 + ranking.reliability)))),
        )
