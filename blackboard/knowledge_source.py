"""Knowledge sources, the :class:`Board` they see, and the :class:`Event` that triggers them.

Lifecycle (as py_trees behaviours): ``__init__`` configures (pure, no middleware);
:meth:`KnowledgeSource.setup` runs once after connecting and may read the board;
:meth:`~KnowledgeSource.precondition` rates each triggering event (None: do not activate);
:meth:`~KnowledgeSource.act` does the work; :meth:`~KnowledgeSource.shutdown` releases resources.
Each knowledge source declares the levels it ``consumes``, ``produces`` and writes
``exclusive``-ly; the runtime refuses anything else with a :class:`DeclarationError`.

Example::

    class Doubler(KnowledgeSource):
        consumes = ("number",)
        produces = ("doubled",)

        def act(self, event, board):
            x = event.hypothesis.body["x"]
            board.post("doubled", {"x": 2 * x}, links=(event.hypothesis.id,))
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, runtime_checkable

from blackboard.errors import DeclarationError
from blackboard.hypothesis import Hypothesis, validate_name

if TYPE_CHECKING:
    from collections.abc import Iterable

__all__ = ["Board", "Event", "EventKind", "KnowledgeSource"]

logger = logging.getLogger(__name__)


class EventKind(str, enum.Enum):
    """What happened to the hypothesis of an :class:`Event`."""

    POSTED = "posted"
    UPDATED = "updated"
    RETRACTED = "retracted"
    TIMEOUT = "timeout"


@dataclass(frozen=True)
class Event:
    """A change on the blackboard delivered to a knowledge source.

    ``reason`` explains a TIMEOUT (``"agent 'detector-house' left"``).
    """

    kind: EventKind
    hypothesis: Hypothesis
    reason: str = ""


class KnowledgeSource:
    """Base class of knowledge sources; subclasses set the class declarations and override
    :meth:`act` (and :meth:`precondition`, :meth:`setup`, :meth:`on_timeout`, :meth:`shutdown`).

    ``options`` are plain data (they cross process boundaries in ``processes`` mode).
    """

    consumes: ClassVar[tuple[str, ...]] = ()
    produces: ClassVar[tuple[str, ...]] = ()
    exclusive: ClassVar[tuple[str, ...]] = ()
    #: failures of act() after which the agent is reported dead
    max_failures: ClassVar[int] = 3

    def __init__(self, name: str, **options: Any) -> None:
        self.name = validate_name(name, "agent name")
        self.options = options
        for level in (*self.consumes, *self.produces, *self.exclusive):
            validate_name(level, f"level declared by {type(self).__name__}")
        if not set(self.exclusive) <= set(self.produces):
            raise DeclarationError(
                name,
                ",".join(sorted(set(self.exclusive) - set(self.produces))),
                "exclusive levels must also be in produces",
            )

    def setup(self, board: Board) -> None:
        """Once, after connecting; may read existing state."""

    def wants(self, level: str, hypothesis_id: str) -> bool:
        """Whether a message about hypothesis ``hypothesis_id`` on ``level`` (of a consumed level)
        is worth decoding: a filter on the message's key, before its body is decoded (default:
        every one). A sharded agent that takes one hypothesis in N says no to the others here,
        so it does not decode, nor queue, every large message of the level."""
        return True

    def precondition(self, event: Event) -> float | None:
        """Activation rating of ``event`` (higher runs first), or None not to activate."""
        return 0.0

    def act(self, event: Event, board: Board) -> None:
        """React to ``event``: read, post, update, retract."""

    def on_timeout(self, hypothesis: Hypothesis, reason: str, board: Board) -> None:
        """An addressed post of this agent got no answer: the addressee left or the deadline passed."""
        logger.warning("%s: addressed post %s timed out: %s", self.name, hypothesis.id, reason)

    def shutdown(self) -> None:
        """Release resources; called once, at the end of the run."""

    def input_error(self, err: Exception) -> str | None:
        """The one-line message when ``err`` (raised by :meth:`setup`, :meth:`act`) is a user's
        input error that no retry can mend (a malformed file): the agent then dies of it at
        once, and the run stops with that message. None (the default): an ordinary failure."""
        return None


@runtime_checkable
class Board(Protocol):
    """What an agent sees of the blackboard: the protocol every board implements.

    :class:`blackboard.zenoh_board.ZenohBoard` is the distributed one (a run's agents, each bound
    to its zenoh session); :class:`blackboard.memory_board.MemoryBoard` is an in-memory one in a
    single thread, for testing knowledge sources without zenoh. Both check the agent's declared
    ``produces`` and validate hypotheses the same way; reads see the agent's own earlier posts.
    """

    #: the name of the agent this board belongs to
    agent: str

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
        """Post a new hypothesis (version 1) on ``level``; returns it.

        With ``addressed_to``, the addressee is expected to post a hypothesis linking to this one
        (within ``deadline_s`` if given); otherwise this agent's ``on_timeout`` is called.

        Raises:
            DeclarationError: ``level`` is not in this agent's ``produces``.
            CodecError: ``body`` cannot be encoded or is larger than the message limit.
            ValueError: a bad id, link, credibility or deadline.
        """
        ...

    def update(self, hypothesis_id: str, *, body: dict | None = None, credibility: float | None = None) -> Hypothesis:
        """Merge ``body`` into the hypothesis' body (top-level keys) and/or set its credibility;
        the board assigns the next version. Returns the new version.

        Raises:
            DeclarationError: its level is not in this agent's ``produces``.
            BlackboardError: no such hypothesis (never posted, or retracted).
        """
        ...

    def retract(self, hypothesis_id: str) -> None:
        """Remove a hypothesis from the board (consumers get a RETRACTED event).

        Raises:
            DeclarationError: its level is not in this agent's ``produces``.
            BlackboardError: no such hypothesis.
        """
        ...

    def get(self, hypothesis_id: str) -> Hypothesis | None:
        """The current version of a hypothesis, or None."""
        ...

    def query(self, level: str) -> list[Hypothesis]:
        """All hypotheses on ``level``, oldest first."""
        ...
