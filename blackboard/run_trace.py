"""What the node records of a run: the trace file (optional) and the counters of every event kind.

:class:`RunTrace` turns the node's events into :class:`~blackboard.trace.TraceKind` records:
hypotheses with their fields, rejected messages (also logged), and the agents' activity reports
(compact rows, :data:`~blackboard.agent.ACTIVITY_ROW`, or dict records), counting each kind in
:attr:`RunTrace.stats` whether or not a trace file is written.
"""

from __future__ import annotations

import logging
from collections import Counter
from pathlib import Path
from typing import Any

from blackboard.agent import ACTIVITY_CODES, ACTIVITY_ROW
from blackboard.hypothesis import Hypothesis
from blackboard.trace import TraceKind, TraceWriter

__all__ = ["RunTrace"]

logger = logging.getLogger(__name__)

_ACTIVITY_KINDS = {
    k.value: k
    for k in (
        TraceKind.ACTIVATION_START,
        TraceKind.ACTIVATION_FINISH,
        TraceKind.ACTIVATION_ERROR,
        TraceKind.ACTIVATION_OBVIATED,
    )
}
_ROW_CODES = {code: (TraceKind(kind), extra) for code, (kind, extra) in ACTIVITY_CODES.items()}
_ROW_FIELDS = ACTIVITY_ROW[1:7]


class RunTrace:
    """The trace writer of a run (``path`` None: count only)."""

    def __init__(self, path: str | Path | None) -> None:
        self._writer = TraceWriter(path) if path is not None else None
        self.stats: Counter[str] = Counter()

    @property
    def writing(self) -> bool:
        return self._writer is not None

    def write(self, kind: TraceKind, **fields: Any) -> None:
        if self._writer is not None:
            self._writer.write(kind, **fields)

    def hypothesis(self, kind: TraceKind, hyp: Hypothesis, **extra: Any) -> None:
        """A post or update of ``hyp``, with all its fields."""
        if self._writer is None:
            return
        self._writer.write(
            kind,
            t=hyp.timestamp,
            agent=hyp.source,
            level=hyp.level,
            id=hyp.id,
            version=hyp.version,
            links=list(hyp.links),
            credibility=hyp.credibility,
            addressed_to=hyp.addressed_to,
            deadline_s=hyp.deadline_s,
            body=hyp.body,
            **extra,
        )

    def reject(self, key: str, message: str, **fields: Any) -> None:
        """A message the node refused: counted, logged, traced."""
        self.stats["rejected"] += 1
        logger.warning("blackboard node: rejected a message on %s: %s", key, message)
        self.write(TraceKind.REJECTED, key=key, message=message, **fields)

    def activity(self, agent: str, records: Any) -> None:
        """Count and trace an agent's activity: rows (:data:`~blackboard.agent.ACTIVITY_ROW`) or
        dict records; a trace record is made only when there is a trace."""
        stats, tracing = self.stats, self._writer is not None
        for record in records:
            if type(record) is list and len(record) == 8:
                code = _ROW_CODES.get(record[0])
                if code is None:
                    continue
                kind, extra = code
                stats[kind.value] += 1
                if tracing:
                    fields = dict(zip(_ROW_FIELDS, record[1:7], strict=True))
                    if extra is not None:
                        fields[extra] = record[7]
                    self.write(kind, agent=agent, **fields)
            elif isinstance(record, dict):
                named = _ACTIVITY_KINDS.get(record.pop("kind", None))
                if named is not None:
                    stats[named.value] += 1
                    self.write(named, agent=agent, **record)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
