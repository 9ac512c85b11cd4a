"""Zenoh client sessions shared by the agents of one process.

Every in-process agent used to open a zenoh client session of its own. A session that sends
large messages maps a shared-memory pool of its own (16 MB, zenoh's default) and touches it
as it cycles through it, and the router sends each post once to every session that subscribes
to it. With ~50 agents in one process (20 indexer shards of a 10,000-viewframe route, detectors,
skyline, ...) that was 50 pools (835 MB resident at 10,000 viewframes, 200 MB of a 594 MB
``hills`` run) and 20 copies of every 150 KB viewframe message on the loopback links. Agents
of one run with the same zenoh configuration (the same node endpoint, config file and password)
now share one session: the router sends a post to the process once and the session
hands it to each agent's subscriber.

An agent's subscribers, queryables and liveliness token stay its own: :meth:`SharedSession.release`
undeclares them, so to the node an agent that stops, or is killed, leaves exactly as if it had
closed a session of its own (its liveliness token disappears). The last agent to release a
session closes it.

Example::

    shared = SESSIONS.acquire(config)        # opens it, or shares the one already open
    sub = shared.session.declare_subscriber(key, callback)
    ...
    shared.release([sub])                    # undeclares, closes the session if it was the last
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterable
from typing import Any

import zenoh

from blackboard.config import close_session, open_session

__all__ = ["SESSIONS", "SharedSession", "SessionRegistry"]

logger = logging.getLogger(__name__)


class SharedSession:
    """One agent's hold on a shared zenoh session (see the module docstring)."""

    def __init__(self, registry: SessionRegistry, key: str, session: zenoh.Session) -> None:
        self._registry = registry
        self._key = key
        self.session = session
        self.released = False

    @property
    def open(self) -> bool:
        """This hold is not released and the session is not closed."""
        return not self.released and not self.session.is_closed()

    def release(self, entities: Iterable[Any] = ()) -> None:
        """Undeclare ``entities`` (this agent's subscribers, queryables, tokens), then give the
        session back: closed when no other agent holds it. Idempotent."""
        if self.released:
            return
        self.released = True
        if not self.session.is_closed():
            for entity in entities:
                try:
                    entity.undeclare()
                except zenoh.ZError as err:  # already gone with a closing session
                    logger.debug("undeclare %r: %s", entity, err)
        self._registry._release(self._key, self.session)


class SessionRegistry:
    """The process's open client sessions, by configuration, with the number of agents holding each."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._open: dict[str, tuple[zenoh.Session, int]] = {}

    def acquire(self, config: zenoh.Config, *, scope: str = "") -> SharedSession:
        """A hold on the session of ``config`` within ``scope`` (the run id: agents of two runs
        never share a session, even when a later run's node listens on a port an earlier one
        used): the open one, or a new one (:class:`~blackboard.errors.TransportError` when it
        cannot be opened)."""
        key = _key(config, scope)
        with self._lock:
            held = self._open.get(key)
            if held is not None and not held[0].is_closed():
                session, count = held
                self._open[key] = (session, count + 1)
            else:
                session = open_session(config)
                self._open[key] = (session, 1)
        return SharedSession(self, key, session)

    def _release(self, key: str, session: zenoh.Session) -> None:
        with self._lock:
            held = self._open.get(key)
            if held is None or held[0] is not session:  # a session closed and replaced meanwhile
                last = True
            else:
                count = held[1] - 1
                last = count <= 0
                if last:
                    del self._open[key]
                else:
                    self._open[key] = (session, count)
        if last:
            close_session(session, owner="shared agent session")

    def holders(self, config: zenoh.Config, *, scope: str = "") -> int:
        """How many agents hold the session of ``config`` within ``scope`` (0: none open)."""
        with self._lock:
            held = self._open.get(_key(config, scope))
            return 0 if held is None or held[0].is_closed() else held[1]


def _key(config: zenoh.Config, scope: str) -> str:
    return f"{scope}\n{config}"


#: the registry of this process
SESSIONS = SessionRegistry()
