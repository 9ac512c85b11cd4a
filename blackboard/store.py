"""The node's store of hypotheses, and the barrier that lets reads and changes see every post their
requester has seen.

:class:`Store` holds the current version of every hypothesis with the encoded message that carried
it (a read is answered with those bytes, not re-encoded). A large message (a viewframe's image,
mask and background) is not kept decoded: given an ``unpack`` function, the store keeps a message
of :data:`KEEP_BYTES_BELOW` bytes or more only as its bytes compressed with zlib (rendered views
compress several times over; incompressible bytes cost only the time), answers a read with the
decompressed message, and decodes the hypothesis again when asked for it (:meth:`Store.get`;
:meth:`Store.hypotheses` lists such an entry as a hypothesis whose body is decoded each time it
is read, never kept). Reads of large hypotheses are rare: late joiners and on-demand fetches. It
is written by the node's worker thread only; readers in other threads (the runtime) take its lock.

:class:`Barrier` holds requests (reads, updates, retractions) until the node has received the
posts their requester had sent, and those it had seen from other senders: an agent that updates a
post it just received never finds the node without it, and an agent that joins late and reads the
store finds everything posted before. Posts travel one hop (producer to consumers and the node at
once), so the node counts what it received from each sender and the requester says what it sent
and saw.
"""

from __future__ import annotations

import dataclasses
import threading
import zlib
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import zenoh

from blackboard.hypothesis import Hypothesis

if TYPE_CHECKING:
    from blackboard.keys import RunKeys

__all__ = ["Barrier", "KEEP_BYTES_BELOW", "PackedHypothesis", "Store"]

#: messages of this many bytes or more are kept compressed when the store can decode them again
KEEP_BYTES_BELOW = 16384
#: zlib level of the compressed messages (1: fastest; rendered views shrink about tenfold already)
ZLIB_LEVEL = 1


class _Packed:
    """A large message as the store holds it: the hypothesis's fields but its body, and the
    compressed message."""

    __slots__ = ("fields", "data")

    def __init__(self, hyp: Hypothesis, data: bytes) -> None:
        self.fields = {k: v for k, v in hyp.__dict__.items() if k != "body"}
        self.data = zlib.compress(data, ZLIB_LEVEL)

    @property
    def level(self) -> str:
        return self.fields["level"]

    @property
    def id(self) -> str:
        return self.fields["id"]

    def message(self) -> bytes:
        return zlib.decompress(self.data)


class PackedHypothesis(Hypothesis):
    """A stored hypothesis whose body is decoded from the store's compressed message each time it
    is read (listings of the store keep no decoded copy of a large body); equal to the
    :class:`~blackboard.hypothesis.Hypothesis` it stands for."""

    @property
    def body(self) -> dict:
        d = self.__dict__
        if "body" in d:  # set by a constructor (dataclasses.replace): an ordinary hypothesis
            return d["body"]
        return d["_unpack"](d["_packed"].message()).body

    @body.setter
    def body(self, value: dict) -> None:
        self.__dict__["body"] = value

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Hypothesis):
            return NotImplemented
        return all(getattr(self, f) == getattr(other, f) for f in _COMPARED)

    __hash__ = Hypothesis.__hash__


_COMPARED = tuple(f.name for f in dataclasses.fields(Hypothesis) if f.compare)


def _lazy(packed: _Packed, unpack: Callable[[bytes], Hypothesis]) -> Hypothesis:
    hyp = object.__new__(PackedHypothesis)
    hyp.__dict__.update(packed.fields)
    hyp.__dict__["_packed"] = packed
    hyp.__dict__["_unpack"] = unpack
    return hyp


def _level(entry: tuple[Hypothesis, bytes] | _Packed) -> str:
    return entry.level if isinstance(entry, _Packed) else entry[0].level


def _id(entry: tuple[Hypothesis, bytes] | _Packed) -> str:
    return entry.id if isinstance(entry, _Packed) else entry[0].id


class Store:
    """Hypotheses by id, each with its encoded message; versions are assigned by the node
    (:meth:`Hypothesis.evolve`), this keeps the current one.

    ``unpack(data)`` (optional) decodes a message into the hypothesis it carries: with it, large
    messages are kept compressed only (see the module docstring); without it every message is
    kept as it came, beside its hypothesis.
    """

    def __init__(self, unpack: Callable[[bytes], Hypothesis] | None = None) -> None:
        self._entries: dict[str, tuple[Hypothesis, bytes] | _Packed] = {}
        self._unpack = unpack
        self._lock = threading.Lock()

    def __contains__(self, hypothesis_id: object) -> bool:
        return hypothesis_id in self._entries

    def __len__(self) -> int:
        return len(self._entries)

    def get(self, hypothesis_id: object) -> Hypothesis | None:
        """The current version of a hypothesis, or None (also for a non-str id)."""
        entry = self._entries.get(hypothesis_id) if isinstance(hypothesis_id, str) else None
        if entry is None:
            return None
        if isinstance(entry, _Packed):
            assert self._unpack is not None  # only then are messages packed
            return self._unpack(entry.message())
        return entry[0]

    def put(self, hyp: Hypothesis, data: bytes, *, op: str = "post", sender: str | None = None) -> int:
        """Store a new hypothesis, or the next version of one; ``data`` is the message (``op``,
        ``sender``) that carried it (kept beside the hypothesis, or alone and compressed when
        large and ``sender`` is given: then ``data`` must carry ``hyp`` in the clear).
        Returns the bytes of message kept (the compressed size for a large one)."""
        entry: tuple[Hypothesis, bytes] | _Packed = (hyp, data)
        kept = len(data)
        if self._unpack is not None and sender is not None and len(data) >= KEEP_BYTES_BELOW:
            entry = _Packed(hyp, data)
            kept = len(entry.data)
        with self._lock:
            self._entries[hyp.id] = entry
        return kept

    def kept_bytes(self) -> int:
        """Bytes of messages held (compressed, for the large ones; see the module docstring)."""
        with self._lock:
            return sum(len(e.data) if isinstance(e, _Packed) else len(e[1]) for e in self._entries.values())

    def decoded_ids(self) -> list[str]:
        """The ids of the hypotheses held decoded (those of small messages)."""
        with self._lock:
            return [k for k, e in self._entries.items() if not isinstance(e, _Packed)]

    def _pair(self, entry: tuple[Hypothesis, bytes] | _Packed) -> tuple[Hypothesis, bytes]:
        if isinstance(entry, _Packed):
            assert self._unpack is not None
            return _lazy(entry, self._unpack), entry.message()
        return entry

    def _listed(self, entry: tuple[Hypothesis, bytes] | _Packed) -> Hypothesis:
        if isinstance(entry, _Packed):
            assert self._unpack is not None
            return _lazy(entry, self._unpack)
        return entry[0]

    def listed(self, hypothesis_id: str) -> Hypothesis | None:
        """The current version of a hypothesis as a listing gives it (a large message's body
        decoded from the store's compressed message when read), or None."""
        with self._lock:
            entry = self._entries.get(hypothesis_id)
        return None if entry is None else self._listed(entry)

    def remove(self, hypothesis_id: str) -> None:
        with self._lock:
            del self._entries[hypothesis_id]

    def hypotheses(self, level: str | None = None) -> list[Hypothesis]:
        """All hypotheses (or those of ``level``), oldest first (those of large messages decode
        their body when it is read)."""
        with self._lock:
            found = [self._listed(e) for e in self._entries.values() if level is None or _level(e) == level]
        return sorted(found, key=lambda h: (h.timestamp, h.id))

    def select(self, keys: RunKeys, key_expr: str) -> list[tuple[Hypothesis, bytes]]:
        """The entries a read of ``key_expr`` answers with: plain ``<level>/<id>`` chunks or ``*``
        are matched directly, anything else as a zenoh key expression."""
        pattern = keys.hypothesis_pattern(key_expr)
        if pattern is not None:
            level, hyp_id = pattern
            with self._lock:
                return [
                    self._pair(e)
                    for e in self._entries.values()
                    if level in ("*", _level(e)) and hyp_id in ("*", _id(e))
                ]
        selector = zenoh.KeyExpr(str(key_expr))
        with self._lock:
            return [
                self._pair(e) for e in self._entries.values() if selector.intersects(keys.hypothesis(_level(e), _id(e)))
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
