"""Codec: round-trip table, property tests, and every way a message can be refused."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from blackboard.codec import MAX_DEPTH, NDARRAY_EXT, decode, encode
from blackboard.errors import CodecError

_rng = np.random.default_rng(4)

ROUND_TRIP = {
    "scalars": {"i": -3, "f": 2.5, "s": "é", "b": b"\x00\xff", "n": None, "t": True, "big": 2**63},
    "nested": {"a": [1, {"b": [2, {"c": "deep"}]}], "empty": {}, "list": []},
    "float32 image": {"img": _rng.random((4, 5), dtype=np.float32)},
    "uint8 rgb": {"img": _rng.integers(0, 256, (3, 4, 3), dtype=np.uint8)},
    "int64 big-endian": {"a": np.arange(6, dtype=">i8").reshape(2, 3)},
    "bool": {"mask": _rng.random(7) > 0.5},
    "complex": {"z": np.array([1 + 2j, -3j], dtype=np.complex128)},
    "0-d": {"s": np.array(3.5)},
    "empty": {"e": np.zeros((0, 3), dtype=np.float64)},
    "fortran order": {"f": np.asfortranarray(np.arange(12.0).reshape(3, 4))},
    "strided view": {"v": np.arange(20, dtype=np.int16)[::3]},
    "unicode array": {"u": np.array(["house", "tree"])},
    "arrays in lists": {"l": [np.ones(2, dtype=np.float16), {"x": np.eye(2)}]},
}


def _assert_same(a: object, b: object) -> None:
    if isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and b.dtype == a.dtype and b.shape == a.shape
        assert b.flags.c_contiguous and b.flags.writeable
        np.testing.assert_array_equal(a, b)
    elif isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys()
        for k in a:
            _assert_same(a[k], b[k])
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, list) and len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _assert_same(x, y)
    else:
        assert a == b and type(a) is type(b)


@pytest.mark.parametrize("value", ROUND_TRIP.values(), ids=ROUND_TRIP.keys())
def test_round_trip(value: dict) -> None:
    _assert_same(value, decode(encode(value)))


def test_numpy_scalars_become_python_scalars() -> None:
    out = decode(encode({"f": np.float32(1.5), "i": np.int64(7), "b": np.bool_(True)}))
    assert out == {"f": 1.5, "i": 7, "b": True}
    assert type(out["i"]) is int


_leaf = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**63), 2**64 - 1),
    st.floats(allow_nan=False),
    st.text(max_size=20),
    st.binary(max_size=20),
)
_arrays = hnp.arrays(
    dtype=st.one_of(
        hnp.integer_dtypes(),
        hnp.unsigned_integer_dtypes(),
        hnp.floating_dtypes(),
        hnp.boolean_dtypes(),
        hnp.complex_number_dtypes(),
    ),
    shape=hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=4),
)
_values = st.recursive(
    st.one_of(_leaf, _arrays),
    lambda kids: st.one_of(st.lists(kids, max_size=4), st.dictionaries(st.text(max_size=8), kids, max_size=4)),
    max_leaves=12,
)


@settings(max_examples=150, deadline=None)
@given(st.dictionaries(st.text(max_size=8), _values, max_size=5))
def test_round_trip_property(value: dict) -> None:
    out = decode(encode(value))
    assert out.keys() == value.keys()
    assert encode(out) == encode(value)  # canonical: same bytes again (NaN-safe, unlike ==)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_decode_arbitrary_bytes_never_crashes(data: bytes) -> None:
    try:
        decode(data)
    except CodecError:
        pass


def _ext(header: list, raw: bytes, code: int = NDARRAY_EXT) -> bytes:
    return msgpack.packb({"a": msgpack.ExtType(code, msgpack.packb(header) + raw)})


BAD_BYTES = {
    "garbage": b"\xc1\xc1\xc1",
    "truncated": encode({"a": [1, 2, 3]})[:-1],
    "trailing bytes": encode({"a": 1}) + b"\x00",
    "unknown ext": _ext(["<f8", [1]], bytes(8), code=9),
    "object dtype": _ext(["|O", [1]], bytes(8)),
    "void dtype": _ext(["|V4", [1]], bytes(4)),
    "size mismatch": _ext(["<f8", [2, 2]], bytes(8)),
    "negative shape": _ext(["<f8", [-1]], b""),
    "bad header": _ext(["<f8"], bytes(8)),
    "non-str map key": msgpack.packb({1: 2}),
    "too deep": msgpack.packb(eval("[" * (MAX_DEPTH + 2) + "]" * (MAX_DEPTH + 2))),
}


@pytest.mark.parametrize("data", BAD_BYTES.values(), ids=BAD_BYTES.keys())
def test_decode_refuses(data: bytes) -> None:
    with pytest.raises(CodecError) as info:
        decode(data, key="mapinterp/r/x/y")
    assert info.value.key == "mapinterp/r/x/y"


def test_decode_size_limit() -> None:
    data = encode({"a": bytes(1000)})
    assert decode(data, max_bytes=len(data))["a"] == bytes(1000)
    with pytest.raises(CodecError, match="exceeds the limit"):
        decode(data, max_bytes=len(data) - 1)


BAD_VALUES = {
    "object": ({"body": {"x": object()}}, "body.x"),
    "object array": ({"a": [1, np.array([None], dtype=object)]}, "a[1]"),
    "non-str key": ({"m": {3: 1}}, "m.3"),
    "huge int": ({"n": 2**70}, "n"),
    "set": ({"s": {1, 2}}, "s"),
}


@pytest.mark.parametrize(("value", "path"), BAD_VALUES.values(), ids=BAD_VALUES.keys())
def test_encode_names_the_bad_key(value: dict, path: str) -> None:
    with pytest.raises(CodecError) as info:
        encode(value)
    assert info.value.key == path


def test_encode_size_limit() -> None:
    with pytest.raises(CodecError, match="exceeds the limit"):
        encode({"a": np.zeros(1000)}, max_bytes=1000)


def _message(body: dict) -> dict:
    """A post as Board.post builds it: the envelope is ours, the body is the user's (depth 2)."""
    return {"op": "post", "hyp": {"id": "h1", "links": ["a"], "body": body}, "sender": "s", "n": 1}


BODIES = {
    "plain": {"x": 1, "a": np.arange(4, dtype=np.int16), "nested": {"l": [1, [2, {"k": "v"}]]}},
    "non-str key": {"m": {3: 1}},
    "non-str key at the top": {5: 1},
    "too deep": {"d": eval("[" * MAX_DEPTH + "]" * MAX_DEPTH)},
    "just deep enough": {"d": eval("[" * (MAX_DEPTH - 3) + "]" * (MAX_DEPTH - 3))},
    "object": {"x": object()},
    "huge int": {"n": 2**70},
    "dict subclass": {"o": __import__("collections").OrderedDict(a=1)},
}


@pytest.mark.parametrize("body", BODIES.values(), ids=BODIES.keys())
def test_encode_checking_the_body_only_is_the_same(body: dict) -> None:
    """``check=[(body, 2)]`` (what a post uses) gives the same bytes, or the same error, as the full walk."""
    outcomes = []
    for check in (None, [(body, 2)]):
        try:
            outcomes.append(encode(_message(body), check=check))
        except CodecError as err:
            outcomes.append((err.message, err.key))
    assert outcomes[0] == outcomes[1]


def test_encoder_recovers_after_an_error() -> None:
    """The per-thread packer is not reused in an unknown state after a failed encode."""
    good = {"a": [1, 2, {"b": bytes(100)}]}
    expected = encode(good)
    with pytest.raises(CodecError):
        encode({"a": [1, 2, object()]})
    assert encode(good) == expected and decode(expected) == good
