"""Addressed posts waiting for an answer, and their deadlines.

A post with ``addressed_to`` (or a ``deadline_s``) is expected to be answered: another post links
to it. Until then it is pending here; when its deadline passes, or its addressee leaves or goes
idle without answering, the node times it out (the poster's ``on_timeout`` runs).
"""

from __future__ import annotations

import heapq
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from blackboard.hypothesis import Hypothesis

__all__ = ["Deadlines", "Pending"]


@dataclass
class Pending:
    """An addressed post and its deadline (``time.monotonic()`` seconds, or None: none)."""

    hyp: Hypothesis
    deadline: float | None


class Deadlines:
    """The pending addressed posts, with a heap of their deadlines; ``clock`` is ``time.monotonic``."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self.pending: dict[str, Pending] = {}
        self._heap: list[tuple[float, str]] = []

    def __bool__(self) -> bool:
        return bool(self.pending)

    def __contains__(self, hypothesis_id: object) -> bool:
        return hypothesis_id in self.pending

    def expect(self, hyp: Hypothesis) -> bool:
        """Start waiting for an answer to ``hyp`` if it is addressed or has a deadline; returns whether."""
        if hyp.addressed_to is None and hyp.deadline_s is None:
            return False
        deadline = None if hyp.deadline_s is None else self._clock() + hyp.deadline_s
        self.pending[hyp.id] = Pending(hyp, deadline)
        if deadline is not None:
            heapq.heappush(self._heap, (deadline, hyp.id))
        return True

    def answered(self, links: Iterable[str]) -> None:
        """A post linking to ``links`` arrived: those are answered."""
        pending = self.pending
        for link in links:
            if link in pending:
                del pending[link]

    def pop(self, hypothesis_id: str) -> Pending | None:
        """Stop waiting for ``hypothesis_id`` (timed out or retracted); returns what waited, or None."""
        return self.pending.pop(hypothesis_id, None)

    def addressed_to(self, agent: str) -> list[str]:
        """Ids of the pending posts addressed to ``agent``, oldest first."""
        return [hyp_id for hyp_id, p in self.pending.items() if p.hyp.addressed_to == agent]

    def any_deadline(self) -> bool:
        """Whether some pending post has a deadline (it will fire: no need to time out the rest)."""
        return any(p.deadline is not None for p in self.pending.values())

    def wait_s(self) -> float | None:
        """Seconds until the next deadline (0 if passed), or None when there is none."""
        return max(0.0, self._heap[0][0] - self._clock()) if self._heap else None

    def due(self) -> list[tuple[str, str]]:
        """``(id, reason)`` of the still-pending posts whose deadline has passed, in deadline order;
        they stay pending until :meth:`pop`."""
        now = self._clock()
        out = []
        while self._heap and self._heap[0][0] <= now:
            _, hyp_id = heapq.heappop(self._heap)
            pending = self.pending.get(hyp_id)
            if pending is not None:
                hyp = pending.hyp
                out.append(
                    (
                        hyp_id,
                        f"no answer within {hyp.deadline_s} s"
                        + (f" from agent {hyp.addressed_to!r}" if hyp.addressed_to else ""),
                    )
                )
        return out
