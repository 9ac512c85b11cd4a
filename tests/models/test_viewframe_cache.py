"""The viewframe cache: a second world of the same map reads its viewframes from disk without a
renderer; any change of what determines them is a miss; concurrent runs share it safely."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from models import viewframe_cache
from models.scenario import scenario_from_dict
from models.viewframe_cache import ViewframeCache, cache_key, default_cache_root
from models.world import World
from tests.models import children
from tests.models.resident import needs_smaps, resident_kb

ROOT = Path(__file__).resolve().parents[2]


def _data(**extra):
    data = {
        "name": "cached",
        "seed": 4,
        "terrain": {"cell_size": 10.0, "procedural": {"size": 64, "relief": 40.0, "seed": 2}},
        "landmarks": [{"id": "H1", "kind": "house", "x": 260.0, "y": 320.0, "width": 20, "depth": 12, "height": 8}],
        "route": [[200, 300], [240, 310], [280, 305], [300, 300]],
        "camera": {"width": 64, "height": 48, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 2000.0},
        "render": {"views_per_leg": 1},  # a viewframe per route point (the entries' counts below)
    }
    data.update(extra)
    return data


def _same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x.index == y.index and x.pose == y.pose
        np.testing.assert_array_equal(x.image, y.image)
        np.testing.assert_array_equal(x.depth, y.depth)
        np.testing.assert_array_equal(x.mask, y.mask)
        assert x.image.dtype == y.image.dtype and x.mask.dtype == y.mask.dtype
        assert x.description == y.description
        for name in vars(x):  # every other field too, e.g. optional arrays added later
            a, b = getattr(x, name), getattr(y, name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                assert a is not None and b is not None, name
                np.testing.assert_array_equal(a, b)
            elif name not in ("description", "pose"):
                assert a == b, name


def test_a_second_world_reads_the_viewframes_without_rendering(tmp_path):
    cache = ViewframeCache(tmp_path)
    scenario = scenario_from_dict(_data())
    with World(scenario, cache=cache) as first:
        assert first.entry is None  # not built yet
        rendered = first.viewframes
        assert first._emulator is not None and cache.misses == 1 and cache.hits == 0
    entries = [p for p in tmp_path.iterdir()]
    assert len(entries) == 1 and (entries[0] / "meta.json").is_file()  # no temporary folder left
    assert first.entry == entries[0]  # the entry written
    with World(scenario_from_dict(_data()), cache=cache) as second:
        cached = second.viewframes
        assert second._emulator is None  # no renderer opened
        assert cache.hits == 1
        assert second.priors == first.priors
        assert second.entry == entries[0]  # the entry read
    assert World(scenario_from_dict(_data()), cache=None).entry is None
    _same(rendered, cached)
    cached[0].image[0, 0] = 7  # copy-on-write: writable, and the entry is unchanged
    _same(rendered, World(scenario_from_dict(_data()), cache=cache).viewframes)


@pytest.mark.parametrize(
    "change",
    [
        {"landmarks": [{"id": "H1", "kind": "house", "x": 262.0, "y": 320.0, "width": 20, "depth": 12, "height": 8}]},
        {"camera": {"width": 64, "height": 48, "fov_y_deg": 50, "eye_height": 2.0, "near": 1.0, "far": 2000.0}},
        {"route": [[200, 300], [240, 310], [280, 305], [301, 300]]},
        {"terrain": {"cell_size": 10.0, "procedural": {"size": 64, "relief": 41.0, "seed": 2}}},
        {"render": {"views_per_leg": 3}},
    ],
    ids=["landmark", "camera", "route", "terrain", "views-per-leg"],
)
def test_any_change_of_the_map_is_a_miss(change):
    base = scenario_from_dict(_data())
    changed = scenario_from_dict(_data(**change))
    with World(base, cache=None) as a, World(changed, cache=None) as b:
        assert cache_key(base, a.environment.terrain) == cache_key(scenario_from_dict(_data()), a.environment.terrain)
        assert cache_key(base, a.environment.terrain) != cache_key(changed, b.environment.terrain)


def test_optional_array_fields_round_trip(tmp_path):
    import dataclasses

    rendered = World(scenario_from_dict(_data()), cache=None).viewframes
    optional = [f.name for f in dataclasses.fields(rendered[0]) if f.default is None]
    if not optional:
        pytest.skip("Viewframe has no optional field")
    name = optional[0]
    mixed = [dataclasses.replace(vf, **{name: None if i % 2 else vf.image.copy()}) for i, vf in enumerate(rendered)]
    cache = ViewframeCache(tmp_path)
    cache.store("k" * 64, mixed)
    back = cache.load("k" * 64)
    assert [getattr(vf, name) is None for vf in back] == [i % 2 == 1 for i in range(len(mixed))]
    _same(mixed, back)


def test_the_writer_takes_rows_in_any_order_and_arrays_of_several_shapes(tmp_path):
    import dataclasses

    heap = World(scenario_from_dict(_data()), cache=None).viewframes
    # the last viewframe's image half as tall: that field goes one file per row
    varied = heap[:-1] + [dataclasses.replace(heap[-1], image=np.ascontiguousarray(heap[-1].image[::2]))]
    cache = ViewframeCache(tmp_path)
    writer = cache.writer("w" * 64, len(varied))
    for row in reversed(range(len(varied))):
        writer.put(row, varied[row])
    assert "w" * 64 not in cache  # nothing readable before the commit
    writer.commit()
    back = cache.read("w" * 64)
    assert back is not None and cache.hits == cache.misses == 0  # read() counts neither
    _same(varied, back)
    assert [vf.image.shape[0] for vf in back] == [48, 48, 48, 24]
    short = cache.writer("s" * 64, 3)
    short.put(0, heap[0])
    with pytest.raises(ValueError, match=r"rows \[1, 2\] of 3 were never written"):
        short.commit()
    assert "s" * 64 not in cache and sorted(p.name for p in tmp_path.iterdir()) == ["w" * 64]


def test_a_rendering_world_writes_the_cache_as_it_renders_and_maps_it(tmp_path):
    scenario = scenario_from_dict(_data())
    heap = World(scenario, cache=None).viewframes
    cache = ViewframeCache(tmp_path)
    with World(scenario, cache=cache) as world:
        mapped = world.viewframes
        assert cache.misses == 1 and cache.hits == 0
    _same(heap, mapped)  # the same viewframes as rendered into memory
    for vf in mapped:  # but held by the cache's files, not in this process's heap
        for a in (vf.image, vf.depth, vf.mask):
            base = a
            while base.base is not None and not isinstance(base, np.memmap):
                base = base.base
            assert isinstance(base, np.memmap)


def test_a_new_renderer_version_is_a_miss(tmp_path, monkeypatch):
    cache = ViewframeCache(tmp_path)
    scenario = scenario_from_dict(_data())
    _ = World(scenario, cache=cache).viewframes
    assert World(scenario, cache=cache).viewframes and cache.hits == 1
    monkeypatch.setattr(viewframe_cache, "RENDERER_VERSION", viewframe_cache.RENDERER_VERSION + 1)
    with World(scenario, cache=cache) as world:
        _ = world.viewframes
        assert world._emulator is not None and cache.hits == 1 and cache.misses == 2
    assert len(list(tmp_path.iterdir())) == 2


def test_an_unreadable_entry_is_a_miss_and_rendered_again(tmp_path):
    cache = ViewframeCache(tmp_path)
    scenario = scenario_from_dict(_data())
    rendered = World(scenario, cache=cache).viewframes
    (entry,) = tmp_path.iterdir()
    # replaced, not overwritten in place: the first world's viewframes map the entry's files
    (entry / "garbage").write_bytes(b"garbage")
    (entry / "garbage").replace(entry / "image.npy")
    with World(scenario, cache=cache) as world:
        _same(rendered, world.viewframes)
        assert world._emulator is not None


def test_the_cache_folder_comes_from_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("MAPINTERP_CACHE", str(tmp_path / "c"))
    assert default_cache_root() == tmp_path / "c"
    assert World(scenario_from_dict(_data())).cache.root == tmp_path / "c"
    monkeypatch.setenv("MAPINTERP_CACHE", "off")
    assert default_cache_root() is None and World(scenario_from_dict(_data())).cache is None
    monkeypatch.delenv("MAPINTERP_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert default_cache_root() == tmp_path / "xdg" / "mapinterp"


_CHILD = """
import hashlib, json, sys
from models.world import World
with World.from_scenario(sys.argv[1]) as world:
    vfs = world.viewframes
    h = hashlib.sha256()
    for vf in vfs:
        h.update(vf.image.tobytes()); h.update(vf.mask.tobytes()); h.update(vf.depth.tobytes())
    print(json.dumps({"digest": h.hexdigest(), "rendered": world._emulator is not None, "n": len(vfs)}))
"""


def test_two_processes_share_a_cache_at_once(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(_data()))
    cache = tmp_path / "cache"
    env = {**os.environ, "MAPINTERP_CACHE": str(cache), "PYOPENGL_PLATFORM": "egl"}
    outs = children.outputs(children.start(_CHILD, [str(path)], env=env))
    assert outs[0]["digest"] == outs[1]["digest"] and outs[0]["n"] == 4
    entries = list(cache.iterdir())
    assert len(entries) == 1 and not entries[0].name.startswith(".")  # one entry, no temporary left
    third = subprocess.run(
        [sys.executable, "-c", _CHILD, str(path)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300
    )
    assert third.returncode == 0, third.stderr
    result = json.loads(third.stdout.strip().splitlines()[-1])
    assert result["digest"] == outs[0]["digest"] and result["rendered"] is False


def _rss_file_kb() -> int:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("RssFile:"))


def test_released_pages_of_a_cache_entry_leave_this_process(tmp_path):
    from models.viewframe_cache import release_pages

    rows = np.broadcast_to(np.arange(64, dtype=np.uint8)[:, None], (64, 512 * 1024))  # 64 rows, 32 MB
    np.save(tmp_path / "a.npy", np.ascontiguousarray(rows))
    mapped = np.load(tmp_path / "a.npy", mmap_mode="c")
    views = [np.asarray(mapped[i]) for i in range(64)]
    views[5][0] = 99  # a written (copy-on-write) page is kept, not lost
    before = _rss_file_kb()
    total = sum(int(v[::4096].sum()) for v in views)  # touch every page
    touched = _rss_file_kb() - before
    assert touched > 24 * 1024  # the 32 MB read are resident
    assert release_pages(views) >= 32 * 1024 * 1024 - 4096
    assert _rss_file_kb() - before < touched / 4  # and given back
    assert sum(int(v[::4096].sum()) for v in views) == total and views[5][0] == 99  # still readable, unchanged
    assert release_pages([np.zeros(10), None]) == 0  # arrays not from a memory map are left alone


# -- the pixels of one viewframe read from an entry (viewframe messages by reference) ---------------


@pytest.fixture(scope="module")
def entry(tmp_path_factory) -> tuple[Path, list]:
    """A committed entry of a route whose first viewframe shows the landmark (a background) and
    whose others may not, and the viewframes rendered without a cache (the reference)."""
    data = _data(route=[[200, 300], [240, 310], [280, 305], [300, 300], [330, 300]])
    cache = ViewframeCache(tmp_path_factory.mktemp("pixels"))
    with World(scenario_from_dict(data), cache=cache) as world:
        _ = world.viewframes
        folder = world.entry
    with World(scenario_from_dict(data), cache=None) as world:
        rendered = world.viewframes
    assert folder is not None and {vf.background is None for vf in rendered} == {True, False}
    return folder, rendered


def test_read_pixels_gives_each_row_as_rendered(entry) -> None:
    folder, rendered = entry
    for vf in rendered:
        px = viewframe_cache.read_pixels(folder, vf.index, count=len(rendered))
        np.testing.assert_array_equal(px.image, vf.image)
        assert px.mask.dtype == np.int16 and np.array_equal(px.mask, vf.mask)
        assert (px.background is None) == (vf.background is None)
        if vf.background is not None:
            np.testing.assert_array_equal(px.background, vf.background)
        # copies, not views of the memory map: nothing of the entry stays mapped through them
        assert px.image.base is None or not isinstance(px.image.base, np.memmap)
        px.image[:] = 0  # and writing them leaves the entry as it was
    again = viewframe_cache.read_pixels(folder, 0, count=len(rendered))
    np.testing.assert_array_equal(again.image, rendered[0].image)


def _stale(folder: Path, tmp: Path, what: str) -> tuple[Path, int, int]:
    """(entry, row, count) of a reference that does not fit: see the cases of the test."""
    n = len(json.loads((folder / "meta.json").read_text())["values"]["index"])
    if what == "missing":
        return tmp / ("0" * 64), 0, n
    if what == "uncommitted":  # an entry being written: its arrays, no meta.json yet
        part = tmp / "partial"
        part.mkdir()
        for f in folder.glob("*.npy"):
            (part / f.name).write_bytes(f.read_bytes())
        return part, 0, n
    if what == "count":
        return folder, 0, n + 1
    if what == "row":
        return folder, n, n
    if what == "relative":
        return Path(folder.name), 0, n
    if what == "format":
        other = tmp / "format"
        other.mkdir()
        (other / "meta.json").write_text(json.dumps({"format": 99, "count": n}))
        return other, 0, n
    raise AssertionError(what)


STALE = {
    "missing": "no such viewframe cache entry",
    "uncommitted": "not a committed viewframe cache entry",
    "count": "the entry holds 5 viewframes, the reference says 6",
    "row": r"row 5 out of range \[0, 5\)",
    "relative": "absolute path",
    "format": "entry format 99",
}


@pytest.mark.parametrize("what", STALE, ids=STALE)
def test_read_pixels_of_a_stale_or_forged_reference_names_the_entry(entry, tmp_path, what) -> None:
    from models.errors import CacheEntryError

    folder, _ = entry
    where, row, count = _stale(folder, tmp_path, what)
    with pytest.raises(CacheEntryError, match=STALE[what]) as err:
        viewframe_cache.read_pixels(where, row, count=count)
    assert str(err.value).startswith(str(where)) and err.value.path == where


def test_at_most_a_few_entries_stay_open(entry, tmp_path) -> None:
    """Each entry read is opened once per process; only the last OPEN_ENTRIES stay open."""
    folder, rendered = entry
    copies = []
    for i in range(viewframe_cache.OPEN_ENTRIES + 2):
        copy = tmp_path / f"copy{i}"
        copy.mkdir()
        for f in folder.iterdir():
            (copy / f.name).write_bytes(f.read_bytes())
        copies.append(copy)
        viewframe_cache.read_pixels(copy, 1, count=len(rendered))
        viewframe_cache.read_pixels(copy, 2, count=len(rendered))
    opened = list(viewframe_cache._open)
    assert opened[-viewframe_cache.OPEN_ENTRIES :] == copies[-viewframe_cache.OPEN_ENTRIES :]
    assert len(opened) == viewframe_cache.OPEN_ENTRIES and copies[0] not in opened


META_HEADS = {
    "values-last": ('{"format": 2, "count": 3, "values": {"x": [1, 2, 3]}}', {"format": 2, "count": 3}),
    "values-first": (
        '{"values": {"x": [1]}, "count": 3, "format": 2}',
        {"values": {"x": [1]}, "count": 3, "format": 2},
    ),
    "spaces": (' {\n "format" : 2 ,\n "count":3 } ', {"format": 2, "count": 3}),
    "key-missing": ('{"format": 2}', {"format": 2}),
}


@pytest.mark.parametrize(("text", "head"), META_HEADS.values(), ids=META_HEADS.keys())
def test_the_head_of_meta_json_is_parsed_up_to_the_keys_asked(text, head) -> None:
    """A reader of pixels parses meta.json only up to the keys it needs (the descriptions, most of
    the file, come last): the same values as a whole parse."""
    assert viewframe_cache._meta_head(text, ("format", "count")) == head
    assert all(json.loads(text)[k] == v for k, v in head.items())


@pytest.mark.parametrize("text", ["[1, 2]", '{"format" 2}', '{"format": 2 "count": 3}', '{"format": 2, "count"'])
def test_a_malformed_meta_json_head_is_a_value_error(text) -> None:
    with pytest.raises(ValueError):
        viewframe_cache._meta_head(text, ("format", "count"))


def test_a_description_read_from_an_entry_builds_its_graph_on_first_use(entry) -> None:
    """Read back, a viewframe's description answers ``visible`` and ``to_dict`` from the stored
    data, and builds the same graph as the rendered one's when it is first asked for."""
    from models.viewframe_cache import StoredDescription

    folder, rendered = entry
    back = ViewframeCache(folder.parent).load(folder.name)
    assert back is not None
    for vf, vr in zip(back, rendered):
        d = vf.description
        assert isinstance(d, StoredDescription) and d._graph is None
        assert d.visible == vr.description.visible and d.to_dict() == vr.description.to_dict() and d == vr.description
        assert d._graph is None  # none of these built it
        g, gr = d.graph, vr.description.graph
        assert dict(g.nodes(data=True)) == dict(gr.nodes(data=True)) and list(g.edges) == list(gr.edges)
        assert d.visible == vr.description.visible and d.to_dict() == vr.description.to_dict()


@pytest.mark.parametrize(
    "data",
    [[], {"visible": ["H1"], "nodes": {}, "edges": []}, {"visible": [], "nodes": {}}, {"visible": "H1", "nodes": {}}],
)
def test_a_malformed_stored_description_is_a_value_error(data) -> None:
    from models.viewframe_cache import StoredDescription

    with pytest.raises(ValueError, match="malformed symbolic description"):
        StoredDescription(data)


@needs_smaps
def test_reading_pixels_leaves_none_of_the_entry_resident(entry) -> None:
    """read_pixels copies the row and gives the mapped pages back (with the neighbours a page
    fault maps too): having read every row, none of the entry's image map is resident here."""
    folder, rendered = entry
    for vf in rendered:
        viewframe_cache.read_pixels(folder, vf.index, count=len(rendered))
    stacked = viewframe_cache._open[folder]._stacked["image"]
    address = int(np.frombuffer(stacked._mmap, dtype=np.uint8, count=1).ctypes.data)
    assert stacked.nbytes > 8 * 4096  # a map of several pages, touched by every read
    assert resident_kb(address) == 0
    _ = np.array(stacked[1])  # read without read_pixels: resident (the test can see it)
    assert resident_kb(address) > 0


def test_an_entrys_stacked_field_is_read_memory_mapped_or_none_with_a_warning(tmp_path, caplog):
    import dataclasses

    from models.viewframe_cache import entry_field

    heap = World(scenario_from_dict(_data()), cache=None).viewframes
    cache = ViewframeCache(tmp_path)
    cache.store("a" * 64, heap)
    images = entry_field(cache.path("a" * 64), "image", count=len(heap))
    assert isinstance(images, np.memmap) and not images.flags.writeable
    assert all(np.array_equal(images[k], vf.image) for k, vf in enumerate(heap))  # row k is viewframe k
    # ragged (one file per row), another count, no entry: None, each with a warning naming the entry
    varied = heap[:-1] + [dataclasses.replace(heap[-1], image=np.ascontiguousarray(heap[-1].image[::2]))]
    cache.store("r" * 64, varied)
    with caplog.at_level("WARNING", logger="models.viewframe_cache"):
        assert entry_field(cache.path("r" * 64), "image") is None
        assert entry_field(cache.path("a" * 64), "image", count=len(heap) + 1) is None
        assert entry_field(tmp_path / "nowhere", "image") is None
    assert caplog.text.count("cannot read image.npy") == 3 and str(cache.path("r" * 64)) in caplog.text


def test_entry_field_and_read_pixels_read_one_open_entry(entry) -> None:
    """The two readers of an entry open it once, the same way: the stacked field is the map
    read_pixels reads its rows from; another stacked field (the skylines) is mapped on first use;
    a field absent in some rows (the background) or not held is None."""
    from models.viewframe_cache import entry_field

    folder, rendered = entry
    images = entry_field(folder, "image", count=len(rendered))
    assert images is viewframe_cache._open[folder].stacked("image")
    px = viewframe_cache.read_pixels(folder, 1, count=len(rendered))
    assert np.array_equal(px.image, images[1])
    skylines = entry_field(folder, "skyline", count=len(rendered))
    assert isinstance(skylines, np.memmap) and not skylines.flags.writeable
    assert all(np.array_equal(skylines[vf.index], vf.skyline, equal_nan=True) for vf in rendered)
    assert entry_field(folder, "background") is None and entry_field(folder, "nope") is None


def test_release_behind_gives_back_the_last_two_batches_after_each_batch(monkeypatch) -> None:
    """After every ``every``-th row and the last: the arrays of the last ``2 * every`` rows."""
    from models.viewframe_cache import release_behind

    asked: list[list[int]] = []
    monkeypatch.setattr(
        viewframe_cache, "release_pages", lambda arrays: asked.append([int(a[0]) for a in arrays if a is not None])
    )
    rows = list(range(10))
    done = [k for k in rows if release_behind(k, rows, lambda r: (np.array([r]), None), every=4)]
    assert done == [3, 7, 9]
    assert asked == [[0, 1, 2, 3], [0, 1, 2, 3, 4, 5, 6, 7], [2, 3, 4, 5, 6, 7, 8, 9]]
    monkeypatch.setattr(viewframe_cache, "RELEASE_EVERY", 5)  # the default, read at the call
    assert [k for k in rows if release_behind(k, rows, lambda r: ())] == [4, 9]


# -- what a map needs of an entry, without parsing its descriptions (summary.npz) -------------------


def _no_json(monkeypatch) -> None:
    """Parsing meta.json in full fails from now on (its head is parsed by a JSONDecoder, not json.loads)."""

    def refuse(*args, **kwargs):
        raise AssertionError("meta.json parsed")

    monkeypatch.setattr(viewframe_cache.json, "loads", refuse)


def _summaries_equal(a, b) -> None:
    for name in viewframe_cache.EntrySummary._fields:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), name


def test_a_committed_entry_is_summarised_without_parsing_its_descriptions(entry, monkeypatch) -> None:
    """The entry writer leaves summary.npz beside meta.json: the index and pose of every viewframe
    and, per landmark visible in it (in description order), its id, pixels and centroid, read back
    without parsing meta.json's descriptions; the same values as the rendered viewframes'."""
    folder, rendered = entry
    assert (folder / "summary.npz").is_file()
    _no_json(monkeypatch)
    got = viewframe_cache.entry_summary(folder)
    assert got is not None
    assert got.viewframes.tolist() == [vf.index for vf in rendered]
    assert got.poses.tolist() == [
        [vf.pose.x, vf.pose.y, vf.pose.z, vf.pose.heading_deg, vf.pose.pitch_deg] for vf in rendered
    ]
    assert got.visible() == [vf.description.visible for vf in rendered] and any(got.visible())
    nodes = [
        (k, lm, vf.description.to_dict()["nodes"][lm]) for k, vf in enumerate(rendered) for lm in vf.description.visible
    ]
    assert got.rows.tolist() == [k for k, _, _ in nodes] and got.landmarks.tolist() == [lm for _, lm, _ in nodes]
    assert got.pixels.tolist() == [int(n["pixels"]) for _, _, n in nodes]
    assert got.centroids.tolist() == [list(map(float, n["centroid"])) for _, _, n in nodes]


@pytest.mark.parametrize("change", ["absent", "other-format", "other-meta-json", "damaged", "other-count"])
def test_an_entry_without_a_usable_summary_is_summarised_from_meta_json_once(entry, tmp_path, monkeypatch, change):
    """An entry written before summaries (none beside its meta.json), or with one of another
    SUMMARY_FORMAT, made from another meta.json, of other shapes or damaged: summarised from its
    meta.json (the same summary) and the summary written beside it, so the next read parses nothing."""
    import shutil

    folder, _ = entry
    expected = viewframe_cache.entry_summary(folder)
    assert expected is not None
    copy = tmp_path / folder.name
    shutil.copytree(folder, copy)
    summary = copy / "summary.npz"
    meta_bytes = (copy / "meta.json").stat().st_size
    if change == "absent":
        summary.unlink()
    elif change == "other-format":
        monkeypatch.setattr(viewframe_cache, "SUMMARY_FORMAT", viewframe_cache.SUMMARY_FORMAT + 1)
        viewframe_cache._write_summary(copy, expected, meta_bytes=meta_bytes)
        monkeypatch.undo()
    elif change == "other-meta-json":
        viewframe_cache._write_summary(copy, expected, meta_bytes=meta_bytes + 1)
    elif change == "other-count":
        viewframe_cache._write_summary(
            copy, expected._replace(viewframes=expected.viewframes[:-1]), meta_bytes=meta_bytes
        )
    else:
        summary.write_bytes(b"PK\x03\x04 not a zip")
    got = viewframe_cache.entry_summary(copy)
    assert got is not None
    _summaries_equal(got, expected)
    assert summary.is_file() and not list(copy.glob(".summary.*"))
    _no_json(monkeypatch)  # written again: read without parsing meta.json
    again = viewframe_cache.entry_summary(copy)
    assert again is not None
    _summaries_equal(again, expected)


def test_an_entry_of_another_format_is_not_summarised(entry, tmp_path, caplog) -> None:
    """An entry whose meta.json says another format (or is not there) has no summary: None, logged."""
    import shutil

    folder, _ = entry
    copy = tmp_path / folder.name
    shutil.copytree(folder, copy)
    meta = json.loads((copy / "meta.json").read_text())
    meta["format"] = 1
    (copy / "meta.json").write_text(json.dumps(meta))
    assert viewframe_cache.entry_summary(copy) is None
    assert "format 1" in caplog.text
    assert viewframe_cache.entry_summary(tmp_path / "nowhere") is None


def test_a_world_summarises_its_cached_viewframes_without_reading_them(tmp_path, monkeypatch) -> None:
    """World.summary: None on a miss; on a hit the entry's summary (and the entry, and the priors
    the viewframes give), without reading the viewframes."""
    cache = ViewframeCache(tmp_path)
    scenario = scenario_from_dict(_data())
    with World(scenario, cache=cache) as first:
        assert first.summary() is None  # a miss: nothing to summarise yet
        rendered, priors = first.viewframes, first.priors
    with World(scenario, cache=cache) as world:
        got = world.summary()
        assert got is not None and world.entry == first.entry and cache.hits == 1
        assert world.priors == priors and "viewframes" not in world.__dict__
        assert got.visible() == [vf.description.visible for vf in rendered]
