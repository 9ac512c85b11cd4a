"""Query patterns shared by the indices of a process: made once per image, key and process."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from models.query_patterns import QueryPatterns, image_digest


def _image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 255, (24, 32, 3), dtype=np.uint8)


def test_the_same_bytes_under_the_same_key_are_made_once() -> None:
    shared = QueryPatterns()
    made: list[int] = []

    def make(v: float) -> np.ndarray:
        made.append(1)
        return np.full((4, 4), v, dtype=np.float32)

    img = _image(1)
    first = shared.get(img, key=("a", 0.0), make=lambda: make(1.0))
    again = shared.get(img.copy(), key=("a", 0.0), make=lambda: make(2.0))  # another copy of the same bytes
    assert again is first and len(made) == 1 and (shared.made, shared.hits) == (1, 1)
    assert not first.flags.writeable
    other_key = shared.get(img, key=("a", 1.5), make=lambda: make(3.0))
    other_image = shared.get(_image(2), key=("a", 0.0), make=lambda: make(4.0))
    assert float(other_key[0, 0]) == 3.0 and float(other_image[0, 0]) == 4.0 and len(made) == 3


def test_the_image_identity_is_its_bytes_shape_and_dtype() -> None:
    img = _image(3)
    assert image_digest(img) == image_digest(img.copy())
    assert image_digest(img) != image_digest(img.reshape(32, 24, 3))
    assert image_digest(img) != image_digest(img.astype(np.uint16))
    changed = img.copy()
    changed[5, 7, 1] ^= 1
    assert image_digest(changed) != image_digest(img)
    assert image_digest(img[:, ::2]) == image_digest(np.ascontiguousarray(img[:, ::2]))  # a view: its content


def test_the_cache_is_bounded_by_the_least_recently_asked_for() -> None:
    shared = QueryPatterns(keep=2)
    images = [_image(s) for s in range(3)]
    for im in images[:2]:
        shared.get(im, key=0, make=lambda: np.zeros(2, np.float32))
    shared.get(images[0], key=0, make=lambda: np.ones(2, np.float32))  # asked again: kept longest
    shared.get(images[2], key=0, make=lambda: np.zeros(2, np.float32))  # the second one goes
    assert len(shared) == 2 and shared.made == 3
    shared.get(images[0], key=0, make=lambda: np.ones(2, np.float32))
    assert shared.made == 3
    shared.get(images[1], key=0, make=lambda: np.ones(2, np.float32))
    assert shared.made == 4
    shared.clear()
    assert len(shared) == 0


def test_callers_at_once_wait_for_the_first_ones_pattern() -> None:
    """Threads asking for one pattern at once: it is made by one of them, all get the same array."""
    shared = QueryPatterns()
    img = _image(4)
    started = threading.Event()
    release = threading.Event()
    calls: list[int] = []

    def make() -> np.ndarray:
        calls.append(1)
        started.set()
        assert release.wait(10)
        return np.arange(6, dtype=np.float32)

    got: list[np.ndarray] = []
    first = threading.Thread(target=lambda: got.append(shared.get(img, key="k", make=make)))
    first.start()
    assert started.wait(10)  # the first caller is making it
    others = [threading.Thread(target=lambda: got.append(shared.get(img, key="k", make=make))) for _ in range(5)]
    for t in others:
        t.start()
    release.set()
    for t in [first, *others]:
        t.join(10)
    assert len(got) == 6 and all(g is got[0] for g in got) and len(calls) == 1


def test_a_failed_pattern_is_not_kept_and_its_error_reaches_the_caller() -> None:
    shared = QueryPatterns()
    img = _image(5)

    def fail() -> np.ndarray:
        raise ValueError("image must have shape (H, W)")

    with pytest.raises(ValueError, match="shape"):
        shared.get(img, key=0, make=fail)
    assert len(shared) == 0
    assert shared.get(img, key=0, make=lambda: np.ones(3, np.float32)).tolist() == [1.0, 1.0, 1.0]


@pytest.mark.parametrize("keep", [0, -1, 1.5, True])
def test_keep_must_be_a_positive_integer(keep) -> None:
    with pytest.raises(ValueError, match="keep"):
        QueryPatterns(keep=keep)
