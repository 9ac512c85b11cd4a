"""The associative indexer: one shard of the viewframes, ranking every camera frame."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels

if TYPE_CHECKING:
    from models.index import ViewframeIndex

__all__ = ["AssociativeIndexer"]

log = logging.getLogger(__name__)


class AssociativeIndexer(KnowledgeSource):
    """Stores the viewframes of its shard (``index % shards == shard``) in a
    :class:`~models.index.ViewframeIndex` (a banked holographic memory, ``memory.bank_size``
    viewframes per bank, with the scenario's preprocessing)
    and posts ``index`` once its shard is stored, then, for each camera frame, the ranking of
    those viewframes by error variance. The
    scheduler merges the rankings of all shards (variances are comparable across banks and shards).

    Options: ``shard`` (this shard, default 0), ``shards`` (number of shards, default 1). Memory
    parameters (size, edge method, blur, bank size, shift search) come from the scenario through
    the ``map`` hypothesis. Camera frames that
    arrive before the shard is stored wait; viewframes missed as events are read back from the
    blackboard, so an indexer that joins late or restarts still indexes everything.
    """

    consumes: ClassVar[tuple[str, ...]] = (levels.VIEWFRAME, levels.MAP, levels.SENSOR_FRAME)
    produces: ClassVar[tuple[str, ...]] = (levels.RANKING, levels.INDEX)

    def __init__(self, name: str, *, shard: int = 0, shards: int = 1, **options: Any) -> None:
        super().__init__(name, **options)
        if shards < 1 or not 0 <= shard < shards:
            raise ValueError(f"shard must be in [0, shards), got shard={shard}, shards={shards}")
        self.shard = shard
        self.shards = shards
        self._images: dict[int, np.ndarray] = {}
        self._index: ViewframeIndex | None = None
        self._waiting: list[Any] = []

    def precondition(self, event: Event) -> float | None:
        if event.kind is not EventKind.POSTED:
            return None
        h = event.hypothesis
        if h.level == levels.VIEWFRAME and h.body["index"] % self.shards != self.shard:
            return None
        return 2.0 if h.level != levels.SENSOR_FRAME else 1.0

    def act(self, event: Event, board: Board) -> None:
        h = event.hypothesis
        if h.level == levels.VIEWFRAME:
            if self._index is None:
                self._images[int(h.body["index"])] = h.body["image"]
        elif h.level == levels.MAP:
            self._build(h.body, board)
            waiting, self._waiting = self._waiting, []
            for frame in waiting:
                self._rank(frame, board)
        elif h.level == levels.SENSOR_FRAME:
            if self._index is None:
                self._waiting.append(h)
            else:
                self._rank(h, board)

    def _build(self, body: dict[str, Any], board: Board) -> None:
        from models.index import ViewframeIndex

        mine = [k for k in range(int(body["viewframes"])) if k % self.shards == self.shard]
        for k in mine:
            if k not in self._images:
                got = board.get(levels.viewframe_id(k))
                if got is None:
                    raise RuntimeError(f"viewframe {k} is on neither the event stream nor the blackboard")
                self._images[k] = got.body["image"]
        index = ViewframeIndex(body["memory"], seed=self.shard)
        index.add((self._images[k] for k in mine), mine)
        self._index = index
        self._images.clear()
        board.post(levels.INDEX, {"shard": self.shard, "shards": self.shards, "viewframes": len(mine)},
                   id=f"index-{self.shard}", links=("map",))
        log.info("%s: shard %d/%d holds %d viewframes", self.name, self.shard, self.shards, len(mine))

    def _rank(self, frame, board: Board) -> None:
        assert self._index is not None  # frames wait in _waiting until the index is built
        ranking = self._index.rank(frame.body["image"])
        board.post(
            levels.RANKING,
            {
                "frame": int(frame.body["frame"]),
                "frame_time": frame.timestamp,
                "shard": self.shard,
                "shards": self.shards,
                **ranking.to_dict(),
            },
            id=f"rk-{int(frame.body['frame']):06d}-{self.shard}",
            links=(frame.id,),
            credibility=float(min(1.0, max(0.0, ranking.reliability / (1.0 + ranking.reliability)))),
        )
