"""The associative indexer: one shard of the viewframes, ranking every camera frame."""

from __future__ import annotations

import logging
import os
import threading
import zlib
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from blackboard.hypothesis import Hypothesis
from blackboard.knowledge_source import Board
from knowledge_sources import levels
from knowledge_sources.ranker import RouteRanker

if TYPE_CHECKING:
    from models.associative import Ranking
    from models.coarse import MemoryCoarse
    from models.index import ViewframeIndex
    from models.scenario import MemorySpec

__all__ = ["AssociativeIndexer", "MAPPED_RANKINGS"]

log = logging.getLogger(__name__)

#: shards of one process ranking at once (their stored, memory-mapped rows, or the coarse stage's
#: candidates): one per core, as many as can compute at once (AssociativeIndexer._ranked and
#: _coarse_ranked)
MAPPED_RANKINGS = max(2, os.cpu_count() or 1)
_MAPPED = threading.BoundedSemaphore(MAPPED_RANKINGS)


class AssociativeIndexer(RouteRanker):
    """Stores the viewframes of its shard (``index // block == shard``, consecutive route points,
    or without ``block`` ``index % shards == shard``) in a
    :class:`~models.index.ViewframeIndex` (a banked holographic memory, ``memory.bank_size``
    viewframes per bank, with the scenario's preprocessing)
    and posts ``index`` once its shard is stored, then, for each camera frame, the ranking of
    those viewframes by error variance. The
    scheduler merges the rankings of all shards (variances are comparable across banks and shards).

    Options: ``shard`` (this shard, default 0), ``shards`` (number of shards, default 1),
    ``block`` (route points per shard, consecutive; a mission gives ``memory.shard_size``;
    default None: every ``shards``-th point), ``tracked`` (a tracker runs; default False),
    ``keep_images`` (see below; default None: decided from this process's viewframe cache).

    A stored index: when the ``map`` names the viewframe cache entry its viewframes came from
    (``entry``), the shard's index is stored beside it and a later run of the same map loads it,
    memory-mapped, instead of indexing (:func:`models.index_store.cached_index`; any change of
    the memory settings, of the shard's viewframes or of the code that builds it is a miss). The
    images are then never needed: with ``keep_images`` False this indexer does not consume the
    viewframe level at all (not subscribed: no message of it is received), and on a miss the
    images are read from the cache entry (memory-mapped), or back from the blackboard when the
    entry cannot be read here. With
    ``keep_images`` True each image is kept (zlib-compressed) as its message arrives, the
    cheaper path without a cache. The default is False when a viewframe cache is on in this
    process (:func:`models.viewframe_cache.default_cache_root`; the map will most likely name an
    entry), True when it is off (``--no-cache``, ``MAPINTERP_CACHE=off``).

    Consecutive blocks keep a track window on one or two shards: the others post an empty
    ranking without preprocessing the frame, so a windowed frame's cost does not grow with the
    number of shards. Memory parameters (size, edge method, blur, bank
    size, shift search, the track window) come from the scenario through the ``map`` hypothesis.
    Camera frames that arrive before the shard is stored wait; viewframes missed as events are
    read back from the blackboard, so an indexer that joins late or restarts still indexes
    everything (the lifecycle of :class:`~knowledge_sources.ranker.RouteRanker`).

    The track's neighbourhood: when ``tracked`` and the route has at least
    ``memory.window_route_points`` points, the ranking of frame t holds only the viewframes of
    :func:`models.index.TrackWindows` (the ``window_next`` of the track of frame t - 1, widened), when
    that track is on the blackboard as the frame is ranked and says ``tracking``; otherwise
    (no such track yet, the track ``lost``, every ``memory.window_full_every``-th frame, frame 0)
    the ranking holds every viewframe of the shard (see :class:`models.scenario.MemorySpec`).
    The indexer never waits for a track: a dead or late tracker costs the window, never a
    ranking. So which frames get the window depends on timing: frames paced as a camera's are
    ranked after the previous frame's track, frames posted in a burst mostly before it.

    The coarse stage: a frame ranked in full (no window) is first compared with every viewframe of
    the shard by :class:`models.coarse.MemoryCoarse` (the memory's low-passed similarity on a
    truncated spectrum at a grid of lags, its rows made once as the index is built or loaded:
    6.2 KB a viewframe),
    and only the ``memory.coarse_candidates`` best are ranked (``among`` them); the ranking holds
    those. A shard holding no more viewframes than that, or ``coarse_candidates`` null, ranks
    every one.
    """

    produces: ClassVar[tuple[str, ...]] = (levels.RANKING, levels.INDEX)

    def __init__(
        self,
        name: str,
        *,
        shard: int = 0,
        shards: int = 1,
        block: int | None = None,
        tracked: bool = False,
        keep_images: bool | None = None,
        **options: Any,
    ) -> None:
        keep = self.from_messages_default(keep_images)
        super().__init__(name, tracked=tracked, from_messages=keep, **options)
        if shards < 1 or not 0 <= shard < shards:
            raise ValueError(f"shard must be in [0, shards), got shard={shard}, shards={shards}")
        if block is not None and int(block) < 1:
            raise ValueError(f"block must be >= 1 or None, got {block}")
        self.shard = shard
        self.shards = shards
        self.block = None if block is None else int(block)
        # the shard's viewframe images until the map is complete: inline ones zlib-compressed (a
        # long route's images would otherwise be resident at once: about 57 KB each at 160 x 120),
        # by reference where they are (read from the cache entry as they are indexed)
        self._images: dict[int, tuple[bytes, tuple[int, ...], str] | levels.PixelsRef] = {}
        self._index: ViewframeIndex | None = None
        #: the images are kept as their messages arrive (else, on a miss, read from the map's cache
        #: entry, or back from the board)
        self.keep_images = keep
        #: the shard's index was loaded from a stored copy (set by build)
        self.loaded = False
        self._held: np.ndarray | None = None  # the viewframes the index holds, sorted (set by build)
        self._coarse: MemoryCoarse | None = None  # the coarse stage (set by build; None: every frame in full)
        self._coarse_k = 0

    def mine(self, index: int) -> bool:
        """Viewframe ``index`` is of this shard."""
        if self.block is not None:
            return min(index // self.block, self.shards - 1) == self.shard
        return index % self.shards == self.shard

    def keep(self, viewframe: levels.Viewframe) -> None:
        if not self.keep_images:
            return  # decided on the map: a stored index needs none, a miss reads them from the entry
        ref = viewframe.reference()
        if ref is not None:  # by reference to a cache entry: where its pixels are, read as they are indexed
            self._images[viewframe.index] = ref
            return
        image = np.ascontiguousarray(viewframe.pixels(agent=self.name).image)
        self._images[viewframe.index] = (zlib.compress(image.data, 1), image.shape, image.dtype.str)

    def _image(self, k: int) -> np.ndarray:
        kept = self._images.pop(k)
        if isinstance(kept, levels.PixelsRef):
            return kept.pixels(agent=self.name).image
        data, shape, dtype = kept
        return np.frombuffer(zlib.decompress(data), dtype=dtype).reshape(shape)

    def build(self, mp: levels.Map, board: Board) -> MemorySpec:
        from models.index_store import cached_index
        from models.viewframe_cache import entry_field, release_behind

        mine = [k for k in range(mp.viewframes) if self.mine(k)]

        def images() -> Iterator[np.ndarray]:
            # a miss: each image is decompressed (or read) as it is made into a pattern and
            # dropped: the images and the banks are never all resident at once
            if self.keep_images:  # the images missed as events, read back first (a missing one fails early)
                for k in mine:
                    if k not in self._images:
                        self.keep(levels.Viewframe.read(board, k))
                for k in mine:
                    yield self._image(k)
                return
            # not kept: from the map's cache entry (memory-mapped, its pages given back batch by
            # batch), else read back from the board
            stacked = None if mp.entry is None else entry_field(mp.entry, "image", count=mp.viewframes)
            for i, k in enumerate(mine):
                if stacked is None:  # by reference too, it names the entry this host cannot read: the error says so
                    yield levels.Viewframe.read(board, k).pixels(agent=self.name).image
                    continue
                yield np.asarray(stacked[k])
                release_behind(i, mine, lambda j: (stacked[j],))

        index, self.loaded = cached_index(mp.entry, mp.memory, mine, seed=self.shard, images=images)
        self._index = index
        self._held = np.sort(index.viewframes)
        self._images.clear()
        self._build_coarse(index)
        stored = len(mine) - len(index.featureless)
        levels.post(
            board,
            levels.Index(shard=self.shard, shards=self.shards, viewframes=stored, featureless=list(index.featureless)),
            links=(levels.map_id(),),
        )
        log.info(
            "%s: shard %d/%d holds %d viewframes (%s)",
            self.name,
            self.shard,
            self.shards,
            stored,
            "a stored index" if self.loaded else "indexed",
        )
        if index.featureless:
            log.warning(
                "%s: %d featureless viewframes not stored (never ranked by the memory): %s",
                self.name,
                len(index.featureless),
                index.featureless[:20],
            )
        return index.settings

    def _build_coarse(self, index: ViewframeIndex) -> None:
        """The coarse stage's rows, when ``memory.coarse_candidates`` is fewer than the shard holds;
        a stored index's rows are read once for them (while at most :data:`MAPPED_RANKINGS` shards
        of this process map theirs, then given back, as after a ranking)."""
        from models.coarse import MemoryCoarse

        k = index.settings.coarse_candidates
        self._coarse, self._coarse_k = None, 0
        if k is None or len(index) <= k:
            return
        if self.loaded:
            with _MAPPED:
                try:
                    self._coarse = MemoryCoarse(index.memory)
                finally:
                    self._release_rows()
        else:
            self._coarse = MemoryCoarse(index.memory)
        self._coarse_k = int(k)

    def _release_rows(self) -> None:
        """A stored index's ranking rows are memory-mapped from its file: the pages a ranking read
        are given back to the page cache (``MADV_DONTNEED``: the next ranking maps them again from
        it, without reading the disk), else every shard's rows stay resident in this process after
        its first full ranking (665 MB at 10,000 viewframes, counted in the process's RSS)."""
        import mmap

        from models.viewframe_cache import release_pages

        assert self._index is not None
        release_pages([self._index.memory.ranking_matrix], advice=mmap.MADV_DONTNEED)

    def _ranked(self, image: np.ndarray, among: np.ndarray | None) -> Ranking:
        """The index's ranking of ``image`` (among those viewframes, None: all). A stored (loaded)
        index ranks while at most :data:`MAPPED_RANKINGS` shards of this process do (each maps
        its ranking rows, 33 MB a shard of 512 viewframes, until it gives them back: 20 shards
        ranking a camera frame at once held 665 MB of the entry's pages in the process's RSS),
        then gives its rows back (:meth:`_release_rows`)."""
        assert self._index is not None
        if not self.loaded:
            return self._index.rank(image, among=among)
        with _MAPPED:
            try:
                return self._index.rank(image, among=among)
            finally:
                self._release_rows()

    def _coarse_ranked(self, image: np.ndarray) -> Ranking:
        """The ranking of ``image`` among the coarse stage's candidates: the frame's pattern and key
        (made once for the shards of this process, :mod:`models.query_patterns`), the coarse rows
        (in memory) give the ``coarse_candidates`` best, and only their ranking rows are read
        (with the roll search, for each turned query); a stored index's pages are given back
        after. While at most :data:`MAPPED_RANKINGS` shards of this process do: with the roll
        search a shard's ranking holds about 10 MB at once (its candidates' rows, and for each
        turned query their products and inverse FFTs), and 20 shards ranking a frame at once
        held 440 MB over the idle level against 166 MB two at a time, in the same time on 2 cores
        (BENCHMARKS.md, "Session 11: the roll search's cost at 10,000 viewframes")."""
        assert self._index is not None and self._coarse is not None
        with _MAPPED:
            among = self._coarse.candidates(self._index.query_key(image), k=self._coarse_k)
            try:  # the candidates ranked with the roll search (memory.roll_search_deg), the patterns not made again
                return self._index.rank(image, among=among)
            finally:
                if self.loaded:
                    self._release_rows()

    def holds_any(self, window: tuple[int, int]) -> bool:
        """The index holds a viewframe of ``window`` (``(first, last)`` viewframes, inclusive)."""
        assert self._held is not None
        return bool(np.searchsorted(self._held, window[1], side="right") > np.searchsorted(self._held, window[0]))

    def rank(self, hypothesis: Hypothesis, board: Board) -> None:
        from models.associative import merge_rankings

        assert self._index is not None  # frames wait until the index is built
        frame = levels.SensorFrame.from_hypothesis(hypothesis)
        window = self.window(frame.frame)
        if window is not None and not self.holds_any(window):
            # outside the track window: the empty ranking at once, not waiting for the stored
            # shards' turn (:data:`MAPPED_RANKINGS`) nor mapping rows: on a long route most shards are here
            ranking = merge_rankings([])
        elif window is None and self._coarse is not None:
            ranking = self._coarse_ranked(frame.image)
        else:
            ranking = self._ranked(frame.image, None if window is None else np.arange(window[0], window[1] + 1))
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
