"""msgpack payloads with numpy arrays, without pickle, with size limits.

A numpy array travels as msgpack ExtType :data:`NDARRAY_EXT`; its data is a small msgpack
header ``[dtype.str, shape]`` followed by the raw C-order bytes. Only plain dtypes
(bool, integer, float, complex, fixed bytes/str) are accepted: never ``object``, so decoding
cannot run code. numpy scalars become Python scalars, tuples become lists.

Example::

    >>> import numpy as np
    >>> decode(encode({"a": np.arange(3, dtype=np.int16)}))["a"].dtype
    dtype('int16')
"""

from __future__ import annotations

import threading
from collections.abc import Iterable
from typing import Any

import msgpack
import numpy as np

from blackboard.errors import CodecError

__all__ = ["encode", "decode", "NDARRAY_EXT", "DEFAULT_MAX_BYTES", "MAX_DEPTH"]

NDARRAY_EXT = 1
#: default limit of one message (64 MiB)
DEFAULT_MAX_BYTES = 64 * 1024 * 1024
#: nesting limit of maps and lists
MAX_DEPTH = 32
_MAX_NDIM = 32
_KINDS = frozenset("biufcSU")
_CONTAINERS = (dict, list, tuple)


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in _KINDS or obj.dtype.fields is not None:
            raise TypeError(f"numpy dtype {obj.dtype} is not supported (plain numeric, bool, S, U only)")
        header = msgpack.packb([obj.dtype.str, list(obj.shape)])
        return msgpack.ExtType(NDARRAY_EXT, header + obj.tobytes(order="C"))
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot encode {type(obj).__name__}")


def _find_bad(obj: Any, path: str, depth: int = 0) -> tuple[str, str] | None:
    """The path of the first value that cannot be encoded, and why."""
    if depth > MAX_DEPTH:
        return path, f"nesting deeper than {MAX_DEPTH}"
    if isinstance(obj, dict):
        for k, v in obj.items():
            if not isinstance(k, str):
                return f"{path}.{k!r}" if path else repr(k), f"map key must be str, got {type(k).__name__}"
            found = _find_bad(v, f"{path}.{k}" if path else k, depth + 1)
            if found:
                return found
        return None
    if isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            found = _find_bad(v, f"{path}[{i}]", depth + 1)
            if found:
                return found
        return None
    if obj is None or isinstance(obj, (bool, int, float, str, bytes, bytearray, np.generic)):
        if isinstance(obj, int) and not isinstance(obj, bool) and not -(2**63) <= obj < 2**64:
            return path, "integer out of the 64-bit range"
        return None
    if isinstance(obj, np.ndarray):
        try:
            _default(obj)
        except TypeError as err:
            return path, str(err)
        return None
    return path, f"cannot encode {type(obj).__name__}"


_local = threading.local()


def _packer() -> msgpack.Packer:
    """This thread's reusable packer (a Packer is not thread-safe; making one per call costs
    as much as packing a 1 KB message)."""
    packer = getattr(_local, "packer", None)
    if packer is None:
        packer = _local.packer = msgpack.Packer(default=_default, use_bin_type=True, strict_types=False)
    return packer


def encode(obj: Any, *, max_bytes: int = DEFAULT_MAX_BYTES, check: Iterable[tuple[Any, int]] | None = None) -> bytes:
    """Encode nested dicts/lists/scalars/bytes/numpy arrays to msgpack bytes.

    ``check``: the parts of ``obj`` that may hold non-str map keys or deep nesting, each with
    its depth in ``obj`` (e.g. ``[(body, 2)]`` for a message whose envelope the caller built
    from str keys); None checks all of ``obj``. Errors are the same either way.

    Raises:
        CodecError: an unsupported value (``.key`` is its path, e.g. ``body.image``), map keys
            that are not str, nesting deeper than :data:`MAX_DEPTH`, or a result over ``max_bytes``.
    """
    try:
        data = _packer().pack(obj)
    except (TypeError, ValueError, OverflowError) as err:
        _local.packer = None  # never reuse a packer an error left in an unknown state
        found = _find_bad(obj, "")
        key, why = found if found else (None, str(err))
        raise CodecError(f"cannot encode: {why}", key=key or None) from None
    if check is None:
        ok = _containers_ok(obj, 0, True)
    else:  # as the walk of all of obj would see them: only exact dict/list/tuple are visited inside
        ok = True
        for part, depth in check:
            if type(part) in _CONTAINERS and not _containers_ok(part, depth, True):
                ok = False
                break
    if not ok:
        # non-str map keys, too deep: msgpack itself would accept them
        found = _find_bad(obj, "")
        key, why = found if found else (None, "invalid structure")
        raise CodecError(f"cannot encode: {why}", key=key or None)
    if len(data) > max_bytes:
        raise CodecError(f"encoded size {len(data)} bytes exceeds the limit of {max_bytes} bytes")
    return data


def _containers_ok(obj: Any, depth: int, keys: bool) -> bool:
    """True if maps have str keys (when ``keys``) and nesting is within :data:`MAX_DEPTH`;
    visits containers only (the hot path of every message)."""
    if depth > MAX_DEPTH:
        return False
    kind = type(obj)
    if kind is dict:
        if keys:
            for k in obj:
                if type(k) is not str:
                    return False
        obj = obj.values()
    elif kind is not list and kind is not tuple:
        if isinstance(obj, (dict, list, tuple)):  # subclasses: the slow, general walk
            return _find_bad(obj, "") is None  # (only ever at the top: nested ones are exact types)
        return True
    depth += 1
    for v in obj:
        kind = type(v)
        if (kind is dict or kind is list or kind is tuple) and not _containers_ok(v, depth, keys):
            return False
    return True


def _ext_hook(code: int, data: bytes) -> Any:
    if code != NDARRAY_EXT:
        raise ValueError(f"unknown msgpack extension type {code}")
    unpacker = msgpack.Unpacker(max_buffer_size=len(data) + 1, raw=False, max_array_len=_MAX_NDIM + 2)
    unpacker.feed(data)
    header = unpacker.unpack()
    offset = unpacker.tell()
    if not (
        isinstance(header, list) and len(header) == 2 and isinstance(header[0], str) and isinstance(header[1], list)
    ):
        raise ValueError("malformed ndarray header")
    dtype = np.dtype(header[0])
    shape = header[1]
    if dtype.kind not in _KINDS or dtype.fields is not None:
        raise ValueError(f"ndarray dtype {dtype} is not allowed")
    if len(shape) > _MAX_NDIM or not all(isinstance(n, int) and n >= 0 for n in shape):
        raise ValueError(f"malformed ndarray shape {shape!r}")
    count = int(np.prod(shape, dtype=np.int64))
    if count * dtype.itemsize != len(data) - offset:
        raise ValueError(f"ndarray data is {len(data) - offset} bytes, shape {shape} of {dtype} needs another size")
    # one copy (the array owns its bytes, writable), straight from the extension's buffer
    return np.frombuffer(data, dtype=dtype, count=count, offset=offset).reshape(tuple(shape)).copy()


def decode(data: bytes, *, max_bytes: int = DEFAULT_MAX_BYTES, key: str | None = None) -> Any:
    """Decode bytes made by :func:`encode`; arrays come back writable, C-order.

    Raises:
        CodecError: malformed bytes, an unknown extension, trailing bytes, nesting deeper than
            :data:`MAX_DEPTH`, or more than ``max_bytes`` (``.key`` is ``key``).
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise CodecError(f"expected bytes, got {type(data).__name__}", key=key)
    if len(data) > max_bytes:
        raise CodecError(f"message of {len(data)} bytes exceeds the limit of {max_bytes} bytes", key=key)
    try:
        obj = msgpack.unpackb(
            data,
            raw=False,
            ext_hook=_ext_hook,
            strict_map_key=True,
            use_list=True,
        )
    except Exception as err:  # msgpack raises many types (ExtraData, ValueError, UnpackValueError, ...)
        raise CodecError(f"malformed message: {type(err).__name__}: {err}", key=key) from None
    if not _containers_ok(obj, 0, False):
        raise CodecError(f"message nested deeper than {MAX_DEPTH}", key=key)
    return obj
