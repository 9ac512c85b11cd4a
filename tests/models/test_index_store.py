"""Stored viewframe indices: a loaded index ranks exactly as a freshly built one; any change of
what determines it is a miss; a corrupt one is rebuilt; a cache folder that cannot be written
keeps the index in memory; two processes storing one index at once leave one good copy."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np
import pytest

from models import index_store
from models.index import ViewframeIndex
from models.index_store import INDEX_FOLDER, cached_index, index_key, load_index, store_index
from models.scenario import MemorySpec
from models.synthetic import scene
from tests.models import children

ROOT = Path(__file__).resolve().parents[2]
COUNT = 11


def _images(seed: int = 7, count: int = COUNT, featureless: tuple[int, ...] = ()) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    images = [scene(rng) for _ in range(count)]
    for k in featureless:
        images[k] = np.zeros_like(images[k])  # constant: featureless
    return images


def _entry(tmp_path: Path, images: list[np.ndarray], name: str = "e" * 64) -> Path:
    """A viewframe cache entry's folder as the cache writes it (meta.json, image.npy)."""
    entry = tmp_path / name
    entry.mkdir()
    np.save(entry / "image.npy", np.stack(images))
    (entry / "meta.json").write_text(json.dumps({"count": len(images)}))
    return entry


def _stored(entry: Path) -> list[Path]:
    return sorted((entry / INDEX_FOLDER).iterdir()) if (entry / INDEX_FOLDER).exists() else []


def _mapped(a: np.ndarray) -> bool:
    """``a`` views a memory map."""
    while isinstance(a, np.ndarray) and not isinstance(a, np.memmap):
        a = a.base
    return isinstance(a, np.memmap)


def _alike(got, want) -> None:
    """Two rankings of one query by indices built apart: the same viewframes with the same
    variances to float32 rounding (two builds may differ in the last bits of preprocessing:
    test_index.py), the same best."""
    assert got.best == want.best
    order = np.argsort(got.viewframes)
    np.testing.assert_array_equal(got.viewframes[order], np.sort(want.viewframes))
    np.testing.assert_allclose(got.variances[order], want.variances[np.argsort(want.viewframes)], rtol=1e-5, atol=1e-9)


def _never() -> list[np.ndarray]:
    raise AssertionError("a stored index must not read the images")


@pytest.mark.parametrize("bank_size", [1, 2, 4])
@pytest.mark.parametrize("max_shift", [(0, 0), (2, 3)])
@pytest.mark.parametrize("featureless", [(), (3,)])
def test_a_loaded_index_ranks_exactly_as_a_fresh_one(tmp_path, bank_size, max_shift, featureless) -> None:
    images = _images(featureless=featureless)
    spec = MemorySpec(size=32, bank_size=bank_size, max_shift=max_shift)
    viewframes = [10 + 2 * k for k in range(COUNT)]  # a shard's share, not 0..n-1
    fresh = ViewframeIndex(spec, seed=3)
    fresh.add(images, viewframes)
    entry = _entry(tmp_path, images)
    key = index_key(spec, viewframes, seed=3, entry=entry)
    assert store_index(fresh, entry, key) is not None
    loaded = load_index(entry, key, spec, seed=3)
    assert loaded is not None
    rows = loaded.memory.ranking_matrix
    assert not rows.flags.writeable and _mapped(rows)  # memory-mapped, read-only
    assert loaded.featureless == fresh.featureless == [viewframes[k] for k in featureless]
    np.testing.assert_array_equal(loaded.viewframes, fresh.viewframes)
    # one pattern per query for both (two preprocessings of an image may differ in the last bits)
    queries = [fresh.pattern(q) for q in [*_images(seed=8, count=3), images[5]]]
    for q in queries:
        for among in (None, viewframes[4:9]):
            want, got = fresh.rank_pattern(q, among=among), loaded.rank_pattern(q, among=among)
            np.testing.assert_array_equal(got.viewframes, want.viewframes)
            np.testing.assert_array_equal(got.variances, want.variances)  # bit for bit
            assert got.reliability == want.reliability
    assert loaded.rank(images[5]).best == viewframes[5]


@pytest.mark.parametrize("bank_size", [1, 3])
def test_cached_index_builds_stores_then_loads_without_the_images(tmp_path, bank_size) -> None:
    images = _images(featureless=(0,))
    spec = MemorySpec(size=32, bank_size=bank_size, max_shift=(2, 3))
    entry = _entry(tmp_path, images)
    fresh = ViewframeIndex(spec, seed=1)
    fresh.add(images, range(COUNT))
    built, hit = cached_index(entry, spec, range(COUNT), seed=1, images=lambda: iter(images))
    assert not hit and len(_stored(entry)) == 1 and _mapped(built.memory.ranking_matrix)  # used from its file
    loaded, hit = cached_index(entry, spec, range(COUNT), seed=1, images=_never)
    assert hit and loaded.featureless == [0]
    for q in [fresh.pattern(im) for im in [*_images(seed=9, count=2), images[4]]]:
        a, b, c = fresh.rank_pattern(q), built.rank_pattern(q), loaded.rank_pattern(q)
        np.testing.assert_array_equal(b.variances, c.variances)
        np.testing.assert_array_equal(b.viewframes, c.viewframes)
        _alike(c, a)
    assert loaded.rank(images[4]).best == 4


def test_a_loaded_index_takes_more_viewframes_without_touching_its_file(tmp_path) -> None:
    images = _images(count=6)
    spec = MemorySpec(size=32, bank_size=2, max_shift=(1, 1))
    entry = _entry(tmp_path, images[:4])
    cached_index(entry, spec, range(4), seed=0, images=lambda: iter(images[:4]))
    loaded, hit = cached_index(entry, spec, range(4), seed=0, images=_never)
    (folder,) = _stored(entry)
    before = (folder / "rows.npy").read_bytes()
    loaded.add(images[4:], [4, 5])
    fresh = ViewframeIndex(spec, seed=0)
    fresh.add(images, range(6))
    assert hit and (folder / "rows.npy").read_bytes() == before
    _alike(loaded.rank(images[1]), fresh.rank(images[1]))


BASE = {"size": 32, "bank_size": 2, "max_shift": (1, 2)}


@pytest.mark.parametrize(
    "change, miss",
    [
        ({"size": 64}, True),
        ({"edge": "laplacian"}, True),
        ({"blur_sigma": 2.0}, True),
        ({"whiten": False}, True),
        ({"bank_size": 3}, True),
        ({"max_shift": (1, 3)}, True),
        ({"key": "quantized"}, True),
        ({"seed": 1}, True),
        ({"viewframes": [0, 1, 2, 4]}, True),  # another membership
        ({"viewframes": [1, 0, 2, 3]}, True),  # another storage order
        ({"version": 2}, True),  # INDEX_VERSION
        ({"source": "changed"}, True),  # the code that builds it
        ({"entry": "other"}, True),  # another viewframe cache entry
        ({"images": "touched"}, True),  # the entry's image file replaced
        ({"weight": 2.0}, False),  # settings that decide what is ranked, not what is stored
        ({"window_margin": 3, "window_full_every": 5, "window_route_points": 9}, False),
        ({"shard_size": 7}, False),
        ({}, False),
    ],
)
def test_what_changes_the_index_is_a_miss(tmp_path, monkeypatch, change, miss) -> None:
    images = _images(count=4)
    entry = _entry(tmp_path, images)
    cached_index(entry, MemorySpec(**BASE), [0, 1, 2, 3], seed=0, images=lambda: iter(images))
    change = dict(change)
    viewframes = change.pop("viewframes", [0, 1, 2, 3])
    seed = change.pop("seed", 0)
    if "version" in change:
        monkeypatch.setattr(index_store, "INDEX_VERSION", change.pop("version"))
    if "source" in change:
        digest = index_store._source_digest() + change.pop("source")
        monkeypatch.setattr(index_store, "_source_digest", lambda: digest)
    if change.pop("entry", None):
        entry = entry.rename(tmp_path / ("f" * 64))
    if change.pop("images", None):
        np.save(entry / "image.npy", np.stack(images))
        os.utime(entry / "image.npy", ns=(1, 1))
    byimage = dict(zip([0, 1, 2, 3], images))
    read: list[int] = []

    def source():
        for k in viewframes:
            read.append(k)
            yield byimage.get(k, images[3])

    _, hit = cached_index(entry, MemorySpec(**{**BASE, **change}), viewframes, seed=seed, images=source)
    assert hit is (not miss) and bool(read) is miss
    assert len(_stored(entry)) == (2 if miss else 1)


@pytest.mark.parametrize(
    "damage",
    ["truncate rows", "garbage meta", "no viewframes file", "wrong count", "bank rows", "float64 rows"],
)
def test_a_corrupt_stored_index_is_rebuilt_with_a_warning(tmp_path, caplog, damage) -> None:
    images = _images(count=5)
    spec = MemorySpec(**BASE)
    entry = _entry(tmp_path, images)
    cached_index(entry, spec, range(5), seed=0, images=lambda: iter(images))
    (folder,) = _stored(entry)
    if damage == "truncate rows":
        data = (folder / "rows.npy").read_bytes()
        (folder / "rows.npy").write_bytes(data[: len(data) // 2])
    elif damage == "garbage meta":
        (folder / "meta.json").write_text("{not json")
    elif damage == "no viewframes file":
        (folder / "viewframes.npy").unlink()
    elif damage == "wrong count":
        meta = json.loads((folder / "meta.json").read_text())
        (folder / "meta.json").write_text(json.dumps({**meta, "count": 9}))
    elif damage == "bank rows":
        np.save(folder / "bank_rows.npy", np.array([5], dtype=np.int64))  # > bank_size 2
    else:
        np.save(folder / "rows.npy", np.load(folder / "rows.npy").astype(np.float64))
    with caplog.at_level(logging.WARNING, logger="models.index_store"):
        index, hit = cached_index(entry, spec, range(5), seed=0, images=lambda: iter(images))
    assert not hit and "unreadable" in caplog.text and str(folder) in caplog.text
    fresh = ViewframeIndex(spec, seed=0)
    fresh.add(images, range(5))
    _alike(index.rank(images[2]), fresh.rank(images[2]))
    again, hit = cached_index(entry, spec, range(5), seed=0, images=_never)  # the rebuilt one replaced it
    assert hit and _stored(entry) == [folder]
    _alike(again.rank(images[2]), fresh.rank(images[2]))


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_cache_keeps_the_index_in_memory(tmp_path, caplog) -> None:
    images = _images(count=4)
    entry = _entry(tmp_path, images)
    entry.chmod(0o555)
    try:
        with caplog.at_level(logging.WARNING, logger="models.index_store"):
            index, hit = cached_index(entry, MemorySpec(**BASE), range(4), seed=0, images=lambda: iter(images))
    finally:
        entry.chmod(0o755)
    assert not hit and len(index) == 4 and index.rank(images[1]).best == 1
    assert "cannot store" in caplog.text and not _stored(entry)


def test_a_cache_folder_refusing_writes_keeps_the_index_in_memory(tmp_path, monkeypatch, caplog) -> None:
    """As a read-only folder for root, who writes into any: the folder cannot be made."""
    images = _images(count=4)
    entry = _entry(tmp_path, images)

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(index_store.tempfile, "mkdtemp", refuse)
    with caplog.at_level(logging.WARNING, logger="models.index_store"):
        index, hit = cached_index(entry, MemorySpec(**BASE), range(4), seed=0, images=lambda: iter(images))
    assert not hit and index.rank(images[3]).best == 3 and "Permission denied" in caplog.text


def test_a_full_disk_keeps_the_index_in_memory(tmp_path, monkeypatch, caplog) -> None:
    images = _images(count=4)
    entry = _entry(tmp_path, images)
    real = np.save

    def full(path, *args, **kwargs):
        if Path(path).name == "rows.npy":
            raise OSError(28, "No space left on device")
        return real(path, *args, **kwargs)

    monkeypatch.setattr(index_store.np, "save", full)
    with caplog.at_level(logging.WARNING, logger="models.index_store"):
        index, hit = cached_index(entry, MemorySpec(**BASE), range(4), seed=0, images=lambda: iter(images))
    assert not hit and index.rank(images[2]).best == 2 and "No space left" in caplog.text
    assert [p.name for p in (entry / INDEX_FOLDER).iterdir()] == []  # no temporary folder left


def test_no_entry_builds_in_memory_and_stores_nothing(tmp_path) -> None:
    images = _images(count=3)
    index, hit = cached_index(None, MemorySpec(**BASE), range(3), seed=0, images=lambda: iter(images))
    assert not hit and len(index) == 3 and list(tmp_path.iterdir()) == []


def test_an_entry_that_is_not_here_stores_nothing(tmp_path, caplog) -> None:
    """A map from another host names an entry this host does not have: indexed in memory."""
    images = _images(count=3)
    where = tmp_path / "elsewhere"
    with caplog.at_level(logging.WARNING, logger="models.index_store"):
        index, hit = cached_index(where, MemorySpec(**BASE), range(3), seed=0, images=lambda: iter(images))
    assert not hit and len(index) == 3 and not where.exists() and "not a viewframe cache entry" in caplog.text


def test_store_keeps_the_index_already_there_and_load_names_none_missing(tmp_path) -> None:
    images = _images(count=3)
    spec = MemorySpec(**BASE)
    entry = _entry(tmp_path, images)
    key = index_key(spec, range(3), seed=0, entry=entry)
    assert load_index(entry, key, spec, seed=0) is None
    index = ViewframeIndex(spec)
    index.add(images, range(3))
    folder = store_index(index, entry, key)
    assert folder is not None and store_index(index, entry, key) == folder
    assert load_index(entry, key, spec, seed=0) is not None


_CHILD = """
import sys, json, numpy as np
from pathlib import Path
from models.index_store import cached_index
from models.scenario import MemorySpec
from models.synthetic import scene
rng = np.random.default_rng(7)
images = [scene(rng) for _ in range(40)]
go = Path(sys.argv[2])
while not go.exists():
    pass
index, hit = cached_index(Path(sys.argv[1]), MemorySpec(size=64, bank_size=2), range(40), seed=0, images=lambda: iter(images))
r = index.rank(images[9])
print(json.dumps({"hit": hit, "best": r.best, "variances": r.variances.tolist()}))
"""


def test_two_processes_store_the_same_index_at_once(tmp_path) -> None:
    rng = np.random.default_rng(7)
    entry = _entry(tmp_path, [scene(rng) for _ in range(40)])
    go = tmp_path / "go"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    procs = children.start(_CHILD, [str(entry), str(go)], env=env)
    go.touch()  # both start indexing at once
    outs = children.outputs(procs)
    assert outs[0]["best"] == outs[1]["best"] == 9
    np.testing.assert_allclose(outs[0]["variances"], outs[1]["variances"], rtol=1e-5, atol=1e-9)
    (folder,) = _stored(entry)  # one index, no temporary folder left
    assert not folder.name.startswith(".")
    third, hit = cached_index(entry, MemorySpec(size=64, bank_size=2), range(40), seed=0, images=_never)
    assert hit
    np.testing.assert_allclose(third.rank(_images_of(entry)[9]).variances, outs[0]["variances"], rtol=1e-5, atol=1e-9)


def _images_of(entry: Path) -> np.ndarray:
    return np.load(entry / "image.npy")
