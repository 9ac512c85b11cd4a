"""The associative indexer: one memory bank of viewframes, ranking every camera frame."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from blackboard.hypothesis import Hypothesis
from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels

if TYPE_CHECKING:
    from models.associative import BankedMemory

__all__ = ["AssociativeIndexer"]

log = logging.getLogger(__name__)


class AssociativeIndexer(KnowledgeSource):
    """Stores the viewframes of its shard (``index % banks == bank``) in a banked holographic
    memory (:class:`~models.associative.BankedMemory`, ``memory.bank_size`` viewframes per bank)
    and posts ``index`` once its shard is stored, then, for each camera frame, the ranking of
    those viewframes by error variance. The
    scheduler merges the rankings of all shards (variances are comparable across banks).

    Options: ``bank`` (this shard, default 0), ``banks`` (number of shards, default 1). Memory
    parameters (size, edge method, blur, bank size, shift search) come from the scenario through
    the ``map`` hypothesis. Camera frames that
    arrive before the bank is complete wait; viewframes missed as events are read back from the
    blackboard, so an indexer that joins late or restarts still indexes everything.
    """

    consumes: ClassVar[tuple[str, ...]] = (levels.VIEWFRAME, levels.MAP, levels.SENSOR_FRAME)
    produces: ClassVar[tuple[str, ...]] = (levels.RANKING, levels.INDEX)

    def __init__(self, name: str, *, bank: int = 0, banks: int = 1, **options: Any) -> None:
        super().__init__(name, **options)
        if banks < 1 or not 0 <= bank < banks:
            raise ValueError(f"bank must be in [0, banks), got bank={bank}, banks={banks}")
        self.bank = bank
        self.banks = banks
        self._images: dict[int, np.ndarray] = {}
        self._memory: BankedMemory | None = None
        self._spec: dict[str, Any] | None = None
        self._waiting: list[Hypothesis] = []

    def precondition(self, event: Event) -> float | None:
        if event.kind is not EventKind.POSTED:
            return None
        h = event.hypothesis
        if h.level == levels.VIEWFRAME and levels.Viewframe.from_hypothesis(h).index % self.banks != self.bank:
            return None
        return 2.0 if h.level != levels.SENSOR_FRAME else 1.0

    def act(self, event: Event, board: Board) -> None:
        h = event.hypothesis
        if h.level == levels.VIEWFRAME:
            if self._memory is None:
                vf = levels.Viewframe.from_hypothesis(h)
                self._images[vf.index] = vf.image
        elif h.level == levels.MAP:
            self._build(levels.Map.from_hypothesis(h), board)
            waiting, self._waiting = self._waiting, []
            for frame in waiting:
                self._rank(frame, board)
        elif h.level == levels.SENSOR_FRAME:
            if self._memory is None:
                self._waiting.append(h)
            else:
                self._rank(h, board)

    def _build(self, mp: levels.Map, board: Board) -> None:
        from models.associative import memory_from_spec
        from models.preprocess import preprocess_with

        spec = mp.memory
        self._spec = spec
        mine = [k for k in range(mp.viewframes) if k % self.banks == self.bank]
        for k in mine:
            if k not in self._images:
                got = board.get(levels.viewframe_id(k))
                if got is None:
                    raise RuntimeError(f"viewframe {k} is on neither the event stream nor the blackboard")
                self._images[k] = levels.Viewframe.from_hypothesis(got).image
        memory = memory_from_spec(spec, seed=self.bank)
        memory.write_many((preprocess_with(self._images[k], memory=spec) for k in mine), mine)
        self._memory = memory
        self._images.clear()
        levels.post(board, levels.Index(bank=self.bank, banks=self.banks, viewframes=len(mine)),
                    links=(levels.map_id(),))
        log.info("%s: shard %d/%d holds %d viewframes", self.name, self.bank, self.banks, len(mine))

    def _rank(self, hypothesis: Hypothesis, board: Board) -> None:
        from models.preprocess import preprocess_with

        assert self._memory is not None and self._spec is not None
        frame = levels.SensorFrame.from_hypothesis(hypothesis)
        ranking = self._memory.rank(preprocess_with(frame.image, memory=self._spec))
        levels.post(
            board,
            levels.Ranking.of(ranking, frame=frame.frame, frame_time=hypothesis.timestamp, bank=self.bank,
                              banks=self.banks),
            links=(hypothesis.id,),
            credibility=float(min(1.0, max(0.0, ranking.reliability / (1.0 + ranking.reliability)))),
        )
