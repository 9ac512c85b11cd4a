"""Who takes part in a run: the agents that joined, their declarations, their liveliness tokens.

An agent joins with a request declaring the levels it consumes, produces and writes exclusively;
:meth:`Membership.join` refuses a name already live and a second writer of an exclusive level.
It is *present* once it holds its liveliness token (or joined and is already dead); a token
that disappears from a live agent means the agent died. Waiters for named agents to join, and
for every token to go at the end of the run, are released by :meth:`Membership.check_presence`.

The node's worker thread changes the agents; readers in other threads take :attr:`Membership.lock`.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from blackboard.hypothesis import NAME_PATTERN

__all__ = ["AgentState", "JoinRefused", "Membership", "gone_phrase"]


@dataclass
class AgentState:
    """What the node knows of one agent."""

    name: str
    consumes: tuple[str, ...]
    produces: tuple[str, ...]
    exclusive: tuple[str, ...]
    pid: int | None = None
    status: dict | None = None
    timeouts_sent: int = 0
    state: str = "ok"  # ok | stopped | dead: reason
    #: the one-line message of a user's input error the agent met (it died of it), else None
    input_error: str | None = None
    #: activations of the agent that raised (it went on), and the last one's message
    failures: int = 0
    last_failure: str | None = None

    def count_failures(self, activity: Any) -> None:
        """Count the failed activations among an agent's activity records (its status message's)."""
        for record in activity or ():
            if isinstance(record, dict) and record.get("kind") == "activation_error":
                self.failures += 1
                self.last_failure = f"{record.get('message')} on {record.get('event')} {record.get('id')}"[:500]

    @property
    def failed(self) -> str | None:
        """``"<n> failed activation(s), the last: <message>"``, or None when none failed."""
        if not self.failures:
            return None
        s = "s" if self.failures > 1 else ""
        return f"{self.failures} failed activation{s}, the last: {self.last_failure}"

    @property
    def live(self) -> bool:
        return self.state == "ok"


@dataclass(frozen=True)
class JoinRefused:
    """Why a join was refused: the reply to send, and (for a second exclusive writer) the level
    and the other agent, for the trace."""

    reply: dict[str, Any]
    level: str | None = None
    other: str | None = None


def gone_phrase(state: str) -> str:
    """How a timeout names the addressee's state: ``left``, ``is dead: <why>``, or the state."""
    if "left" in state:
        return "left"
    return state.replace("dead: ", "is dead: ", 1) if state.startswith("dead") else state


class Membership:
    """The agents of a run and their liveliness tokens."""

    def __init__(self) -> None:
        self.agents: dict[str, AgentState] = {}
        self.lock = threading.Lock()
        self.tokens: set[str] = set()  # agents whose liveliness token is present
        self.any_exclusive = False
        self._join_waiters: list[tuple[frozenset[str], threading.Event]] = []
        self._gone_waiters: list[threading.Event] = []

    def get(self, name: str) -> AgentState | None:
        return self.agents.get(name)

    def live(self) -> list[AgentState]:
        return [a for a in self.agents.values() if a.live]

    # -- joining and declarations -----------------------------------------------------------------

    def join(self, name: str, request: dict) -> AgentState | JoinRefused:
        """Admit agent ``name`` with the declarations of its join ``request``, or say why not."""
        try:
            decl = {k: tuple(str(x) for x in request.get(k, ())) for k in ("consumes", "produces", "exclusive")}
        except TypeError as err:
            return JoinRefused({"ok": False, "error": "malformed", "message": str(err)})
        if NAME_PATTERN.fullmatch(name) is None:
            return JoinRefused({"ok": False, "error": "malformed", "message": f"bad agent name {name!r}"})
        old = self.agents.get(name)
        if old is not None and old.live:
            return JoinRefused(
                {"ok": False, "error": "declaration", "level": "", "message": f"an agent named {name!r} already joined"}
            )
        for other in self.agents.values():
            if not other.live or other.name == name:
                continue
            for level in decl["produces"]:
                if level in other.exclusive or (level in decl["exclusive"] and level in other.produces):
                    return JoinRefused(
                        {
                            "ok": False,
                            "error": "declaration",
                            "level": level,
                            "message": f"level is written exclusively, and agent {other.name!r} also writes it",
                        },
                        level=level,
                        other=other.name,
                    )
        state = AgentState(name, decl["consumes"], decl["produces"], decl["exclusive"], pid=request.get("pid"))
        with self.lock:
            self.agents[name] = state
        self.any_exclusive = self.any_exclusive or bool(decl["exclusive"])
        return state

    def declaration_problem(self, agent: str, level: str) -> str | None:
        """Why ``agent`` may not write ``level`` (not in its produces, or another's exclusive level), or None."""
        state = self.agents.get(agent)
        if state is not None and level not in state.produces:
            return f"level not declared in produces {list(state.produces)}"
        if not self.any_exclusive:  # no agent ever declared an exclusive level: nothing to scan
            return None
        owner = next(
            (a.name for a in self.agents.values() if a.live and level in a.exclusive and a.name != agent), None
        )
        if owner is not None:
            return f"level is written exclusively by agent {owner!r}"
        return None

    # -- state --------------------------------------------------------------------------------------

    def set_state(self, agent: AgentState, state: str) -> None:
        with self.lock:
            agent.state = state

    def set_status(self, agent: AgentState, status: dict) -> None:
        with self.lock:
            agent.status = status

    def token(self, name: str, present: bool) -> None:
        """Agent ``name``'s liveliness token appeared (``present``) or disappeared."""
        with self.lock:
            if present:
                self.tokens.add(name)
            else:
                self.tokens.discard(name)

    def present(self, name: str) -> bool:
        """Joined and holding its token, or joined and already dead (caller holds the lock)."""
        agent = self.agents.get(name)
        return agent is not None and (name in self.tokens or not agent.live)

    def missing(self, names: Iterable[str]) -> list[str]:
        """Those of ``names`` not present, sorted."""
        with self.lock:
            return sorted(n for n in set(names) if not self.present(n))

    def connected(self) -> list[str]:
        """Agents still holding a token, sorted."""
        with self.lock:
            return sorted(self.tokens)

    # -- waiters ------------------------------------------------------------------------------------

    def await_join(self, names: frozenset[str], event: threading.Event) -> None:
        self._join_waiters.append((names, event))
        self.check_presence()

    def await_gone(self, event: threading.Event) -> None:
        self._gone_waiters.append(event)
        self.check_presence()

    def check_presence(self) -> None:
        """Release the join waiters whose agents are all present, and the end waiters once no token is left."""
        with self.lock:
            if self._join_waiters:
                waiting = []
                for names, event in self._join_waiters:
                    if all(self.present(n) for n in names):
                        event.set()
                    else:
                        waiting.append((names, event))
                self._join_waiters = waiting
            if self._gone_waiters and not self.tokens:
                for event in self._gone_waiters:
                    event.set()
                self._gone_waiters.clear()
