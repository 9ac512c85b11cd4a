"""The camera: posts the mission's camera frames once the map is indexed."""

from __future__ import annotations

import logging
import threading
import time
from typing import Any, ClassVar

from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels
from knowledge_sources.errors import input_error_message

__all__ = ["Camera"]

log = logging.getLogger(__name__)


#: what a camera paced on answers waits for before posting the next frame
PACE_LEVELS = (levels.POSITION, levels.TRACK)


class Camera(KnowledgeSource):
    """Reads the scenario's camera images, or simulates them along the route, and posts each on
    ``sensor_frame``: all at once, at ``rate_hz`` (a camera's fixed rate), or paced on answers
    (``pace``: the next frame once the previous frame's ``position``, or its ``track``, is
    posted: the system's capacity with every frame's predecessor answered, so the tracker and
    the indexers' track window apply to every frame). The true pose, when known, goes to the
    separate ``truth`` level, which no agent consumes: it is there for evaluation only. The
    mission starts when every associative indexer shard has posted ``index`` (the vehicle
    drives once its map is prepared), so no frame waits for a memory still being built. The
    frames are prepared (read, or simulated with the camera's own renderer) as soon as the
    ``scenario`` is posted, while the map is rendered or read and indexed, by a thread of the
    camera's own that makes them one by one: the first frame is posted once it is made and the
    map is up, the next ones as they are made (paced, each still after its predecessor's
    answer), so the mission does not wait for the last simulated frame (an error making them
    stops the run when the frames are wanted). A camera that missed the scenario prepares them
    from the map's scenario path once the map is indexed.

    Paced on ``track``, a tracker that never answers a frame stops the camera there: the run
    then ends at quiescence with the later frames reported as never posted.
    """

    consumes: ClassVar[tuple[str, ...]] = (levels.SCENARIO, levels.INDEX, *PACE_LEVELS)
    produces: ClassVar[tuple[str, ...]] = (levels.SENSOR_FRAME, levels.TRUTH)
    exclusive: ClassVar[tuple[str, ...]] = (levels.SENSOR_FRAME, levels.TRUTH)

    def __init__(self, name: str, *, rate_hz: float | None = None, pace: str | None = None, **options: Any) -> None:
        """``rate_hz``: post frames at this rate, as a camera would; ``pace``: ``"position"`` or
        ``"track"``, post each frame once that level's hypothesis of the frame before is posted
        (default, neither: all at once)."""
        super().__init__(name, **options)
        if rate_hz is not None and not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        if pace is not None and pace not in PACE_LEVELS:
            raise ValueError(f"pace must be one of {', '.join(PACE_LEVELS)} or None, got {pace!r}")
        if pace is not None and rate_hz is not None:
            raise ValueError("give rate_hz or pace, not both")
        self.rate_hz = rate_hz
        self.pace = pace
        self._ready: set[int] = set()
        self._started = False
        self._frames: _Frames | None = None  # the frames, made when the scenario was posted (or at the index)
        self._next = 0  # paced: the next frame to post

    def precondition(self, event: Event) -> float | None:
        if event.kind is not EventKind.POSTED:
            return None
        level = event.hypothesis.level
        if level in (levels.SCENARIO, levels.INDEX) or (self.pace is not None and level == self.pace):
            return 1.0
        return None

    def input_error(self, err: Exception) -> str | None:
        return input_error_message(err)  # the scenario's files: the run stops with their error

    def act(self, event: Event, board: Board) -> None:
        if event.hypothesis.level == levels.SCENARIO:
            if self._frames is None and not self._started:
                self._frames = _Frames(levels.Scenario.from_hypothesis(event.hypothesis).path, name=self.name)
            return
        if event.hypothesis.level != levels.INDEX:  # paced: an answer; the next frame once it is the last posted's
            answered = int(event.hypothesis.body["frame"])
            if self._frames is None or self._next == 0:
                return
            last = self._frames.get(self._next - 1)
            if last is not None and answered == last.index:
                f = self._frames.get(self._next)
                if f is not None:
                    self._post(f, board)
                    self._next += 1
            return
        index = levels.Index.from_hypothesis(event.hypothesis)
        self._ready.add(index.shard)
        if self._started or len(self._ready) < index.shards:
            return
        self._started = True
        if self._frames is None:  # the scenario's event missed (joined late): from the map's scenario path
            got = board.get(levels.map_id())
            if got is None:
                raise LookupError("the map is indexed but not on the blackboard")
            self._frames = _Frames(levels.Map.from_hypothesis(got).path, name=self.name)
        frames = self._frames
        if self.pace is not None:
            first = frames.get(0)
            if first is not None:
                self._post(first, board)
                self._next = 1
            log.info("%s: posting the camera frames, each after the %s of the one before", self.name, self.pace)
            return
        start = time.perf_counter()
        k = 0
        while (f := frames.get(k)) is not None:
            if self.rate_hz is not None:
                delay = start + f.index / self.rate_hz - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)  # this agent's own worker thread: nothing else waits on it
            self._post(f, board)
            k += 1
        log.info("%s: posted %d camera frames", self.name, k)

    def shutdown(self) -> None:
        if self._frames is not None:
            self._frames.stop()
        super().shutdown()

    def _post(self, f: Any, board: Board) -> None:
        """Post one camera frame (a :class:`models.sensor.SensorFrame`) and its truth."""
        posted = levels.post(
            board,
            levels.SensorFrame(
                frame=f.index,
                image=f.image,
                source=f.source,
                time=f.time,
                columns=None if f.columns is None else list(f.columns),
            ),
            links=(levels.map_id(),),
        )
        if f.truth is not None:
            levels.post(board, levels.Truth(frame=f.index, pose=list(f.truth)), links=(posted.id,))


class _Frames:
    """The camera frames of the scenario file ``path`` (:meth:`models.world.World.iter_sensor_frames`),
    made one by one by a thread of their own (its world, and its renderer, made, used and closed
    there) from construction on; :meth:`get` waits for a frame."""

    def __init__(self, path: str, *, name: str) -> None:
        self._made: list[Any] = []
        self._done = False
        self._error: Exception | None = None
        self._stop = threading.Event()
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._make, args=(path, name), name=f"{name}-frames", daemon=True)
        self._thread.start()

    def _make(self, path: str, name: str) -> None:
        from models.world import World

        try:
            with World.from_scenario(path) as world:
                for f in world.iter_sensor_frames():
                    with self._cond:
                        self._made.append(f)
                        self._cond.notify_all()
                    if self._stop.is_set():
                        return
            log.info("%s: %d camera frames prepared", name, len(self._made))
        except Exception as err:  # noqa: BLE001 - given to the agent, which raises it (get)
            self._error = err
        finally:
            with self._cond:
                self._done = True
                self._cond.notify_all()

    def get(self, k: int) -> Any | None:
        """Frame ``k`` (a :class:`models.sensor.SensorFrame`) once made; None when there are not that
        many; the error that stopped making them, raised here."""
        with self._cond:
            while len(self._made) <= k and not self._done:
                self._cond.wait()
            if k < len(self._made):
                return self._made[k]
            if self._error is not None:
                raise self._error
            return None

    def stop(self) -> None:
        """Stop making frames (after the one being made)."""
        self._stop.set()
