"""The route ranker: the lifecycle shared by the agents that rank the route's viewframes for each camera frame."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, ClassVar

from blackboard.hypothesis import Hypothesis
from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels

if TYPE_CHECKING:
    import numpy as np

    from models.index import TrackWindows
    from models.scenario import MemorySpec

__all__ = ["RouteRanker"]

log = logging.getLogger(__name__)


class RouteRanker(KnowledgeSource):
    """Base of the knowledge sources that rank viewframes for every camera frame (the associative
    indexer, the skyline ranker). It keeps what each subclass needs of the viewframes as they are
    posted (:meth:`keep`), builds its model once the ``map`` is posted (:meth:`build`; viewframes
    missed as events are read back from the blackboard there), then ranks every camera frame
    (:meth:`rank`). Camera frames that arrive before the map wait and are ranked, in order, once it
    is built.

    The track's neighbourhood: with ``tracked`` (a tracker runs), the ``track`` hypotheses are
    collected, those that come before the map too, into the :class:`models.index.TrackWindows` rule
    (with the map's ``memory`` settings, the same in every ranker); :meth:`window` gives a frame's
    window (``(first, last)`` route points, or None: rank all) and records it in ``windows``. A
    ranker never waits for a track: a dead or late tracker costs the window, never a ranking; a
    track posted before the frame whose event comes after it is read from the blackboard
    (:meth:`_track_before`).

    What a ranker needs of the viewframes may come from the viewframe cache entry the ``map``
    names instead of their messages: with ``from_messages`` False it does not consume the
    viewframe level at all (not subscribed: on a long route its messages are most of what is
    posted, each ranker would otherwise receive and check every one); :meth:`from_messages_default`
    is the subclasses' default.

    Options: ``tracked`` (default False), ``from_messages`` (default True); the rest go to
    :class:`KnowledgeSource`.
    """

    consumes: ClassVar[tuple[str, ...]] = (levels.VIEWFRAME, levels.MAP, levels.SENSOR_FRAME, levels.TRACK)

    @staticmethod
    def from_messages_default(option: bool | None) -> bool:
        """Whether a ranker keeps what it needs of the viewframes from their messages: ``option``,
        or when None, only without a viewframe cache in this process (with one, the map will most
        likely name an entry to read them from: :func:`models.viewframe_cache.default_cache_root`)."""
        from models.viewframe_cache import default_cache_root

        return default_cache_root() is None if option is None else bool(option)

    def __init__(self, name: str, *, tracked: bool = False, from_messages: bool = True, **options: Any) -> None:
        super().__init__(name, **options)
        if not from_messages:
            self.consumes = tuple(lv for lv in type(self).consumes if lv != levels.VIEWFRAME)  # type: ignore[misc]
        self.tracked = bool(tracked)
        self._windows: TrackWindows | None = None  # the track window rule, set once the map is built
        self._route_points: np.ndarray | None = None  # the map's route point of each viewframe (None: the same)
        self._early: list[tuple[int, str, list | None]] = []  # tracks that came before the map
        self._waiting: list[Hypothesis] = []  # camera frames that came before the map
        #: per ranking posted: the frame and the (first, last) route points ranked, None: all
        self.windows: dict[int, tuple[int, int] | None] = {}

    def input_error(self, err: Exception) -> str | None:
        from models.errors import CacheEntryError

        # a viewframe's cache entry this host cannot read (another machine, a stale reference):
        # no retry helps, the run stops with the message naming the entry, viewframe and agent
        return str(err) if isinstance(err, CacheEntryError) else None

    # -- what a subclass provides ------------------------------------------------------------

    def mine(self, index: int) -> bool:
        """Viewframe ``index`` is one this ranker ranks (default: every one)."""
        return True

    def keep(self, viewframe: levels.Viewframe) -> None:
        """Keep what :meth:`build` needs of a viewframe posted before the map."""
        raise NotImplementedError

    def build(self, mp: levels.Map, board: Board) -> MemorySpec:
        """Build the model of the map's viewframes (those of :meth:`mine`); return the memory
        settings of the track window rule."""
        raise NotImplementedError

    def rank(self, hypothesis: Hypothesis, board: Board) -> None:
        """Rank the camera frame ``hypothesis`` (built: :meth:`window` gives its window) and post it."""
        raise NotImplementedError

    # -- the lifecycle -------------------------------------------------------------------------

    def wants(self, level: str, hypothesis_id: str) -> bool:
        """Viewframes of :meth:`mine` only, told by their id before they are decoded (a shard of a
        long route decodes its share of the viewframe messages, not all of them)."""
        if level != levels.VIEWFRAME:
            return True
        index = levels.viewframe_index(hypothesis_id)
        return index is None or self.mine(index)

    @property
    def built(self) -> bool:
        """The map has been built (camera frames are ranked as they come)."""
        return self._windows is not None

    def window(self, frame: int) -> tuple[int, int] | None:
        """The viewframes ``(first, last)`` to rank for ``frame`` (None: all): those of the route points
        of the track window rule; recorded in :attr:`windows`."""
        assert self._windows is not None, "window() before build()"
        window = self._windows.window(frame)
        if window is not None and self._route_points is not None:  # viewframes between the route points
            from models.route_views import views_of_points

            window = views_of_points(self._route_points, *window)
        self.windows[frame] = window
        return window

    def _track_before(self, frame: Hypothesis, board: Board) -> None:
        """When the camera ``frame``'s window needs the track of the frame before and its event has
        not come (a camera paced on the track posts a frame once that track is posted, but the two
        reach this ranker by different subscriptions: the frame may come first), read that track
        from the blackboard, once: one read, no waiting; not there, the frame is ranked in full as
        before. So a paced run's windows do not depend on which message came first."""
        windows, k = self._windows, int(frame.body["frame"])
        if windows is None or not windows.enabled or k <= 0 or k % windows.full_every == 0:
            return
        if windows.has(k - 1):  # the track of frame k - 1 is here (any state)
            return
        got = board.get(levels.track_id(k - 1))
        if got is not None:
            track = levels.Track.from_hypothesis(got)
            windows.add(track.frame, track.state, track.window_next)

    def precondition(self, event: Event) -> float | None:
        if event.kind is not EventKind.POSTED:
            return None
        h = event.hypothesis
        if h.level == levels.TRACK and not self.tracked:
            return None
        return 2.0 if h.level != levels.SENSOR_FRAME else 1.0

    def act(self, event: Event, board: Board) -> None:
        from models.index import TrackWindows

        h = event.hypothesis
        if h.level == levels.VIEWFRAME:  # wants() declined the others by id; an id it cannot read is checked here
            if not self.built:
                vf = levels.Viewframe.from_hypothesis(h)
                if self.mine(vf.index):
                    self.keep(vf)
        elif h.level == levels.MAP:
            mp = levels.Map.from_hypothesis(h)
            settings = self.build(mp, board)
            # the rule works in route points (the tracks' unit); window() gives their viewframes
            self._windows = TrackWindows(settings, viewframes=len(mp.route), tracked=self.tracked)
            self._route_points = mp.route_points
            for early in self._early:
                self._windows.add(*early)
            self._early.clear()
            waiting, self._waiting = self._waiting, []
            for frame in waiting:
                self._track_before(frame, board)
                self.rank(frame, board)
        elif h.level == levels.SENSOR_FRAME:
            if self.built:
                self._track_before(h, board)
                self.rank(h, board)
            else:
                self._waiting.append(h)
        elif h.level == levels.TRACK:
            track = levels.Track.from_hypothesis(h)
            if self._windows is None:
                self._early.append((track.frame, track.state, track.window_next))
            else:
                self._windows.add(track.frame, track.state, track.window_next)
