"""The viewframe cache: rendered viewframes and their symbolic descriptions kept on disk, so a
second run of the same map skips rendering.

An entry is keyed by a SHA-256 of everything that determines a route's viewframes (:func:`cache_key`):
the terrain heights and cell size, the placed landmarks' specs, the route, the camera, the scenario
seed, the level-of-detail options, the :class:`~models.viewframes.Viewframe` field names, the
:data:`RENDERER_VERSION` constant and a digest of the source of the modules that render and
describe (:data:`RENDERER_MODULES`). Any change of one of them is a miss; entries are never
modified, only added.

An entry is a folder ``<root>/<key>/`` holding ``meta.json`` (per viewframe: the non-array
fields) and, per array field of :class:`~models.viewframes.Viewframe`, one ``<field>.npy``
stacking that field of every viewframe (shape (V, ...), loaded memory-mapped copy-on-write, so
only the pages read are resident and writes stay private). Fields are serialised generically
from the dataclass: arrays as ``.npy``, dataclasses by their fields, objects with
``to_dict``/``from_dict`` through those, plain values as JSON; an optional array field (None
for some viewframes, such as ``background``) is stacked with its absent rows marked; a field
added to ``Viewframe`` later is stored without changes here. An entry is written to a temporary folder next to its
place and renamed into place in one step: concurrent runs never see a partial entry, and when
two write the same entry at once, one rename wins and the other run's copy is dropped.

Beside ``meta.json`` an entry holds ``summary.npz``: what a map needs of its viewframes
without parsing the descriptions (26 MB of JSON at 10,000 viewframes, 2 to 5 s): the index and
pose of each, and a row per landmark visible in each (its id, pixels and centroid)
(:func:`entry_summary`, :class:`EntrySummary`). It is derived from ``meta.json`` only (written
with it; an entry written before it existed gets it on first read, atomically, like the stored
indices beside an entry), carries its own :data:`SUMMARY_FORMAT` and the size of the
``meta.json`` it was made from, and is ignored (made again from ``meta.json``) when either
does not match or it cannot be read.

Agents that need a viewframe's pixels read them from the entry the map was rendered into
(:func:`read_pixels`: the ``image``, ``mask`` and ``background`` row of one viewframe, from the
entry's stacked arrays memory-mapped read-only; a few entries opened per process, see
:data:`OPEN_ENTRIES`), so the ``viewframe`` messages need not carry them
(:class:`knowledge_sources.levels.Viewframe`). A missing entry, an entry of another count or a
row out of range is a :class:`~models.errors.CacheEntryError` naming the entry.

The cache folder is, in this order: the ``root`` given, ``$MAPINTERP_CACHE``,
``$XDG_CACHE_HOME/mapinterp``, ``~/.cache/mapinterp``. ``MAPINTERP_CACHE=off`` turns it off.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import mmap
import os
import shutil
import tempfile
import threading
import typing
import zipfile
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from models.errors import CacheEntryError
from models.symbolic import SymbolicDescription
from models.viewframes import Viewframe

__all__ = [
    "RENDERER_VERSION",
    "StoredDescription",
    "RENDERER_MODULES",
    "CACHE_ENV",
    "EntrySummary",
    "EntryWriter",
    "OPEN_ENTRIES",
    "PIXEL_FIELDS",
    "Pixels",
    "RELEASE_EVERY",
    "SUMMARY_FORMAT",
    "read_pixels",
    "ViewframeCache",
    "cache_key",
    "default_cache_root",
    "entry_field",
    "entry_summary",
    "release_behind",
    "release_pages",
    "source_digest",
]

log = logging.getLogger(__name__)

#: bump when rendering or describing changes in a way the source digest would not show
RENDERER_VERSION = 1
#: the modules whose source decides what a viewframe looks like (their digest is part of the key)
RENDERER_MODULES = ("camera_emulator", "environment", "landmarks", "symbolic", "terrain", "viewframes")
#: the environment variable naming the cache folder (``off`` disables the cache)
CACHE_ENV = "MAPINTERP_CACHE"
_OFF = {"off", "0", "no", "false", "none"}
_FORMAT = 2


def default_cache_root() -> Path | None:
    """The cache folder from the environment (see the module docstring); None when turned off."""
    value = os.environ.get(CACHE_ENV)
    if value is not None and value.strip().lower() in _OFF:
        return None
    if value:
        return Path(value).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "mapinterp"


#: Linux madvise(2) MADV_PAGEOUT (5.4 and later; Python's mmap module may not name it)
_MADV_PAGEOUT = getattr(mmap, "MADV_PAGEOUT", 21)
_MADV_DONTNEED = getattr(mmap, "MADV_DONTNEED", 4)
#: the bytes around a faulting address that Linux maps too when they are in the page cache
#: (``fault_around_bytes``, 64 KiB by default): what :func:`read_pixels` gives back besides the row
FAULT_AROUND = 64 * 1024


def release_pages(arrays: Iterable[np.ndarray | None], *, advice: int = _MADV_PAGEOUT, margin: int = 0) -> int:
    """Give back the resident pages of arrays read from a cache entry (memory-mapped), e.g. once a
    batch of viewframes is posted: the kernel drops them from this process (``MADV_PAGEOUT``)
    and reads them from the file again if they are used again; nothing is lost, written
    copy-on-write pages included. One call per memory map, over the span of the arrays in it:
    give a batch of neighbouring rows at once (the kernel keeps a page-cache folio only partly
    in the span). Arrays not backed by a memory map are left alone; where the system does not
    support it, nothing happens. ``advice``: ``mmap.MADV_DONTNEED`` for a read-only map (the pages
    leave this process, the page cache keeps them). ``margin``: bytes more on either side of the
    span, within the map (a page fault maps the neighbouring pages already cached too, up to
    :data:`FAULT_AROUND` bytes: a row read alone leaves its neighbours' pages mapped otherwise).
    Returns the bytes advised."""
    spans: dict[int, tuple[mmap.mmap, int, int]] = {}
    for a in arrays:
        base = a
        while isinstance(base, np.ndarray) and not isinstance(base, np.memmap):
            base = base.base
        mm = getattr(base, "_mmap", None) if isinstance(base, np.memmap) else None
        if a is None or not isinstance(mm, mmap.mmap) or a.nbytes == 0:
            continue
        address = int(a.ctypes.data)
        m, lo, hi = spans.get(id(mm), (mm, address, address + a.nbytes))
        spans[id(mm)] = (m, min(lo, address), max(hi, address + a.nbytes))
    done = 0
    for mm, lo, hi in spans.values():
        try:
            start = np.frombuffer(mm, dtype=np.uint8, count=1).ctypes.data
            rel = max(0, lo - margin - start)
            rel -= rel % mmap.PAGESIZE
            end = min(len(mm), hi + margin - start)
            mm.madvise(advice, rel, end - rel)
            done += end - rel
        except (OSError, ValueError, TypeError, AttributeError):
            continue
    return done


#: rows used (posted, indexed) between two returns of their memory-mapped pages (:func:`release_behind`)
RELEASE_EVERY = 64

_Row = typing.TypeVar("_Row")


def release_behind(
    k: int,
    rows: Sequence[_Row],
    arrays: Callable[[_Row], Iterable[np.ndarray | None]],
    *,
    every: int | None = None,
) -> bool:
    """Once ``rows[k]`` is used, rows being used in order (viewframes read from a memory-mapped
    entry and posted, images indexed): after every ``every``-th row and the last, give back the
    pages of the ``arrays`` of the last two batches (this one and the one before, to cover the
    pages that straddle the two; :func:`release_pages`), else a long route's whole entry would
    become resident as it is used. ``every``: default :data:`RELEASE_EVERY`. Returns True when it
    gave them back (a batch is done)."""
    every = RELEASE_EVERY if every is None else every
    if (k + 1) % every and k + 1 != len(rows):
        return False
    release_pages(a for row in rows[max(0, k + 1 - 2 * every) : k + 1] for a in arrays(row))
    return True


def source_digest(modules: Sequence[str]) -> str:
    """SHA-256 over the names and sources of the ``models`` modules ``modules`` (a missing one
    counts as ``-``): what a stored product of that code is keyed by."""
    h = hashlib.sha256()
    here = Path(__file__).resolve().parent
    for name in modules:
        path = here / f"{name}.py"
        h.update(name.encode())
        h.update(path.read_bytes() if path.exists() else b"-")
    return h.hexdigest()


def cache_key(
    scenario: Any, terrain: Any, *, lod: Mapping[str, Any] | None = None, renderer_version: int | None = None
) -> str:
    """The hex SHA-256 key of a scenario's viewframes (see the module docstring).

    ``scenario`` is a :class:`~models.scenario.Scenario`, ``terrain`` its loaded
    :class:`~models.terrain.Terrain` (its heights are hashed, so a changed DEM file is a miss).
    """
    h = hashlib.sha256()
    spec = {
        "format": _FORMAT,
        "renderer_version": RENDERER_VERSION if renderer_version is None else int(renderer_version),
        "seed": scenario.seed,
        "landmarks": [lm.model_dump(mode="json") for lm in scenario.landmarks],
        "route": [list(map(float, p)) for p in scenario.route],
        "camera": scenario.camera.model_dump(mode="json"),
        "skyline_step_deg": float(scenario.skyline.step_deg),  # viewframes carry their skyline at this step
        "lod": {str(k): v for k, v in sorted((lod or {}).items())},
        "fields": [f.name for f in dataclasses.fields(Viewframe)],
        "cell_size": float(terrain.cell_size),
        "terrain_shape": list(terrain.heights.shape),
    }
    views = int(scenario.views_per_leg)
    if views != 1:  # viewframes between the route points; one per point keeps the keys it always had
        spec["views_per_leg"] = views
    h.update(json.dumps(spec, sort_keys=True, default=repr).encode())
    h.update(np.ascontiguousarray(terrain.heights, dtype=np.float64).tobytes())
    h.update(source_digest(RENDERER_MODULES).encode())
    return h.hexdigest()


def _field_types() -> dict[str, Any]:
    return typing.get_type_hints(Viewframe)


def _encode(value: Any) -> Any:
    """A non-array field value as JSON data."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _encode(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if hasattr(value, "to_dict"):
        return value.to_dict()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_encode(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _encode(v) for k, v in value.items()}
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"cannot store a {type(value).__name__} in the viewframe cache")


class StoredDescription(SymbolicDescription):
    """A symbolic description read from a cache entry: its graph is built from the stored data on
    first use of :attr:`graph`; until then :attr:`visible` and :meth:`to_dict` answer from the data
    (a warm run's map renderer needs nothing else of most viewframes: building 10,000 graphs and
    turning them back into plain data cost it about 20 s on the loaded 2-core machine). The data
    is checked for its shape when read; its values when the graph is built (ValueError)."""

    def __init__(self, data: dict[str, Any]) -> None:  # no super().__init__: the graph is built later
        if not (
            isinstance(data, dict)
            and isinstance(data.get("visible"), list)
            and isinstance(data.get("nodes"), dict)
            and isinstance(data.get("edges"), list)
            and set(data["visible"]) == set(data["nodes"])
        ):
            raise ValueError(f"malformed symbolic description: {str(data)[:200]}")
        self._data: dict[str, Any] | None = data
        self._graph: Any = None

    @property
    def graph(self) -> Any:
        if self._graph is None:
            assert self._data is not None
            self._graph = SymbolicDescription.from_dict(self._data).graph
            self._data = None  # the graph is the description from now on
        return self._graph

    @graph.setter
    def graph(self, value: Any) -> None:
        self._graph, self._data = value, None

    @property
    def visible(self) -> list[str]:
        if self._data is not None:
            return list(self._data["visible"])
        return super().visible

    def to_dict(self) -> dict[str, Any]:
        if self._data is not None:
            return dict(self._data)
        return super().to_dict()


def _decode(data: Any, kind: Any) -> Any:
    """Inverse of :func:`_encode` for a field declared as ``kind``."""
    if data is None:
        return None
    origin = typing.get_origin(kind)
    if origin is typing.Union or str(origin) == "<class 'types.UnionType'>":
        options = [a for a in typing.get_args(kind) if a is not type(None)]
        kind = options[0] if len(options) == 1 else Any
    if isinstance(kind, type):
        if dataclasses.is_dataclass(kind):
            hints = typing.get_type_hints(kind)
            return kind(**{k: _decode(v, hints.get(k, Any)) for k, v in data.items()})
        if kind is SymbolicDescription:
            return StoredDescription(data)
        if hasattr(kind, "from_dict"):
            return kind.from_dict(data)
        if kind is tuple:
            return tuple(data)
    return data


class ViewframeCache:
    """Viewframes on disk under ``root`` (see the module docstring).

    Example::

        cache = ViewframeCache.from_env()          # None when MAPINTERP_CACHE=off
        key = cache_key(scenario, terrain)
        viewframes = cache.load(key)               # None on a miss
        if viewframes is None:
            viewframes = render(...)
            cache.store(key, viewframes)
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root).expanduser()
        self.hits = 0
        self.misses = 0

    @classmethod
    def from_env(cls) -> ViewframeCache | None:
        """The cache in :func:`default_cache_root`, or None when turned off."""
        root = default_cache_root()
        return None if root is None else cls(root)

    def path(self, key: str) -> Path:
        return self.root / key

    def __contains__(self, key: str) -> bool:
        return (self.path(key) / "meta.json").is_file()

    def load(self, key: str) -> list[Viewframe] | None:
        """The viewframes stored under ``key``, or None (a miss; an unreadable entry is a miss too,
        logged)."""
        folder = self.path(key)
        if not (folder / "meta.json").is_file():
            self.misses += 1
            return None
        try:
            viewframes = self._read(folder)
        except (OSError, ValueError, KeyError, TypeError) as err:
            log.warning("viewframe cache %s: unreadable entry, rendering again: %s", folder, err)
            self.misses += 1
            return None
        self.hits += 1
        log.info("viewframe cache: %d viewframes from %s", len(viewframes), folder)
        return viewframes

    def _read(self, folder: Path) -> list[Viewframe]:
        meta = json.loads((folder / "meta.json").read_text())
        if meta.get("format") != _FORMAT:
            raise ValueError(f"format {meta.get('format')!r}, expected {_FORMAT}")
        n = int(meta["count"])
        types = _field_types()
        columns: dict[str, Any] = {}
        for name in meta["arrays"]:
            stacked = np.load(folder / f"{name}.npy", mmap_mode="c", allow_pickle=False)
            if stacked.shape[0] != n:
                raise ValueError(f"{name}.npy holds {stacked.shape[0]} viewframes, expected {n}")
            absent = meta.get("absent", {}).get(name) or [False] * n
            columns[name] = [None if absent[i] else np.asarray(stacked[i]) for i in range(n)]
        for name in meta["ragged"]:
            columns[name] = [
                None if not ok else np.load(folder / f"{name}.{i}.npy", allow_pickle=False)
                for i, ok in enumerate(meta["ragged"][name])
            ]
        for name, values in meta["values"].items():
            columns[name] = [_decode(v, types.get(name, Any)) for v in values]
        missing = {f.name for f in dataclasses.fields(Viewframe)} - set(columns)
        if missing:
            raise ValueError(f"entry lacks the fields {sorted(missing)}")
        return [Viewframe(**{name: col[i] for name, col in columns.items()}) for i in range(n)]

    def read(self, key: str) -> list[Viewframe] | None:
        """:meth:`load` without counting a hit or a miss (an entry this run has just written)."""
        folder = self.path(key)
        if not (folder / "meta.json").is_file():
            return None
        try:
            return self._read(folder)
        except (OSError, ValueError, KeyError, TypeError) as err:
            log.warning("viewframe cache %s: unreadable entry: %s", folder, err)
            return None

    def store(self, key: str, viewframes: Sequence[Viewframe]) -> Path:
        """Write ``viewframes`` under ``key`` (atomically; a no-op when the entry exists)."""
        final = self.path(key)
        if key in self:
            return final
        try:
            writer = self.writer(key, len(viewframes))
        except OSError as err:
            log.warning("viewframe cache %s: cannot store (%s); the run goes on without it", final, err)
            return final
        try:
            for row, vf in enumerate(viewframes):
                writer.put(row, vf)
            writer.commit()
        except OSError as err:
            log.warning("viewframe cache %s: cannot store (%s); the run goes on without it", final, err)
        finally:
            writer.abort()
        return final

    def writer(self, key: str, count: int) -> EntryWriter:
        """An :class:`EntryWriter` filling the entry of ``count`` viewframes under ``key`` row by
        row, as they are rendered (:class:`OSError` when the cache folder cannot be written)."""
        self.root.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key[:16]}.", suffix=".tmp", dir=self.root))
        return EntryWriter(tmp, self.path(key), count)


class EntryWriter:
    """Writes one cache entry (see the module docstring) a viewframe at a time, in any order of
    rows, without holding them: each array is written at its row's place in its field's stacked
    ``.npy`` (plain file writes, so the entry's pages are not resident in this process), the
    other fields are kept as JSON data until :meth:`commit`. :meth:`commit` writes ``meta.json``
    and renames the folder into place; :meth:`abort` (or a failed commit) removes it.

    Example::

        writer = cache.writer(key, len(poses))
        for row, pose in enumerate(poses):
            writer.put(row, render_one(pose))
        writer.commit()
    """

    def __init__(self, folder: Path, final: Path, count: int) -> None:
        if count < 0:
            raise ValueError(f"count must be >= 0, got {count}")
        self.folder, self.final, self.count = folder, final, int(count)
        self._names = [f.name for f in dataclasses.fields(Viewframe)]
        self._stacked: dict[str, tuple[int, int, tuple[int, ...], np.dtype]] = {}  # fd, data offset, shape, dtype
        self._ragged: set[str] = set()
        self._has: dict[str, list[bool]] = {}  # array fields: which rows hold an array
        self._values: dict[str, list[Any]] = {name: [None] * self.count for name in self._names}
        self._put = [False] * self.count

    def put(self, row: int, viewframe: Viewframe) -> None:
        """Write ``viewframe`` as the entry's row ``row`` (0 <= row < count)."""
        if not 0 <= row < self.count:
            raise ValueError(f"row must be in [0, {self.count}), got {row}")
        for name in self._names:
            value = getattr(viewframe, name)
            if isinstance(value, np.ndarray):
                if any(v is not None for v in self._values[name]):
                    raise TypeError(f"field {name} holds an array in row {row} and other values elsewhere")
                self._array(name, row, value)
            elif value is not None:
                if name in self._has:
                    raise TypeError(f"field {name} holds a {type(value).__name__} in row {row} and arrays elsewhere")
                self._values[name][row] = _encode(value)
        self._put[row] = True

    def _array(self, name: str, row: int, value: np.ndarray) -> None:
        has = self._has.setdefault(name, [False] * self.count)
        a = np.ascontiguousarray(value)
        if name not in self._stacked and name not in self._ragged:
            path = self.folder / f"{name}.npy"
            head = np.lib.format.open_memmap(path, mode="w+", dtype=a.dtype, shape=(self.count, *a.shape))
            offset = int(head.offset)
            del head  # the header and the (sparse, zero) file are written; rows go in by plain writes
            self._stacked[name] = (os.open(path, os.O_WRONLY), offset, a.shape, a.dtype)
        if name in self._stacked:
            fd, offset, shape, dtype = self._stacked[name]
            if a.shape == shape and a.dtype == dtype:
                os.pwrite(fd, a.tobytes(), offset + row * a.nbytes)
                has[row] = True
                return
            self._unstack(name)  # arrays of several shapes: one file per row
        np.save(self.folder / f"{name}.{row}.npy", a, allow_pickle=False)
        has[row] = True

    def _unstack(self, name: str) -> None:
        fd, _, _, _ = self._stacked.pop(name)
        os.close(fd)
        path = self.folder / f"{name}.npy"
        stacked = np.load(path, mmap_mode="r", allow_pickle=False)
        for r, ok in enumerate(self._has[name]):
            if ok:
                np.save(self.folder / f"{name}.{r}.npy", np.array(stacked[r]), allow_pickle=False)
        del stacked
        path.unlink()
        self._ragged.add(name)

    def _close_files(self) -> None:
        for fd, _, _, _ in self._stacked.values():
            os.close(fd)
        self._stacked.clear()

    def commit(self) -> Path:
        """Write ``meta.json`` and move the entry into place (when another run wrote the same
        entry first, its copy stays and this one is dropped); ValueError when a row is missing."""
        missing = [r for r, ok in enumerate(self._put) if not ok]
        if missing:
            self.abort()
            raise ValueError(f"viewframe cache entry: rows {missing[:5]} of {self.count} were never written")
        stacked = list(self._stacked)
        self._close_files()
        meta: dict[str, Any] = {"format": _FORMAT, "count": self.count, "arrays": [], "absent": {}, "ragged": {}}
        meta["values"] = {}
        for name in self._names:
            if name in stacked:
                meta["arrays"].append(name)
                if not all(self._has[name]):
                    meta["absent"][name] = [not ok for ok in self._has[name]]
            elif name in self._ragged:
                meta["ragged"][name] = list(self._has[name])
            else:
                meta["values"][name] = self._values[name]
        text = json.dumps(meta)
        try:
            summary = _summary_of(meta["values"], self.count)
        except (ValueError, KeyError, TypeError) as err:  # rows of another shape than the renderer's
            log.debug("viewframe cache %s: no %s (%s)", self.final, _SUMMARY, err)
        else:
            _write_summary(self.folder, summary, meta_bytes=len(text.encode()))
        # meta.json last: an entry without it is never read
        (self.folder / "meta.json").write_text(text)
        try:
            os.rename(self.folder, self.final)
        except OSError:
            if not (self.final / "meta.json").is_file():  # not a concurrent writer that won: a real failure
                self.abort()
                raise
            log.debug("viewframe cache: %s was written concurrently; keeping that one", self.final)
        self.abort()
        return self.final

    def abort(self) -> None:
        """Remove the unfinished entry (nothing once committed)."""
        self._close_files()
        if self.folder.exists():
            shutil.rmtree(self.folder, ignore_errors=True)


# -- the pixels of one viewframe, read from an entry ------------------------------------------------

#: the array fields a viewframe message may leave in the entry (read by :func:`read_pixels`)
PIXEL_FIELDS = ("image", "mask", "background")
#: cache entries kept open (memory-mapped) per process, least recently used closed first
OPEN_ENTRIES = 4


class Pixels(NamedTuple):
    """A viewframe's pixel arrays, images (row, col): ``image`` uint8 (H, W, 3) RGB, ``mask`` int16
    (H, W) landmark index per pixel (-1: none), ``background`` uint8 (H, W, 3) the view without
    landmarks, or None when no landmark is in view."""

    image: np.ndarray
    mask: np.ndarray
    background: np.ndarray | None


class _EntryPixels:
    """The pixel arrays of one committed entry, memory-mapped read-only (only the rows read are
    resident, and only while they are copied)."""

    def __init__(self, folder: Path) -> None:
        meta_path = folder / "meta.json"
        if not folder.is_dir():
            raise CacheEntryError(folder, "no such viewframe cache entry (folder)")
        if not meta_path.is_file():
            raise CacheEntryError(folder, "not a committed viewframe cache entry (no meta.json)")
        try:
            meta = _meta_head(meta_path.read_text(), ("format", "count", "arrays", "absent", "ragged"))
        except (OSError, ValueError) as err:
            raise CacheEntryError(folder, f"unreadable meta.json: {err}") from None
        if not isinstance(meta, dict) or meta.get("format") != _FORMAT:
            got = meta.get("format") if isinstance(meta, dict) else None
            raise CacheEntryError(folder, f"entry format {got!r}, expected {_FORMAT}")
        self.folder = folder
        self.count = int(meta["count"])
        self._arrays = list(meta.get("arrays", []))  # the fields stacked in <name>.npy
        self._stacked: dict[str, np.ndarray] = {}
        self._absent: dict[str, list[bool]] = {}
        self._ragged: dict[str, list[bool]] = {}
        for name in PIXEL_FIELDS:
            if name in meta.get("arrays", []):
                try:
                    stacked = np.load(folder / f"{name}.npy", mmap_mode="r", allow_pickle=False)
                except (OSError, ValueError) as err:
                    raise CacheEntryError(folder, f"unreadable {name}.npy: {err}") from None
                if stacked.shape[0] != self.count:
                    raise CacheEntryError(
                        folder, f"{name}.npy holds {stacked.shape[0]} viewframes, meta.json says {self.count}"
                    )
                self._stacked[name] = stacked
                self._absent[name] = meta.get("absent", {}).get(name) or []
            elif name in meta.get("ragged", {}):
                self._ragged[name] = list(meta["ragged"][name])
            elif name != "background":
                raise CacheEntryError(folder, f"entry holds no {name} arrays")

    def _row(self, name: str, row: int) -> np.ndarray | None:
        if name in self._stacked:
            absent = self._absent[name]
            if absent and absent[row]:
                return None
            view = self._stacked[name][row]
            out = np.array(view)  # a copy: the mapped pages are given back below
            release_pages([view], advice=_MADV_DONTNEED, margin=FAULT_AROUND)
            return out
        if name in self._ragged:
            if not self._ragged[name][row]:
                return None
            try:
                return np.load(self.folder / f"{name}.{row}.npy", allow_pickle=False)
            except (OSError, ValueError) as err:
                raise CacheEntryError(self.folder, f"unreadable {name}.{row}.npy: {err}") from None
        return None

    def stacked(self, name: str) -> np.ndarray:
        """Array field ``name`` of every row, memory-mapped read-only (the pixel fields mapped when
        the entry was opened, another stacked field such as ``skyline`` on first use);
        CacheEntryError when the entry holds it otherwise (absent in some rows, one file per
        row, not at all) or it cannot be read."""
        if name not in self._stacked and name in self._arrays and name not in PIXEL_FIELDS:
            try:
                stacked = np.load(self.folder / f"{name}.npy", mmap_mode="r", allow_pickle=False)
            except (OSError, ValueError) as err:
                raise CacheEntryError(self.folder, f"unreadable {name}.npy: {err}") from None
            if stacked.shape[0] != self.count:
                raise CacheEntryError(
                    self.folder, f"{name}.npy holds {stacked.shape[0]} viewframes, meta.json says {self.count}"
                )
            self._stacked[name] = stacked
        if name not in self._stacked or any(self._absent.get(name) or ()):
            raise CacheEntryError(self.folder, f"{name} is not stacked for every viewframe (absent, or one file each)")
        return self._stacked[name]

    def pixels(self, row: int) -> Pixels:
        image, mask = self._row("image", row), self._row("mask", row)
        if image is None or mask is None:
            raise CacheEntryError(self.folder, f"row {row} holds no image or no mask")
        return Pixels(image=image, mask=mask.astype(np.int16, copy=False), background=self._row("background", row))


def _meta_head(text: str, keys: Sequence[str]) -> dict[str, Any]:
    """The members ``keys`` of the JSON object ``text`` (a ``meta.json``), parsed member by member
    until all are seen: the per-viewframe ``values`` (the descriptions: most of the file, 26 MB at
    10,000 viewframes) come last and are not parsed; ValueError on malformed JSON."""
    decoder = json.JSONDecoder()
    ws = json.decoder.WHITESPACE.match  # type: ignore[attr-defined]
    out: dict[str, Any] = {}
    i = ws(text, 0).end()
    if text[i : i + 1] != "{":
        raise ValueError("meta.json is not a JSON object")
    i = ws(text, i + 1).end()
    while text[i : i + 1] != "}" and not set(keys) <= set(out):
        key, i = decoder.raw_decode(text, i)
        i = ws(text, i).end()
        if text[i : i + 1] != ":":
            raise ValueError(f"meta.json: expected ':' at character {i}")
        value, i = decoder.raw_decode(text, ws(text, i + 1).end())
        out[key] = value
        i = ws(text, i).end()
        if text[i : i + 1] == ",":
            i = ws(text, i + 1).end()
        elif text[i : i + 1] != "}":
            raise ValueError(f"meta.json: expected ',' or '}}' at character {i}")
    return out


_open: OrderedDict[Path, _EntryPixels] = OrderedDict()
_open_lock = threading.Lock()


def _opened(folder: Path) -> _EntryPixels:
    """The committed entry ``folder`` (absolute) opened, memory-mapped: kept open, at most
    :data:`OPEN_ENTRIES` per process (least recently used closed first); CacheEntryError naming it."""
    with _open_lock:
        opened = _open.get(folder)
        if opened is None:
            opened = _EntryPixels(folder)
            _open[folder] = opened
            while len(_open) > OPEN_ENTRIES:
                _open.popitem(last=False)
        else:
            _open.move_to_end(folder)
    return opened


def read_pixels(entry: str | Path, row: int, *, count: int) -> Pixels:
    """The pixels of row ``row`` (the viewframe index) of the committed cache entry ``entry`` (its
    folder, absolute), which must hold ``count`` viewframes: copies, the entry's pages are not kept
    resident. The entry is opened (memory-mapped) on first use and kept open, at most
    :data:`OPEN_ENTRIES` entries per process. :class:`~models.errors.CacheEntryError` (naming the
    entry) when it is missing, not committed, of another format or count, or ``row`` is out of range.
    """
    folder = Path(entry)
    if not folder.is_absolute():
        raise CacheEntryError(folder, "a viewframe cache entry must be named by its absolute path")
    opened = _opened(folder)
    if opened.count != count:
        raise CacheEntryError(folder, f"the entry holds {opened.count} viewframes, the reference says {count} (stale)")
    if not 0 <= row < count:
        raise CacheEntryError(folder, f"row {row} out of range [0, {count})")
    return opened.pixels(row)


def entry_field(entry: str | Path, name: str, *, count: int | None = None) -> np.ndarray | None:
    """The stacked array field ``name`` (e.g. ``"image"``, ``"skyline"``) of every viewframe of the
    cache entry folder ``entry``, shape (V, ...), memory-mapped read-only (row k is viewframe k;
    nothing is read until used: give the pages back with :func:`release_pages` or
    :func:`release_behind`). The entry is opened as :func:`read_pixels` opens it (the same checks,
    the same open entry). None, logged, when the entry cannot be read, holds another ``count`` of
    viewframes or does not hold the field stacked for every viewframe (absent in some, one file
    per viewframe, not at all)."""
    try:
        opened = _opened(Path(entry).absolute())
        if count is not None and opened.count != count:
            raise CacheEntryError(opened.folder, f"holds {opened.count} viewframes, expected {count}")
        return opened.stacked(name)
    except CacheEntryError as err:
        log.warning("viewframe cache %s: cannot read %s.npy: %s", entry, name, err.message)
        return None


# -- what a map needs of an entry's viewframes, without the descriptions ---------------------------

#: the version of ``summary.npz`` (bump when what it holds changes: an older one is made again)
SUMMARY_FORMAT = 1
_SUMMARY = "summary.npz"


class EntrySummary(NamedTuple):
    """What a map needs of a cache entry's viewframes (module docstring), in the entry's row order
    (row k is viewframe ``viewframes[k]``): ``viewframes`` (V,) int64 (their indices), ``poses`` (V, 5) float64 (x, y, z,
    heading_deg, pitch_deg; world metres, degrees), and per landmark visible in a viewframe, in its
    description's ``visible`` order, a row of ``rows`` (M,) int64 (the viewframe's row),
    ``landmarks`` (M,) str (the landmark id), ``pixels`` (M,) int64 and ``centroids`` (M, 2)
    float64 ((row, col) in the image, as the description's nodes say)."""

    viewframes: np.ndarray
    poses: np.ndarray
    rows: np.ndarray
    landmarks: np.ndarray
    pixels: np.ndarray
    centroids: np.ndarray

    def visible(self) -> list[list[str]]:
        """The landmark ids visible in each viewframe (row), in description order."""
        out: list[list[str]] = [[] for _ in range(len(self.viewframes))]
        for k, lm in zip(self.rows.tolist(), self.landmarks.tolist()):
            out[k].append(lm)
        return out


def _summary_of(values: Mapping[str, Sequence[Any]], count: int) -> EntrySummary:
    """The summary of an entry's per-viewframe JSON values (``meta.json``'s ``values``: ``index``,
    ``pose`` as a map of fields, ``description`` as SymbolicDescription.to_dict data); ValueError
    or KeyError on values of another shape."""
    index, poses, descriptions = values["index"], values["pose"], values["description"]
    if not len(index) == len(poses) == len(descriptions) == count:
        raise ValueError(
            f"meta.json values: {len(index)} indices, {len(poses)} poses, {len(descriptions)} descriptions"
        )
    fields = ("x", "y", "z", "heading_deg", "pitch_deg")
    rows: list[int] = []
    landmarks: list[str] = []
    pixels: list[int] = []
    centroids: list[Sequence[float]] = []
    for k, d in enumerate(descriptions):
        nodes = d["nodes"]
        for lm in d["visible"]:
            node = nodes[lm]
            rows.append(k)
            landmarks.append(str(lm))
            pixels.append(int(node["pixels"]))
            centroids.append(node["centroid"])
    return EntrySummary(
        viewframes=np.asarray(index, dtype=np.int64).reshape(count),
        poses=np.asarray([[float(p[f]) for f in fields] for p in poses], dtype=np.float64).reshape(count, 5),
        rows=np.asarray(rows, dtype=np.int64),
        landmarks=np.asarray(landmarks, dtype=str) if landmarks else np.zeros(0, dtype="<U1"),
        pixels=np.asarray(pixels, dtype=np.int64),
        centroids=np.asarray(centroids, dtype=np.float64).reshape(-1, 2),
    )


def _write_summary(folder: Path, summary: EntrySummary, *, meta_bytes: int) -> None:
    """Write ``summary.npz`` into the entry ``folder`` atomically (a temporary file renamed into
    place: concurrent writers of the same entry write the same bytes); OSError when it cannot."""
    fd, tmp = tempfile.mkstemp(prefix=".summary.", suffix=".npz.tmp", dir=folder)
    try:
        os.fchmod(fd, 0o644)  # as the entry's other files (mkstemp makes it private)
        with os.fdopen(fd, "wb") as f:
            np.savez(
                f,
                format=np.int64(SUMMARY_FORMAT),
                meta_bytes=np.int64(meta_bytes),
                **summary._asdict(),
            )
        os.replace(tmp, folder / _SUMMARY)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _read_summary(folder: Path, *, count: int, meta_bytes: int) -> EntrySummary | None:
    """The entry's ``summary.npz``, or None when it is absent, unreadable, of another
    :data:`SUMMARY_FORMAT` or made from another ``meta.json`` (size) or count."""
    path = folder / _SUMMARY
    if not path.is_file():
        return None
    try:
        with path.open("rb") as f, np.load(f, allow_pickle=False) as z:  # the file closed on any error
            if int(z["format"]) != SUMMARY_FORMAT or int(z["meta_bytes"]) != meta_bytes:
                log.info("viewframe cache %s: %s of another format or meta.json, made again", folder, _SUMMARY)
                return None
            got = EntrySummary(**{name: np.array(z[name]) for name in EntrySummary._fields})
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as err:
        log.warning("viewframe cache %s: unreadable %s (%s), made again from meta.json", folder, _SUMMARY, err)
        return None
    m = len(got.rows)
    if not (
        got.viewframes.shape == (count,)
        and got.poses.shape == (count, 5)
        and got.landmarks.shape == got.pixels.shape == (m,)
        and got.centroids.shape == (m, 2)
        and (m == 0 or (0 <= got.rows.min() and got.rows.max() < count and bool((np.diff(got.rows) >= 0).all())))
    ):
        log.warning("viewframe cache %s: %s of other shapes than %d viewframes, made again", folder, _SUMMARY, count)
        return None
    return got


def entry_summary(entry: str | Path) -> EntrySummary | None:
    """What a map needs of the viewframes of the committed cache entry folder ``entry``
    (:class:`EntrySummary`), read from its ``summary.npz`` without parsing the descriptions; an
    entry without one (or with a stale or damaged one) has it made from its ``meta.json`` and
    written beside it (when the folder can be written; else it is made again on each read). None,
    logged, when the entry is not a committed entry of this format or its ``meta.json`` cannot be
    read."""
    folder = Path(entry)
    meta_path = folder / "meta.json"
    try:
        meta_bytes = meta_path.stat().st_size
        with meta_path.open("rb") as f:
            head = _meta_head(f.read(4096).decode("utf-8", errors="replace"), ("format", "count"))
    except (OSError, ValueError) as err:
        log.warning("viewframe cache %s: cannot read meta.json: %s", folder, err)
        return None
    if head.get("format") != _FORMAT or not isinstance(head.get("count"), int):
        log.warning("viewframe cache %s: entry format %r, expected %d", folder, head.get("format"), _FORMAT)
        return None
    count = int(head["count"])
    got = _read_summary(folder, count=count, meta_bytes=meta_bytes)
    if got is not None:
        return got
    try:
        text = meta_path.read_text()
        meta = json.loads(text)
        got = _summary_of(meta["values"], count)
    except (OSError, ValueError, KeyError, TypeError) as err:
        log.warning("viewframe cache %s: cannot summarise meta.json: %s", folder, err)
        return None
    try:
        _write_summary(folder, got, meta_bytes=len(text.encode()))
    except OSError as err:
        log.info("viewframe cache %s: cannot write %s (%s); it is made again on the next read", folder, _SUMMARY, err)
    return got
