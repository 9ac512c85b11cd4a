"""The associative indexer: one shard of the viewframes, ranking every camera frame."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from blackboard.hypothesis import Hypothesis
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
        self._waiting: list[Hypothesis] = []

    def precondition(self, event: Event) -> float | None:
        if event.kind is not EventKind.POSTED:
            return None
        h = event.hypothesis
        if h.level == levels.VIEWFRAME and levels.Viewframe.from_hypothesis(h).index % self.shards != self.shard:
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

    def _build(self, mp: levels.Map, board: Board) -> None:
        from models.index import ViewframeIndex

        mine = [k for k in range(mp.viewframes) if k % self.shards == self.shard]
        for k in mine:
            if k not in self._images:
                got = board.get(levels.viewframe_id(k))
                if got is None:
                    raise RuntimeError(f"viewframe {k} is on neither the event stream nor the blackboard")
                self._images[k] = levels.Viewframe.from_hypothesis(got).image
        index = ViewframeIndex(mp.memory, seed=self.shard)
        index.add((self._images[k] for k in mine), mine)
        self._index = index
        self._images.clear()
        levels.post(
            board, levels.Index(shard=self.shard, shards=self.shards, viewframes=len(mine)), links=(levels.map_id(),)
        )
        log.info("%s: shard %d/%d holds %d viewframes", self.name, self.shard, self.shards, len(mine))

    def _rank(self, hypothesis: Hypothesis, board: Board) -> None:
        assert self._index is not None  # frames wait in _waiting until the index is built
        frame = levels.SensorFrame.from_hypothesis(hypothesis)
        ranking = self._index.rank(frame.image)
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
