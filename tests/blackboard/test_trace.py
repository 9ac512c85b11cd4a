"""Trace files: writing, reading, truncated (crashed) files, summaries of large values."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from blackboard.errors import TraceError
from blackboard.trace import TraceKind, TraceWriter, read_trace, summarise


def _write(path: Path, n: int) -> None:
    writer = TraceWriter(path)
    for i in range(n):
        writer.write(
            TraceKind.POST, agent="a", level="l", id=f"h{i}", version=1, body={"i": i, "img": np.ones((50, 50))}
        )
    writer.close()


def test_write_read(tmp_path: Path) -> None:
    path = tmp_path / "t.trace"
    _write(path, 5)
    records = read_trace(path)
    assert [r["id"] for r in records] == [f"h{i}" for i in range(5)]
    assert [r["seq"] for r in records] == [1, 2, 3, 4, 5]
    assert records[0]["body"]["img"] == {
        "__array__": {"shape": [50, 50], "dtype": "<f8", "min": 1.0, "max": 1.0, "digest": _digest(np.ones((50, 50)))}
    }


def test_every_truncation_reads_up_to_the_last_complete_record(tmp_path: Path) -> None:
    path = tmp_path / "t.trace"
    _write(path, 3)
    data = path.read_bytes()
    ends = [len(data) * 0]
    full = len(read_trace(path))
    assert full == 3
    for cut in range(len(data)):
        path.write_bytes(data[:cut])
        n = len(read_trace(path))
        assert n < full
        ends.append(n)
    assert ends == sorted(ends) and ends[-1] == 2


@pytest.mark.parametrize("data", [b"\xc1\xc1garbage", b"\x93\x01\x02\x03", b"\x81\xa1a\x01"])
def test_not_a_trace(tmp_path: Path, data: bytes) -> None:
    path = tmp_path / "bad.trace"
    path.write_bytes(data)
    with pytest.raises(TraceError, match="bad.trace"):
        read_trace(path)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(TraceError, match="cannot read"):
        read_trace(tmp_path / "nope.trace")


def _digest(a: np.ndarray) -> str:
    return hashlib.blake2b(np.ascontiguousarray(a).tobytes(), digest_size=8).hexdigest()


def test_large_arrays_are_a_digest_not_their_bytes(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    image = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
    other = image.copy()
    other[5, 7, 1] ^= 1
    path = tmp_path / "t.trace"
    writer = TraceWriter(path)
    for i, img in enumerate((image, image.copy(), other, np.asfortranarray(image))):
        writer.write(TraceKind.POST, agent="a", level="viewframe", id=f"vf{i}", body={"image": img})
    writer.close()
    assert path.stat().st_size < 2000  # four 57 KB images, no bytes of them
    digests = [r["body"]["image"]["__array__"]["digest"] for r in read_trace(path)]
    assert digests[0] == digests[1] == digests[3] != digests[2]  # equal content, equal digest (any memory order)


SUMMARIES = {
    "small array inline": (np.arange(3), [0, 1, 2]),
    "large array": (
        np.zeros((4, 5), np.uint8),
        {
            "__array__": {
                "shape": [4, 5],
                "dtype": "|u1",
                "min": 0.0,
                "max": 0.0,
                "digest": _digest(np.zeros((4, 5), np.uint8)),
            }
        },
    ),
    "string array": (
        np.array(["a", "b"]),
        {"__array__": {"shape": [2], "dtype": "<U1", "digest": _digest(np.array(["a", "b"]))}},
    ),
    "small bytes": (b"ab", b"ab"),
    "large bytes": (bytes(1000), {"__bytes__": 1000}),
    "nested": ({"a": [np.float32(2.5), None]}, {"a": [2.5, None]}),
    "object": ({1, 2}, "{1, 2}"),
}


@pytest.mark.parametrize(("value", "expected"), SUMMARIES.values(), ids=SUMMARIES.keys())
def test_summarise(value: object, expected: object) -> None:
    assert summarise(value) == expected
