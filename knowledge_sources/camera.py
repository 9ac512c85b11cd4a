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


class Camera(KnowledgeSource):
    """Reads the scenario's camera images, or simulates them along the route, and posts each on
    ``sensor_frame``, all at once or paced at ``rate_hz``. The true pose, when known, goes to the separate ``truth`` level, which no
    agent consumes: it is there for evaluation only. The mission starts when every associative
    indexer shard has posted ``index`` (the vehicle drives once its map is prepared), so no frame
    waits for a memory still being built.
    """

    consumes: ClassVar[tuple[str, ...]] = (levels.INDEX,)
    produces: ClassVar[tuple[str, ...]] = (levels.SENSOR_FRAME, levels.TRUTH)
    exclusive: ClassVar[tuple[str, ...]] = (levels.SENSOR_FRAME, levels.TRUTH)

    def __init__(self, name: str, *, rate_hz: float | None = None, **options: Any) -> None:
        """``rate_hz``: post frames at this rate, as a camera would (default: all at once)."""
        super().__init__(name, **options)
        if rate_hz is not None and not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.rate_hz = rate_hz
        self._ready: set[int] = set()
        self._started = False

    def precondition(self, event: Event) -> float | None:
        return 1.0 if event.kind is EventKind.POSTED else None

    def input_error(self, err: Exception) -> str | None:
        return input_error_message(err)  # the scenario's files: the run stops with their error

    def act(self, event: Event, board: Board) -> None:
        from models.world import World

        index = levels.Index.from_hypothesis(event.hypothesis)
        self._ready.add(index.shard)
        if self._started or len(self._ready) < index.shards:
            return
        self._started = True
        got = board.get(levels.map_id())
        if got is None:
            raise LookupError("the map is indexed but not on the blackboard")
        with World.from_scenario(levels.Map.from_hypothesis(got).path) as world:
            frames = world.sensor_frames
        start = time.perf_counter()
        for f in frames:
            if self.rate_hz is not None:
                delay = start + f.index / self.rate_hz - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)  # this agent's own worker thread: nothing else waits on it
            posted = levels.post(
                board,
                levels.SensorFrame(frame=f.index, image=f.image, source=f.source, time=f.time),
                links=(levels.map_id(),),
            )
            if f.truth is not None:
                levels.post(board, levels.Truth(frame=f.index, pose=list(f.truth)), links=(posted.id,))
        log.info("%s: posted %d camera frames", self.name, len(frames))
