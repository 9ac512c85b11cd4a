"""The trace: every blackboard event appended to a msgpack stream, flushed per event.

Each record is a map with at least ``seq`` (node order), ``t`` (``time.time()``), ``kind``
(a :class:`TraceKind` value) and, where they apply, ``agent``, ``level``, ``id``, ``version``,
``links``, ``source``, ``credibility``, ``body`` (large arrays and byte strings summarised by
:func:`summarise`: a trace never holds a large array's bytes, only its shape, dtype, range and a
digest that names the bytes, so a viewframe costs the trace about a hundred bytes), ``reason``,
``message``. :func:`read_trace` reads up to the last complete
record, so the trace of a crashed run still reads.
"""

from __future__ import annotations

import enum
import hashlib
import logging
import threading
import time
from pathlib import Path
from typing import Any, BinaryIO

import msgpack
import numpy as np

from blackboard.errors import TraceError

__all__ = ["TraceKind", "TraceWriter", "read_trace", "summarise", "TraceRecord"]

logger = logging.getLogger(__name__)

TraceRecord = dict[str, Any]

#: arrays with more elements than this are replaced by a summary
ARRAY_INLINE_LIMIT = 16
#: byte/str values longer than this are replaced by a summary
BYTES_INLINE_LIMIT = 256


class TraceKind(str, enum.Enum):
    """The fixed kinds of trace records."""

    RUN_START = "run_start"
    RUN_END = "run_end"
    POST = "post"
    UPDATE = "update"
    RETRACT = "retract"
    ACTIVATION_START = "activation_start"
    ACTIVATION_FINISH = "activation_finish"
    ACTIVATION_ERROR = "activation_error"
    ACTIVATION_OBVIATED = "activation_obviated"
    TIMEOUT = "timeout"
    AGENT_JOIN = "agent_join"
    AGENT_LEAVE = "agent_leave"
    AGENT_DEAD = "agent_dead"
    REJECTED = "rejected"
    QUIESCENT = "quiescent"


def summarise(value: Any, *, depth: int = 0) -> Any:
    """``value`` with large numpy arrays replaced by ``{"__array__": {shape, dtype, min, max,
    digest}}`` (``digest``: BLAKE2b-64 hex of the C-order bytes, the same for equal arrays) and long
    bytes/str by ``{"__bytes__": length}`` / truncated text; msgpack-able."""
    if depth > 32:
        return "<deeper than 32>"
    if isinstance(value, dict):
        return {str(k): summarise(v, depth=depth + 1) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [summarise(v, depth=depth + 1) for v in value]
    if isinstance(value, np.ndarray):
        if value.size <= ARRAY_INLINE_LIMIT and value.dtype.kind in "biuf":
            return value.tolist()
        summary: dict[str, Any] = {"shape": list(value.shape), "dtype": value.dtype.str}
        if value.size and value.dtype.kind in "biuf":
            summary["min"] = float(np.min(value))
            summary["max"] = float(np.max(value))
        if value.dtype.kind != "O":
            summary["digest"] = hashlib.blake2b(np.ascontiguousarray(value).data, digest_size=8).hexdigest()
        return {"__array__": summary}
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value) if len(value) <= BYTES_INLINE_LIMIT else {"__bytes__": len(value)}
    if isinstance(value, str) and len(value) > 4 * BYTES_INLINE_LIMIT:
        return value[: 4 * BYTES_INLINE_LIMIT] + f"... ({len(value)} chars)"
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return repr(value)


class TraceWriter:
    """Append records to ``path`` (created, truncated), one flush per record; thread-safe.

    Raises:
        TraceError: the file cannot be created.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file: BinaryIO | None = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        except OSError as err:
            raise TraceError(self.path, f"cannot create trace: {err.strerror}") from None
        self._packer = msgpack.Packer(use_bin_type=True)
        self._lock = threading.Lock()
        self._seq = 0

    def write(self, kind: TraceKind, **fields: Any) -> None:
        """Append one record of ``kind``; ``body`` is summarised."""
        with self._lock:
            if self._file is None:
                return
            self._seq += 1
            record = {"seq": self._seq, "t": fields.pop("t", None) or time.time(), "kind": kind.value}
            for name, value in fields.items():
                if value is not None:
                    record[name] = summarise(value) if name == "body" else value
            try:
                self._file.write(self._packer.pack(record))
                self._file.flush()
            except (OSError, TypeError, ValueError) as err:
                logger.error("trace %s: cannot write a %s record: %s", self.path, kind.value, err)

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None


def read_trace(path: str | Path) -> list[TraceRecord]:
    """All complete records of a trace file, in order; a truncated last record is ignored.

    Raises:
        TraceError: the file is missing, unreadable, or not a trace (garbage before the end).
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise TraceError(path, f"cannot read trace: {err.strerror}") from None
    unpacker = msgpack.Unpacker(raw=False, strict_map_key=False, max_buffer_size=max(len(data), 1 << 20))
    unpacker.feed(data)
    records: list[TraceRecord] = []
    while True:
        try:
            record = unpacker.unpack()
        except msgpack.OutOfData:
            break  # a truncated last record (crashed run), or the clean end
        except Exception as err:  # malformed bytes
            raise TraceError(path, f"not a trace file: record {len(records) + 1} is malformed ({err})") from None
        if not isinstance(record, dict) or "kind" not in record or "seq" not in record:
            raise TraceError(path, f"not a trace file: record {len(records) + 1} is not a trace record")
        records.append(record)
    return records
