"""Global quiescence of a run, across processes, without sleeping.

The node counts every sample on each level (including the updates and retractions it publishes
itself), the one-hop posts it received from each agent and the timeouts it sent to each agent.
Agents report ``idle`` with their own counters whenever their inbox and agenda are empty. When
every live agent is idle and caught up (received on each consumed level what the node counted,
the node received all its posts, it received all its timeouts), no request is held and no
addressed post waits for its deadline, the node sends a probe; if every live agent answers the
probe idle and nothing changed in between, the run is quiescent.

:class:`Quiescence` keeps the counters and decides (:meth:`Quiescence.step`); the node does what
it says (time out, probe, release the waiters).
"""

from __future__ import annotations

import enum
import threading
from collections import Counter
from dataclasses import dataclass

from blackboard.deadlines import Deadlines
from blackboard.membership import AgentState

__all__ = ["Quiescence", "Step", "StepKind"]


class StepKind(enum.Enum):
    """What the node must do next for quiescence."""

    WAIT = "wait"  # not yet: agents busy, requests held or deadlines to come
    TIME_OUT = "time_out"  # every agent idle, yet addressed posts without deadline wait: time them out
    PROBE = "probe"  # send probe number ``probe``
    QUIESCENT = "quiescent"  # release the waiters


@dataclass(frozen=True)
class Step:
    kind: StepKind
    probe: int = 0
    time_out: tuple[str, ...] = ()


class Quiescence:
    """Counters of a run and the quiescence decision.

    ``received`` is the node's count of posts received per sender (shared with its barrier).
    """

    def __init__(self, received: Counter[str]) -> None:
        self.level_counts: Counter[str] = Counter()
        self.received = received
        self.changes = 0
        self.probe = 0
        self._probe_changes: int | None = None
        self.waiters: list[threading.Event] = []

    def sample(self, level: str) -> None:
        """A sample on ``level`` went out or came in."""
        self.level_counts[level] += 1
        self.changes += 1

    def change(self) -> None:
        """Something happened that an idle agent has not seen yet (a join, a death, a timeout, a request)."""
        self.changes += 1

    def caught_up(self, agent: AgentState) -> bool:
        """``agent`` reported idle with counters matching the node's."""
        status = agent.status
        if status is None or status.get("state") != "idle":
            return False
        if status.get("sent", 0) != self.received[agent.name] or status.get("timeouts", 0) != agent.timeouts_sent:
            return False
        recv = status.get("recv") or {}
        return all(recv.get(level, 0) == self.level_counts[level] for level in agent.consumes)

    def step(self, live: list[AgentState], *, held: bool, deadlines: Deadlines) -> Step:
        """The next step towards quiescence, given the live agents, whether requests are held,
        and the pending addressed posts."""
        if held or not all(self.caught_up(a) for a in live):
            return Step(StepKind.WAIT)
        if deadlines.any_deadline():
            return Step(StepKind.WAIT)  # the deadline will fire
        if deadlines:
            return Step(StepKind.TIME_OUT, time_out=tuple(deadlines.pending))
        if live and self._probe_changes != self.changes:
            self.probe += 1
            self._probe_changes = self.changes
            return Step(StepKind.PROBE, probe=self.probe)
        if live and not all((a.status or {}).get("probe") == self.probe for a in live):
            return Step(StepKind.WAIT)
        return Step(StepKind.QUIESCENT)

    def release(self) -> None:
        """Set and forget the waiters (the run is quiescent)."""
        for waiter in self.waiters:
            waiter.set()
        self.waiters.clear()
