"""A camera frame's query patterns, made once per process and shared by the indices that rank it.

Every associative indexer shard of a mission ranks the same camera frame with the same
preprocessing, and with the memory's roll search (``memory.roll_search_deg``) the frame turned by
each roll: 20 shards at 10,000 viewframes, 5 rolls, 100 turned and preprocessed images a frame
where 5 differ; and each turned image's key (its seed-independent part,
:meth:`models.associative.HolographicMemory.query_phase`: the shards' keys differ only by their
seed's random phase). :class:`QueryPatterns` keeps the patterns of the latest frames, keyed by the
image's bytes (a digest with its shape and dtype: each agent decodes its own copy of a frame's
message), the roll and the preprocessing parameters, so the shards of one process make each
once; shards in other processes make their own (the same numbers: the same function of the same
bytes). A pattern several shards ask for at once is made by the first, the others wait for it.
The patterns handed out are read only.

:data:`SHARED` is the process's cache (:meth:`models.index.ViewframeIndex.query_pattern` uses
it); its size is bounded (:data:`KEEP`).
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["KEEP", "QueryPatterns", "SHARED", "image_digest"]

#: patterns kept (the latest asked for): 8 frames of 5 rolls, each a pattern (64 KB at N = 128)
#: and its key's phase (133 KB)
KEEP = 80


def image_digest(image: NDArray[Any]) -> tuple[bytes, tuple[int, ...], str]:
    """The identity of an image's content: a BLAKE2b digest of its bytes (C order), its shape and dtype."""
    img = np.ascontiguousarray(image)
    return hashlib.blake2b(img.data, digest_size=16).digest(), tuple(img.shape), img.dtype.str


class _Slot:
    """One pattern: made once (``done`` set when ``value`` is there, or its making failed)."""

    __slots__ = ("done", "value")

    def __init__(self) -> None:
        self.done = threading.Event()
        self.value: NDArray[Any] | None = None


class QueryPatterns:
    """A bounded cache of query patterns, safe across threads (the agents of a process).

    ``keep``: how many patterns are kept (the least recently asked for goes first), >= 1.

    Example::

        shared = QueryPatterns()
        p = shared.get(image, key=(settings, roll), make=lambda: index.pattern(rolled(image, roll)))
    """

    def __init__(self, *, keep: int = KEEP) -> None:
        if isinstance(keep, bool) or not isinstance(keep, int) or keep < 1:
            raise ValueError(f"keep must be an integer >= 1, got {keep!r}")
        self.keep = keep
        self._lock = threading.Lock()
        self._slots: OrderedDict[Hashable, _Slot] = OrderedDict()
        #: patterns made here / handed out again (for tests and benchmarks)
        self.made = 0
        self.hits = 0

    def __len__(self) -> int:
        return len(self._slots)

    def clear(self) -> None:
        """Forget every pattern."""
        with self._lock:
            self._slots.clear()

    def get(
        self,
        image: NDArray[Any],
        *,
        key: Hashable,
        make: Callable[[], NDArray[Any]],
        digest: Hashable | None = None,
    ) -> NDArray[Any]:
        """The pattern of ``image`` (H, W[, C], indexed (row, col)) under ``key`` (what else decides
        it: the preprocessing parameters, the roll), made by ``make()`` when it is not held. The
        same array to every caller (read only). An error of ``make`` reaches its caller; callers
        waiting for it make the pattern themselves. ``digest``: :func:`image_digest` of ``image``,
        when the caller has it (not made again)."""
        full = (image_digest(image) if digest is None else digest, key)
        with self._lock:
            slot = self._slots.get(full)
            mine = slot is None
            if slot is None:
                slot = self._slots[full] = _Slot()
                while len(self._slots) > self.keep:
                    self._slots.popitem(last=False)
            else:
                self._slots.move_to_end(full)
        if not mine:
            slot.done.wait()
            if slot.value is not None:
                with self._lock:
                    self.hits += 1
                return slot.value
            return self._made(make)  # its maker failed: this caller's own error, if any
        try:
            value = self._made(make)
            slot.value = value
            return value
        finally:
            if slot.value is None:
                with self._lock:
                    if self._slots.get(full) is slot:
                        del self._slots[full]
            slot.done.set()

    def _made(self, make: Callable[[], NDArray[Any]]) -> NDArray[Any]:
        value = np.asarray(make())
        value.setflags(write=False)
        with self._lock:
            self.made += 1
        return value


#: the process's shared query patterns
SHARED = QueryPatterns()
