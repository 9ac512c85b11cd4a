"""The camera: posts the mission's camera frames once the map is indexed."""

from __future__ import annotations

import logging
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
    ``scenario`` is posted, while the map is rendered or read and indexed; a camera that missed
    the scenario prepares them from the map's scenario path once the map is indexed.

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
        self._frames: list[Any] = []  # paced: the frames, posted one by one
        self._next = 0
        self._prepared: list[Any] | None = None  # the frames, prepared when the scenario was posted

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
            if self._prepared is None and not self._started:
                self._prepared = _frames_of(levels.Scenario.from_hypothesis(event.hypothesis).path)
                log.info("%s: %d camera frames prepared", self.name, len(self._prepared))
            return
        if event.hypothesis.level != levels.INDEX:  # paced: an answer; the next frame once it is the last posted's
            answered = int(event.hypothesis.body["frame"])
            if self._next < len(self._frames) and answered == self._frames[self._next - 1].index:
                self._post(self._frames[self._next], board)
                self._next += 1
            return
        index = levels.Index.from_hypothesis(event.hypothesis)
        self._ready.add(index.shard)
        if self._started or len(self._ready) < index.shards:
            return
        self._started = True
        frames, self._prepared = self._prepared, None
        if frames is None:  # the scenario's event missed (joined late): from the map's scenario path
            got = board.get(levels.map_id())
            if got is None:
                raise LookupError("the map is indexed but not on the blackboard")
            frames = _frames_of(levels.Map.from_hypothesis(got).path)
        if self.pace is not None:
            self._frames, self._next = list(frames), 1
            if frames:
                self._post(frames[0], board)
            log.info(
                "%s: posting %d camera frames, each after the %s of the one before", self.name, len(frames), self.pace
            )
            return
        start = time.perf_counter()
        for f in frames:
            if self.rate_hz is not None:
                delay = start + f.index / self.rate_hz - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)  # this agent's own worker thread: nothing else waits on it
            self._post(f, board)
        log.info("%s: posted %d camera frames", self.name, len(frames))

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


def _frames_of(path: str) -> list[Any]:
    """The camera frames of the scenario file ``path`` (:attr:`models.world.World.sensor_frames`),
    its renderer closed once they are made."""
    from models.world import World

    with World.from_scenario(path) as world:
        return list(world.sensor_frames)
