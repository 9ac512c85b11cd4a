"""Stored viewframe indices: a shard's memory banks kept beside the viewframe cache entry its
viewframes came from, so a second run of the same map does not index it again.

A :class:`~models.index.ViewframeIndex` (compact: the banks' ranking rows) is stored in
``<entry>/index/<key>/``, ``<entry>`` the viewframe cache entry (:mod:`models.viewframe_cache`)
and ``<key>`` (:func:`index_key`) a SHA-256 of everything that determines the index: the memory
settings (:class:`~models.scenario.MemorySpec`, but those of :data:`NOT_IN_KEY`), the viewframe indices stored (a shard's
membership, in order), the keys' seed, :data:`INDEX_VERSION`, a digest of the source of the modules
that build it (:data:`INDEX_MODULES`), numpy's version (its FFTs) and the entry's identity (its
name, which is the viewframe cache key, and its image file's size and modification time). Any
change of one of them is a miss. The folder holds, as the compact memory gives them
(:meth:`models.associative.BankedMemory.compact_arrays`), ``rows.npy`` (H, D) float32, the
ranking rows, 66.5 KB per viewframe at N = 128; ``viewframes.npy``, ``bank_rows.npy``,
``bank_energy_sq.npy``; and ``meta.json`` (the format, the key, the featureless viewframes),
written last. A stored index is loaded memory-mapped read-only: loading reads no rows, and a
ranking reads them from the page cache (file-backed pages, shared by every process that maps
them and given back by the kernel under pressure, rather than anonymous memory).

Writes go to a temporary folder beside the final one, renamed into place in one step: a reader
never sees a partial index, and when two runs store the same index at once one rename wins and
the other copy is dropped. An unreadable stored index is logged and built again (and the new
one replaces it); a cache folder that cannot be written (read-only, full) is logged and the
index stays in memory: neither ever fails a run.

Example::

    index, hit = cached_index(entry, settings, mine, seed=shard, images=lambda: (image(k) for k in mine))
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from models.associative import BankedMemory
from models.errors import AssociativeMemoryError
from models.index import ViewframeIndex, memory_settings
from models.scenario import MemorySpec
from models.viewframe_cache import source_digest

__all__ = [
    "INDEX_VERSION",
    "INDEX_MODULES",
    "INDEX_FOLDER",
    "NOT_IN_KEY",
    "index_key",
    "load_index",
    "store_index",
    "cached_index",
]

log = logging.getLogger(__name__)

#: bump when building an index changes in a way the source digest would not show
INDEX_VERSION = 1
#: the modules whose source decides a stored index's bytes (their digest is part of the key)
INDEX_MODULES = ("associative", "index", "preprocess", "memory_keys", "index_store")
#: the folder of a viewframe cache entry that holds its stored indices
INDEX_FOLDER = "index"
#: the image field's file in a viewframe cache entry (its size and time are the entry's identity)
_ENTRY_IMAGES = "image.npy"
_FORMAT = 1
#: memory settings that decide what is ranked, never what is stored (the shard size decides the
#: membership, which is in the key itself): left out of the key, so changing them is a hit. Every
#: other field, including any added to MemorySpec later, is in the key.
NOT_IN_KEY = (
    "shard_size",
    "weight",
    "window_route_points",
    "window_margin",
    "window_full_every",
    "roll_search_deg",
    "roll_shortlist",
    "coarse_candidates",
)
_ARRAYS = ("rows", "viewframes", "bank_rows", "bank_energy_sq")


def _source_digest() -> str:
    return source_digest(INDEX_MODULES)


def _entry_identity(entry: Path) -> dict[str, Any]:
    """The entry's name (its viewframe cache key) and its image file's size and modification time."""
    images = entry / _ENTRY_IMAGES
    st = images.stat() if images.is_file() else None
    return {
        "name": entry.name,
        "images": None if st is None else [int(st.st_size), int(st.st_mtime_ns)],
    }


def index_key(
    settings: MemorySpec | Mapping[str, Any] | None,
    viewframes: Sequence[int] | ArrayLike,
    *,
    seed: int,
    entry: str | Path,
    version: int | None = None,
) -> str:
    """The hex SHA-256 key of the index of ``viewframes`` (in storage order) built with the memory
    ``settings`` and keys of ``seed`` from the images of the viewframe cache entry ``entry`` (see
    the module docstring); ``version`` stands for :data:`INDEX_VERSION` (tests)."""
    spec = {
        "format": _FORMAT,
        "version": INDEX_VERSION if version is None else int(version),
        "memory": memory_settings(settings).model_dump(mode="json", exclude=set(NOT_IN_KEY)),
        "seed": int(seed),
        "numpy": np.__version__,
        "entry": _entry_identity(Path(entry)),
    }
    h = hashlib.sha256()
    h.update(json.dumps(spec, sort_keys=True).encode())
    h.update(np.ascontiguousarray(np.asarray(viewframes, dtype=np.int64).ravel()).tobytes())
    h.update(_source_digest().encode())
    return h.hexdigest()


def _folder(entry: str | Path, key: str) -> Path:
    return Path(entry) / INDEX_FOLDER / key


def load_index(
    entry: str | Path, key: str, settings: MemorySpec | Mapping[str, Any] | None, *, seed: int
) -> ViewframeIndex | None:
    """The index stored under ``key`` in ``entry``, its rows memory-mapped read-only, or None when
    there is none. Raises :class:`AssociativeMemoryError` naming the folder when the stored
    index is unreadable or malformed (:func:`cached_index` then builds it again)."""
    folder = _folder(entry, key)
    if not (folder / "meta.json").is_file():
        return None
    s = memory_settings(settings)
    try:
        meta = json.loads((folder / "meta.json").read_text())
        if meta.get("format") != _FORMAT or meta.get("key") != key:
            raise ValueError(f"format {meta.get('format')!r} and key {str(meta.get('key'))[:12]}, expected {_FORMAT}")
        arrays = {name: np.load(folder / f"{name}.npy", allow_pickle=False) for name in _ARRAYS if name != "rows"}
        rows = np.load(folder / "rows.npy", mmap_mode="r", allow_pickle=False) if arrays["viewframes"].size else None
        # a plain array viewing the map (a memmap subclass would leak into every slice and product)
        arrays["rows"] = rows.view(np.ndarray) if rows is not None else np.load(folder / "rows.npy", allow_pickle=False)
        memory = BankedMemory.from_compact_arrays(
            arrays, size=s.size, bank_size=s.bank_size, seed=seed, key_method=s.key, max_shift=s.max_shift
        )
        featureless = [int(v) for v in meta["featureless"]]
        if len(memory) != int(meta["count"]):
            raise ValueError(f"{len(memory)} viewframes stored, meta.json says {meta['count']}")
    except (OSError, ValueError, KeyError, TypeError, AssociativeMemoryError) as err:
        raise AssociativeMemoryError(f"stored index {folder}: unreadable: {err}") from err
    index = ViewframeIndex(s, seed=seed)
    index.memory = memory
    index.featureless = featureless
    return index


def store_index(index: ViewframeIndex, entry: str | Path, key: str, *, replace: bool = False) -> Path | None:
    """Write ``index`` (compact) under ``key`` in ``entry`` atomically; the folder, or None when it
    cannot be written (logged: the index stays in memory). An index already stored under ``key``
    is kept (another run stored it first), unless ``replace`` (it was unreadable)."""
    final = _folder(entry, key)
    if not replace and (final / "meta.json").is_file():
        return final
    if not (Path(entry) / "meta.json").is_file():
        log.warning("stored index: %s is not a viewframe cache entry here; the index stays in memory", entry)
        return None
    arrays = index.memory.compact_arrays()
    tmp: Path | None = None
    try:
        final.parent.mkdir(exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key[:16]}.", suffix=".tmp", dir=final.parent))
        for name in _ARRAYS:
            np.save(tmp / f"{name}.npy", np.ascontiguousarray(arrays[name]), allow_pickle=False)
        meta = {"format": _FORMAT, "key": key, "count": len(index), "featureless": [int(v) for v in index.featureless]}
        (tmp / "meta.json").write_text(json.dumps(meta))  # last: an index without it is never read
        if replace and final.exists():
            _remove(final)
        try:
            os.rename(tmp, final)
        except OSError:
            if not (final / "meta.json").is_file():  # not a concurrent writer that won: a real failure
                raise
            log.debug("stored index %s was written concurrently; keeping that one", final)
    except OSError as err:
        log.warning("stored index %s: cannot store (%s); the index stays in memory", final, err)
        return None
    finally:
        if tmp is not None and tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return final


def _remove(folder: Path) -> None:
    """Remove a stored index folder: renamed aside first (one step), so no reader sees it half gone."""
    aside = Path(tempfile.mkdtemp(prefix=f".{folder.name[:16]}.", suffix=".old", dir=folder.parent))
    try:
        os.rename(folder, aside / folder.name)
    except OSError:
        pass  # another run removed or replaced it first
    shutil.rmtree(aside, ignore_errors=True)


def cached_index(
    entry: str | Path | None,
    settings: MemorySpec | Mapping[str, Any] | None,
    viewframes: Sequence[int],
    *,
    seed: int,
    images: Callable[[], Iterable[ArrayLike]],
) -> tuple[ViewframeIndex, bool]:
    """``(index, hit)``: the index of ``viewframes`` loaded from ``entry`` (``hit`` True; the
    images are not read), else built from ``images()`` (the viewframes' images, in the order of
    ``viewframes``) and stored there, then used from the stored copy (memory-mapped, as a later
    run's). ``entry`` None: built in memory, nothing stored."""
    s = memory_settings(settings)
    vfs = [int(v) for v in viewframes]
    key = index_key(s, vfs, seed=seed, entry=entry) if entry is not None else None
    replace = False
    if entry is not None and key is not None:
        try:
            loaded = load_index(entry, key, s, seed=seed)
        except AssociativeMemoryError as err:
            log.warning("%s; indexing again", err)
            loaded, replace = None, True
        if loaded is not None:
            log.info("stored index: %d viewframes from %s", len(loaded) + len(loaded.featureless), entry)
            return loaded, True
    index = ViewframeIndex(s, seed=seed)
    index.add(images(), vfs)
    if entry is None or key is None:
        return index, False
    if store_index(index, entry, key, replace=replace) is None:
        return index, False
    try:
        back = load_index(entry, key, s, seed=seed)
    except AssociativeMemoryError as err:
        log.warning("%s; keeping the index in memory", err)
        back = None
    return (index if back is None else back), False
