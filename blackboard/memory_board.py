"""An in-memory blackboard in one thread: knowledge sources tested without zenoh.

:class:`MemoryBlackboard` keeps a store of hypotheses and a set of knowledge sources, each with
its own :class:`MemoryBoard` (the :class:`~blackboard.knowledge_source.Board` protocol) and agenda.
It follows the distributed blackboard's rules so that an agent that works here works there:

* every body goes through the codec (:mod:`blackboard.codec`) as on the wire: consumers see lists
  for tuples and read-only numpy arrays, and a body that cannot be encoded raises at the post;
* a post, update or retraction is delivered at once to every agent consuming its level (the poster
  too, when it consumes it) whose ``precondition`` rates it; agendas run highest rating first,
  in posting order among equals, timeouts before anything else; an activation whose hypothesis
  was superseded or retracted meanwhile is obviated (skipped);
* levels outside ``produces`` raise :class:`~blackboard.errors.DeclarationError`, as does a second
  writer of an ``exclusive`` level at :meth:`MemoryBlackboard.add`; a post whose id exists is
  rejected (logged, listed in :attr:`MemoryBlackboard.rejected`), as the node does;
* an addressed post that nobody answered (no post links to it) when nothing is left to run times
  out: its poster's ``on_timeout`` runs with the reason. Time does not pass here, so a
  ``deadline_s`` is not waited for: the answer comes within the run or never.

:meth:`MemoryBlackboard.run` runs the agents round-robin, one activation each in turn, until no
agenda holds anything: deterministic, and nothing runs in another thread.

Example::

    >>> from tests.blackboard.agents import Doubler        # doctest: +SKIP
    >>> bb = MemoryBlackboard()
    >>> bb.add(Doubler("doubler"))                         # doctest: +SKIP
    >>> bb.post("number", {"x": 2})                        # doctest: +SKIP
    >>> bb.run()                                           # doctest: +SKIP
    >>> [h.body["x"] for h in bb.hypotheses("doubled")]    # doctest: +SKIP
    [4]
"""

from __future__ import annotations

import heapq
import itertools
import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from blackboard.codec import DEFAULT_MAX_BYTES, decode, encode
from blackboard.errors import AgentError, BlackboardError, DeclarationError
from blackboard.hypothesis import Hypothesis, validate_name
from blackboard.knowledge_source import Event, EventKind, KnowledgeSource

if TYPE_CHECKING:
    from collections.abc import Iterable

__all__ = ["USER", "MemoryBlackboard", "MemoryBoard"]

logger = logging.getLogger(__name__)

#: the source of posts made with :meth:`MemoryBlackboard.post` (as the runtime's inputs)
USER = "user"


def _wire(hyp: Hypothesis, max_bytes: int) -> Hypothesis:
    """``hyp`` as a receiver would see it: encoded and decoded by the codec."""
    return Hypothesis.from_record(decode(encode(hyp.to_record(), max_bytes=max_bytes), max_bytes=max_bytes))


@dataclass
class _Agent:
    source: KnowledgeSource
    board: MemoryBoard
    agenda: list[tuple[float, int, Event]] = field(default_factory=list)
    failures: int = 0
    dead: str | None = None


class MemoryBoard:
    """One agent's view of a :class:`MemoryBlackboard` (the :class:`~blackboard.knowledge_source.Board`
    protocol); ``produces=None`` allows every level (the user's board)."""

    def __init__(self, blackboard: MemoryBlackboard, agent: str, *, produces: Iterable[str] | None) -> None:
        self._bb = blackboard
        self.agent = validate_name(agent, "agent name")
        self._produces = None if produces is None else frozenset(produces)

    def _check_level(self, level: str) -> None:
        validate_name(level, "level")
        if self._produces is not None and level not in self._produces:
            raise DeclarationError(self.agent, level, f"not declared in produces {sorted(self._produces)}")

    def post(
        self,
        level: str,
        body: dict,
        *,
        links: Iterable[str] = (),
        credibility: float = 1.0,
        id: str | None = None,
        addressed_to: str | None = None,
        deadline_s: float | None = None,
    ) -> Hypothesis:
        self._check_level(level)
        hyp = Hypothesis.new(
            level,
            body,
            source=self.agent,
            links=tuple(links),
            credibility=credibility,
            id=id,
            addressed_to=addressed_to,
            deadline_s=deadline_s,
        )
        self._bb._accept(_wire(hyp, self._bb.max_message_bytes))
        return hyp

    def update(self, hypothesis_id: str, *, body: dict | None = None, credibility: float | None = None) -> Hypothesis:
        hyp = self._existing(hypothesis_id)
        if body is not None and not isinstance(body, dict):
            raise BlackboardError(f"agent {self.agent!r}: update of {hypothesis_id!r}: body must be a map")
        new = _wire(hyp.evolve(body=body, credibility=credibility), self._bb.max_message_bytes)
        self._bb._replace(new)
        return new

    def retract(self, hypothesis_id: str) -> None:
        self._bb._remove(self._existing(hypothesis_id))

    def get(self, hypothesis_id: str) -> Hypothesis | None:
        validate_name(hypothesis_id, "hypothesis id")
        return self._bb._store.get(hypothesis_id)

    def query(self, level: str) -> list[Hypothesis]:
        validate_name(level, "level")
        return self._bb.hypotheses(level)

    def _existing(self, hypothesis_id: str) -> Hypothesis:
        hyp = self._bb._store.get(hypothesis_id)
        if hyp is None:
            raise BlackboardError(f"agent {self.agent!r}: no hypothesis {hypothesis_id!r} on the board")
        self._check_level(hyp.level)
        return hyp


class MemoryBlackboard:
    """A blackboard and its knowledge sources in one thread (see the module docstring).

    Args:
        raise_errors: an exception in an agent's ``precondition``, ``act`` or ``on_timeout``
            propagates out of :meth:`run` (the default: a test sees the traceback). When False,
            it is logged and listed in :attr:`errors`, and the agent is dead after its
            ``max_failures``, as under the runtime.
        max_message_bytes: the codec's size limit.
    """

    def __init__(self, *, raise_errors: bool = True, max_message_bytes: int = DEFAULT_MAX_BYTES) -> None:
        self.raise_errors = raise_errors
        self.max_message_bytes = max_message_bytes
        self._store: dict[str, Hypothesis] = {}
        self._agents: dict[str, _Agent] = {}
        self._order = itertools.count()
        self._pending: dict[str, Hypothesis] = {}  # addressed posts not answered yet
        self._latest: dict[str, int] = {}
        self._retracted: set[str] = set()
        #: every event in order: what a trace would list
        self.events: list[Event] = []
        #: (hypothesis, why) of posts the node would have rejected
        self.rejected: list[tuple[Hypothesis, str]] = []
        #: (agent, event, exception) of failed activations (when not ``raise_errors``)
        self.errors: list[tuple[str, Event, Exception]] = []
        #: timeouts of addressed posts made by the user
        self.user_timeouts: list[tuple[Hypothesis, str]] = []
        self.user = MemoryBoard(self, USER, produces=None)

    # -- agents ------------------------------------------------------------------------------------

    def add(self, source: KnowledgeSource) -> MemoryBoard:
        """Join ``source`` (declaration checks as the node's) and run its ``setup``; returns its board.

        Raises:
            DeclarationError: its name is taken, or it would be a second writer of an exclusive level.
        """
        name = source.name
        if name in self._agents or name == USER:
            raise DeclarationError(name, "", f"an agent named {name!r} already joined")
        for other in self._agents.values():
            for level in source.produces:
                if level in other.source.exclusive or (level in source.exclusive and level in other.source.produces):
                    raise DeclarationError(
                        name, level, f"level is written exclusively, and agent {other.source.name!r} also writes it"
                    )
        board = MemoryBoard(self, name, produces=source.produces)
        self._agents[name] = _Agent(source, board)
        source.setup(board)
        return board

    def board(self, name: str) -> MemoryBoard:
        """The board of agent ``name`` (or of ``"user"``)."""
        if name == USER:
            return self.user
        return self._agents[name].board

    def dead(self) -> dict[str, str]:
        """Agents that failed ``max_failures`` times, with the reason."""
        return {name: a.dead for name, a in self._agents.items() if a.dead is not None}

    # -- the user's side -----------------------------------------------------------------------------

    def post(self, level: str, body: dict, **kw: Any) -> Hypothesis:
        """Post an input as source ``"user"`` (keywords as ``Board.post``)."""
        return self.user.post(level, body, **kw)

    def hypotheses(self, level: str | None = None) -> list[Hypothesis]:
        """The current store (all levels, or one), oldest first."""
        found = [h for h in self._store.values() if level is None or h.level == level]
        return sorted(found, key=lambda h: (h.timestamp, h.id))

    def run(self, *, timeouts: bool = True, max_activations: int = 1_000_000) -> int:
        """Run activations until every agenda is empty and no addressed post waits; returns how many ran.

        ``timeouts=False``: return once the agendas are empty, leaving unanswered addressed posts
        pending (a test that answers them itself, then runs again).

        Raises:
            AgentError: more than ``max_activations`` (a loop between agents).
        """
        ran = 0
        while True:
            progressed = False
            for agent in list(self._agents.values()):
                if agent.agenda:
                    self._run_one(agent)
                    ran += 1
                    progressed = True
                    if ran > max_activations:
                        raise AgentError(agent.source.name, f"more than {max_activations} activations: a loop?")
            if progressed:
                continue
            if not self._pending or not timeouts:
                return ran
            for hyp_id, hyp in list(self._pending.items()):
                addressee = self._agents.get(hyp.addressed_to or "")
                if addressee is None:
                    reason = f"agent {hyp.addressed_to!r} is not on the board"
                elif addressee.dead is not None:
                    reason = f"agent {hyp.addressed_to!r} is dead: {addressee.dead}"
                else:
                    reason = f"agent {hyp.addressed_to!r} went idle without answering"
                self._timeout(hyp_id, reason)

    # -- the store (called by the boards) -------------------------------------------------------------

    def _accept(self, hyp: Hypothesis) -> None:
        if hyp.id in self._store:
            logger.warning("memory blackboard: rejected %s from %s: id exists", hyp.id, hyp.source)
            self.rejected.append((hyp, f"hypothesis id {hyp.id!r} already exists"))
            return
        self._store[hyp.id] = hyp
        self._latest[hyp.id] = hyp.version
        self._retracted.discard(hyp.id)
        for link in hyp.links:
            self._pending.pop(link, None)
        if hyp.addressed_to is not None:
            self._pending[hyp.id] = hyp
        self._deliver(Event(EventKind.POSTED, hyp))

    def _replace(self, hyp: Hypothesis) -> None:
        self._store[hyp.id] = hyp
        self._latest[hyp.id] = hyp.version
        self._deliver(Event(EventKind.UPDATED, hyp))

    def _remove(self, hyp: Hypothesis) -> None:
        del self._store[hyp.id]
        self._pending.pop(hyp.id, None)
        self._retracted.add(hyp.id)
        self._deliver(Event(EventKind.RETRACTED, hyp))

    def _timeout(self, hyp_id: str, reason: str) -> None:
        hyp = self._pending.pop(hyp_id)
        event = Event(EventKind.TIMEOUT, hyp, reason)
        self.events.append(event)
        poster = self._agents.get(hyp.source)
        if poster is None or poster.dead is not None:
            self.user_timeouts.append((hyp, reason))
            return
        heapq.heappush(poster.agenda, (-float("inf"), next(self._order), event))

    def _deliver(self, event: Event) -> None:
        self.events.append(event)
        level = event.hypothesis.level
        for agent in self._agents.values():
            if agent.dead is not None or level not in agent.source.consumes:
                continue
            try:
                rating = agent.source.precondition(event) if agent.source.wants(level, event.hypothesis.id) else None
            except Exception as err:  # noqa: BLE001  # the agent's own code
                self._failed(agent, event, err)
                continue
            if rating is not None:
                heapq.heappush(agent.agenda, (-float(rating), next(self._order), event))

    def _run_one(self, agent: _Agent) -> None:
        _, _, event = heapq.heappop(agent.agenda)
        hyp = event.hypothesis
        if event.kind in (EventKind.POSTED, EventKind.UPDATED) and (
            hyp.id in self._retracted or self._latest.get(hyp.id, 0) > hyp.version
        ):
            return  # obviated
        try:
            if event.kind is EventKind.TIMEOUT:
                agent.source.on_timeout(hyp, event.reason, agent.board)
            else:
                agent.source.act(event, agent.board)
        except Exception as err:  # noqa: BLE001  # the agent's own code
            self._failed(agent, event, err)

    def _failed(self, agent: _Agent, event: Event, err: Exception) -> None:
        if self.raise_errors:
            raise err
        name = agent.source.name
        logger.warning(
            "memory blackboard: agent %s raised %s: %s on %s", name, type(err).__name__, err, event.hypothesis.id
        )
        self.errors.append((name, event, err))
        agent.failures += 1
        if agent.failures >= agent.source.max_failures:
            agent.dead = f"{agent.failures} failures, the last: {type(err).__name__}: {err}"
            agent.agenda.clear()
            for hyp_id, hyp in list(self._pending.items()):
                if hyp.addressed_to == name:
                    self._timeout(hyp_id, f"agent {name!r} is dead: {agent.dead}")
