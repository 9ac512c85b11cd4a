"""The node's store of hypotheses, and the barrier that lets reads and changes see every post their
requester has seen.

:class:`Store` holds the current version of every hypothesis with the encoded message that carried
it (a read is answered with those bytes, not re-encoded). A large message (a viewframe's image
and mask) is not kept twice: given an ``encode`` function, the store keeps only the decoded
hypothesis of a message of :data:`KEEP_BYTES_BELOW` bytes or more, and encodes it again when a
read asks for it (reads of large hypotheses are rare: late joiners and on-demand fetches). It is
written by the node's worker thread only; readers in other threads (the runtime) take its lock.

:class:`Barrier` holds requests (reads, updates, retractions) until the node has received the
posts their requester had sent, and those it had seen from other senders: an agent that updates a
post it just received never finds the node without it, and an agent that joins late and reads the
store finds everything posted before. Posts travel one hop (producer to consumers and the node at
once), so the node counts what it received from each sender and the requester says what it sent
and saw.
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import zenoh

if TYPE_CHECKING:
    from blackboard.hypothesis import Hypothesis
    from blackboard.keys import RunKeys

__all__ = ["Barrier", "KEEP_BYTES_BELOW", "Store"]

#: messages of this many bytes or more are not kept encoded when the store can encode them again
KEEP_BYTES_BELOW = 16384


class Store:
    """Hypotheses by id, each with its encoded message; versions are assigned by the node
    (:meth:`Hypothesis.evolve`), this keeps the current one.

    ``encode(hyp, op, sender)`` (optional) makes the message again for a hypothesis whose bytes
    were not kept (see the module docstring); without it every message is kept.
    """

    def __init__(self, encode: Callable[[Hypothesis, str, str], bytes] | None = None) -> None:
        self._entries: dict[str, tuple[Hypothesis, bytes | tuple[str, str]]] = {}
        self._encode = encode
        self._lock = threading.Lock()

    def __contains__(self, hypothesis_id: object) -> bool:
        return hypothesis_id in self._entries

    def __len__(self) -> int:
        return len(self._entries)

    def get(self, hypothesis_id: object) -> Hypothesis | None:
        """The current version of a hypothesis, or None (also for a non-str id)."""
        entry = self._entries.get(hypothesis_id) if isinstance(hypothesis_id, str) else None
        return None if entry is None else entry[0]

    def put(self, hyp: Hypothesis, data: bytes, *, op: str = "post", sender: str | None = None) -> None:
        """Store a new hypothesis, or the next version of one; ``data`` is the message (``op``,
        ``sender``) that carried it (kept, or dropped when large and ``sender`` is given)."""
        kept: bytes | tuple[str, str] = data
        if self._encode is not None and sender is not None and len(data) >= KEEP_BYTES_BELOW:
            kept = (op, sender)
        with self._lock:
            self._entries[hyp.id] = (hyp, kept)

    def kept_bytes(self) -> int:
        """Bytes of encoded messages held (the large ones are not, see the module docstring)."""
        with self._lock:
            return sum(len(d) for _, d in self._entries.values() if isinstance(d, bytes))

    def _data(self, hyp: Hypothesis, kept: bytes | tuple[str, str]) -> bytes:
        if isinstance(kept, bytes):
            return kept
        assert self._encode is not None  # only then are bytes dropped
        return self._encode(hyp, *kept)

    def remove(self, hypothesis_id: str) -> None:
        with self._lock:
            del self._entries[hypothesis_id]

    def hypotheses(self, level: str | None = None) -> list[Hypothesis]:
        """All hypotheses (or those of ``level``), oldest first."""
        with self._lock:
            found = [h for h, _ in self._entries.values() if level is None or h.level == level]
        return sorted(found, key=lambda h: (h.timestamp, h.id))

    def select(self, keys: RunKeys, key_expr: str) -> list[tuple[Hypothesis, bytes]]:
        """The entries a read of ``key_expr`` answers with: plain ``<level>/<id>`` chunks or ``*``
        are matched directly, anything else as a zenoh key expression."""
        pattern = keys.hypothesis_pattern(key_expr)
        if pattern is not None:
            level, hyp_id = pattern
            with self._lock:
                return [
                    (h, self._data(h, d))
                    for h, d in self._entries.values()
                    if level in ("*", h.level) and hyp_id in ("*", h.id)
                ]
        selector = zenoh.KeyExpr(str(key_expr))
        with self._lock:
            return [
                (h, self._data(h, d))
                for h, d in self._entries.values()
                if selector.intersects(keys.hypothesis(h.level, h.id))
            ]


@dataclass
class _Held:
    after: dict[str, int]
    handler: Callable[..., Any]
    args: tuple = field(default_factory=tuple)


class Barrier:
    """Requests held until the posts they depend on have been received.

    :attr:`received` counts the posts received from each sender (the node's quiescence check
    reads it too).
    """

    def __init__(self) -> None:
        self.received: Counter[str] = Counter()
        self._held: list[_Held] = []

    def __bool__(self) -> bool:
        return bool(self._held)

    @staticmethod
    def after(agent: str, sent: int, seen: Any) -> dict[str, int]:
        """What must have been received before answering ``agent``: its own ``sent`` posts and,
        of every sender in ``seen`` (a mapping; anything else is ignored), as many as it saw."""
        after = {agent: sent}
        if isinstance(seen, dict):
            for name, n in seen.items():
                if isinstance(name, str) and isinstance(n, int):
                    after[name] = max(n, after.get(name, 0))
        return after

    def received_from(self, sender: str) -> None:
        """Count one post received from ``sender``."""
        self.received[sender] += 1

    def hold(self, after: dict[str, int], handler: Callable[..., Any], *args: Any) -> None:
        """Run ``handler(*args)`` once ``after`` is satisfied (call :meth:`release` after counting)."""
        self._held.append(_Held(after, handler, args))
        self.release()

    def release(self) -> None:
        """Run the held requests that are now ready, in the order they came."""
        if not self._held:
            return
        received = self.received
        ready: list[_Held] = []
        waiting: list[_Held] = []
        for held in self._held:
            (ready if all(received[a] >= n for a, n in held.after.items()) else waiting).append(held)
        if not ready:
            return
        self._held = waiting
        for held in ready:
            held.handler(*held.args)
