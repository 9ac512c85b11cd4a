"""The associative indexer on an in-memory board: its shards (the lifecycle it shares with the
skyline ranker is tested in test_ranker.py)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from blackboard.memory_board import MemoryBlackboard
from knowledge_sources import levels
from knowledge_sources.indexer import AssociativeIndexer
from models.index_store import INDEX_FOLDER
from tests.knowledge_sources.conftest import inline_viewframe
from tests.knowledge_sources.rankers import frames_from_viewframes, post_map, repost, track
from tests.models.resident import needs_smaps, resident_kb


@pytest.mark.parametrize("shards", [1, 2])
def test_each_shard_stores_its_viewframes_and_ranks_every_frame(small_rendered: dict, shards: int) -> None:
    bb = MemoryBlackboard()
    for b in range(shards):
        bb.add(AssociativeIndexer(f"indexer-{b}", shard=b, shards=shards))
    for h in small_rendered["viewframes"]:
        repost(bb, h)
    repost(bb, small_rendered["map"])
    bb.run()
    n = len(small_rendered["viewframes"])
    index = {i.shard: i for i in (levels.Index.from_hypothesis(h) for h in bb.hypotheses(levels.INDEX))}
    assert sorted(index) == list(range(shards)) and sum(i.viewframes for i in index.values()) == n
    frames_from_viewframes(bb, small_rendered, list(range(n)))
    bb.run()
    rankings = [levels.Ranking.from_hypothesis(h) for h in bb.hypotheses(levels.RANKING)]
    assert len(rankings) == n * shards
    for r in rankings:
        assert set(r.viewframes) == {k for k in range(n) if k % shards == r.shard}
        assert r.variances == sorted(r.variances) and r.shards == shards
        if r.frame % shards == r.shard:
            assert r.viewframes[0] == r.frame  # the frame is its own viewframe
        h = bb.user.get(levels.ranking_id(r.frame, r.shard))
        assert h is not None and h.links == (levels.frame_id(r.frame),) and 0.0 <= h.credibility <= 1.0


def _map_without_entry(bb: MemoryBlackboard, small_rendered: dict) -> None:
    """The map, saying its viewframes were rendered without a cache (a test that changes or drops
    viewframe messages: they are no longer those of the map's cache entry)."""
    bb.post(levels.MAP, {**small_rendered["map"].body, "entry": None}, id=levels.map_id())


@pytest.mark.parametrize("keep_images", [True, False])
def test_a_missing_viewframe_is_an_error(small_rendered: dict, keep_images: bool) -> None:
    bb = MemoryBlackboard()
    bb.add(AssociativeIndexer("indexer-0", keep_images=keep_images))
    for h in small_rendered["viewframes"][:-1]:
        repost(bb, h)
    _map_without_entry(bb, small_rendered)
    with pytest.raises(RuntimeError, match="viewframe 7 is on neither"):
        bb.run()


def test_bad_shard_options() -> None:
    with pytest.raises(ValueError, match="shard"):
        AssociativeIndexer("indexer", shard=2, shards=2)


def _block_shards(small_rendered: dict) -> tuple[MemoryBlackboard, list[AssociativeIndexer], int]:
    """Three tracked shards of three consecutive route points each (``block``) on a board with the
    map (every route point windowed, no margin): ``(board, indexers, viewframes)``."""
    bb = MemoryBlackboard()
    n = len(small_rendered["viewframes"])
    indexers = [
        AssociativeIndexer(f"indexer-{b}", shard=b, shards=3, block=3, tracked=True, keep_images=True) for b in range(3)
    ]
    for ix in indexers:
        bb.add(ix)
    post_map(bb, small_rendered, window_route_points=n, window_margin=0, window_full_every=10)
    return bb, indexers, n


def test_consecutive_shards_outside_the_track_window_post_an_empty_ranking(small_rendered: dict) -> None:
    """Shards of consecutive route points (``block``): a windowed frame's ranking comes from the
    shards the window covers; the others post an empty ranking; together the full order within it."""
    bb, indexers, n = _block_shards(small_rendered)
    bb.run()
    stored = {i.shard: i.viewframes for i in (levels.Index.from_hypothesis(h) for h in bb.hypotheses(levels.INDEX))}
    assert stored == {0: 3, 1: 3, 2: 2}
    # each shard keeping images decodes only its own viewframes' messages (told by their id)
    assert [ix.wants(levels.VIEWFRAME, levels.viewframe_id(4)) for ix in indexers] == [False, True, False]
    assert all(ix.wants(levels.SENSOR_FRAME, levels.frame_id(4)) for ix in indexers)
    frames_from_viewframes(bb, small_rendered, [0])
    bb.run()
    full = {b: levels.Ranking.from_hypothesis(bb.user.get(levels.ranking_id(0, b))) for b in range(3)}
    assert [sorted(full[b].viewframes) for b in range(3)] == [[0, 1, 2], [3, 4, 5], [6, 7]]
    levels.post(bb.user, track(0, "tracking", 4, n))  # frame 1 predicted at route point 4 only
    bb.run()
    frames_from_viewframes(bb, small_rendered, [1])
    bb.run()
    got = {b: levels.Ranking.from_hypothesis(bb.user.get(levels.ranking_id(1, b))) for b in range(3)}
    assert all(ix.windows[1] == (4, 4) for ix in indexers)
    assert got[0].viewframes == [] and got[2].viewframes == [] and got[1].viewframes == [4]


def test_a_shard_outside_the_track_window_posts_its_empty_ranking_without_ranking(small_rendered: dict) -> None:
    """A shard none of whose viewframes is in the frame's window posts the empty ranking without
    going into its index (for a stored shard: without waiting its turn among the process's
    stored shards, :data:`MAPPED_RANKINGS`, and without mapping its rows): at 10,000 viewframes
    19 of the 20 shards are outside a tracked frame's window."""
    bb, indexers, n = _block_shards(small_rendered)
    frames_from_viewframes(bb, small_rendered, [0])
    bb.run()
    levels.post(bb.user, track(0, "tracking", 4, n))  # frame 1 predicted at route point 4 only: shard 1's
    bb.run()
    entered: list[int] = []
    for ix in indexers:
        plain = ix._ranked
        ix._ranked = lambda image, among, ix=ix, plain=plain: entered.append(ix.shard) or plain(image, among)  # type: ignore[method-assign]
    frames_from_viewframes(bb, small_rendered, [1])
    bb.run()
    got = {b: levels.Ranking.from_hypothesis(bb.user.get(levels.ranking_id(1, b))) for b in range(3)}
    assert entered == [1]
    assert got[0].viewframes == [] and got[2].viewframes == [] and got[1].viewframes == [4]
    assert got[0].reliability == got[2].reliability == 0.0 and got[0].shards == 3 and got[0].frame == 1


def test_bad_block_option() -> None:
    with pytest.raises(ValueError, match="block"):
        AssociativeIndexer("indexer", block=0)


@pytest.mark.parametrize("keep_images", [True, False])
def test_a_featureless_viewframe_is_named_in_the_index_and_the_shard_ranks_the_others(
    small_rendered: dict, keep_images: bool
) -> None:
    """A viewframe whose image is constant (a camera inside a landmark) used to fail the shard's
    whole index, so the camera waited for it forever; now it is left out and named."""
    import dataclasses

    bb = MemoryBlackboard()
    bb.add(AssociativeIndexer("indexer-0", keep_images=keep_images))
    n = len(small_rendered["viewframes"])
    for h in small_rendered["viewframes"]:
        vf = levels.Viewframe.from_hypothesis(h)
        if vf.index == 4:  # posted inline, whether the others are inline or by reference
            inline = inline_viewframe(vf)
            vf = dataclasses.replace(inline, image=np.full_like(inline.image, 90))
        levels.post(bb.user, vf)
    _map_without_entry(bb, small_rendered)
    bb.run()
    (index,) = [levels.Index.from_hypothesis(h) for h in bb.hypotheses(levels.INDEX)]
    assert index.featureless == [4] and index.viewframes == n - 1
    frames_from_viewframes(bb, small_rendered, [2, 6])
    bb.run()
    for f in (2, 6):
        r = levels.Ranking.from_hypothesis(bb.user.get(levels.ranking_id(f, 0)))
        assert sorted(r.viewframes) == [k for k in range(n) if k != 4] and r.viewframes[0] == f


def _entry_copy(small_rendered: dict, tmp_path: Path) -> Path:
    """A copy of the small map's viewframe cache entry without its stored indices (the same name
    and files: the same identity, so what is stored in the copy is what a second run would find)."""
    entry = Path(small_rendered["map"].body["entry"])
    copy = tmp_path / "cache" / entry.name
    shutil.copytree(entry, copy, ignore=shutil.ignore_patterns(INDEX_FOLDER))
    return copy


def _run_shards(small_rendered: dict, entry: Path, shards: int, *, viewframes: bool, **memory: object) -> tuple:
    """The shards on a fresh board with the map naming ``entry`` (and the viewframe messages when
    ``viewframes``), then every viewframe as a camera frame: ``(indexers, {(frame, shard): ranking})``."""
    bb = MemoryBlackboard()
    indexers = [AssociativeIndexer(f"indexer-{b}", shard=b, shards=shards) for b in range(shards)]
    for ix in indexers:
        bb.add(ix)
    if viewframes:
        for h in small_rendered["viewframes"]:
            repost(bb, h)
    body = dict(small_rendered["map"].body)
    bb.post(levels.MAP, {**body, "entry": str(entry), "memory": {**body["memory"], **memory}}, id=levels.map_id())
    bb.run()
    n = len(small_rendered["viewframes"])
    frames_from_viewframes(bb, small_rendered, list(range(n)))
    bb.run()
    rankings = {
        (r.frame, r.shard): r for r in (levels.Ranking.from_hypothesis(h) for h in bb.hypotheses(levels.RANKING))
    }
    return indexers, rankings


@pytest.mark.parametrize("shards", [1, 2])
def test_a_second_run_of_the_map_loads_the_stored_index_without_its_viewframes(
    small_rendered: dict, tmp_path: Path, shards: int
) -> None:
    entry = _entry_copy(small_rendered, tmp_path)
    first, want = _run_shards(small_rendered, entry, shards, viewframes=True)
    assert not any(ix.loaded for ix in first) and len(list((entry / INDEX_FOLDER).iterdir())) == shards
    # a cache is on in the tests: the viewframe level is not even consumed
    assert not any(ix.keep_images or levels.VIEWFRAME in ix.consumes for ix in first)
    second, got = _run_shards(small_rendered, entry, shards, viewframes=False)  # a stored index needs none
    assert all(ix.loaded for ix in second) and sorted(got) == sorted(want)
    for k, r in got.items():
        assert r.viewframes == want[k].viewframes  # the same order
        np.testing.assert_allclose(r.variances, want[k].variances, rtol=1e-5, atol=1e-9)
    n = len(small_rendered["viewframes"])
    assert all(got[(f, f % shards)].viewframes[0] == f for f in range(n))


def test_a_changed_memory_setting_indexes_again(small_rendered: dict, tmp_path: Path) -> None:
    entry = _entry_copy(small_rendered, tmp_path)
    _run_shards(small_rendered, entry, 1, viewframes=True)
    (ix,), _ = _run_shards(small_rendered, entry, 1, viewframes=True, blur_sigma=2.0)
    assert not ix.loaded and len(list((entry / INDEX_FOLDER).iterdir())) == 2
    (ix,), _ = _run_shards(small_rendered, entry, 1, viewframes=False, window_margin=3)  # ranking only: a hit
    assert ix.loaded


def test_a_miss_reads_the_images_from_the_entry_or_else_back_from_the_board(
    small_rendered: dict, tmp_path: Path, caplog
) -> None:
    entry = _entry_copy(small_rendered, tmp_path)
    _, want = _run_shards(small_rendered, entry, 1, viewframes=False)  # from the entry: no message needed
    other = _entry_copy(small_rendered, tmp_path / "other")
    (other / "image.npy").unlink()  # an entry whose images cannot be read here
    with caplog.at_level("WARNING", logger="models.viewframe_cache"):
        (ix,), got = _run_shards(small_rendered, other, 1, viewframes=True)
    assert not ix.loaded and "cannot read image.npy" in caplog.text
    for k, r in got.items():
        assert r.viewframes == want[k].viewframes
        np.testing.assert_allclose(r.variances, want[k].variances, rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize("cache, keeps", [("off", True), ("OFF", True), ("some/folder", False)])
def test_images_are_kept_as_they_come_only_without_a_viewframe_cache(monkeypatch, cache: str, keeps: bool) -> None:
    """Without a cache (``--no-cache``) no map names an entry: each image is kept as its message
    comes; with one, the map decides, and the viewframe level is not subscribed to."""
    monkeypatch.setenv("MAPINTERP_CACHE", cache)
    ix = AssociativeIndexer("indexer-0")
    assert ix.keep_images is keeps and (levels.VIEWFRAME in ix.consumes) is keeps
    assert AssociativeIndexer.consumes == (levels.VIEWFRAME, levels.MAP, levels.SENSOR_FRAME, levels.TRACK)
    assert AssociativeIndexer("indexer-0", keep_images=not keeps).keep_images is not keeps


@needs_smaps
def test_a_stored_index_leaves_none_of_its_rows_resident_after_a_ranking(small_rendered: dict, tmp_path: Path) -> None:
    """A loaded shard's ranking rows are memory-mapped from the stored index: each ranking gives
    the pages it read back (the page cache keeps them), so a long route's rows do not all stay
    resident once ranked; the rankings are those of the index as built."""
    entry = _entry_copy(small_rendered, tmp_path)
    _, want = _run_shards(small_rendered, entry, 1, viewframes=True)
    (ix,), got = _run_shards(small_rendered, entry, 1, viewframes=False)
    assert ix.loaded
    rows = ix._index.memory.ranking_matrix
    assert rows.nbytes > 8 * 4096  # several pages, every one read by the full rankings
    assert resident_kb(int(rows.ctypes.data)) == 0
    _ = float(np.asarray(rows).sum())  # read without a ranking: resident (the test can see it)
    assert resident_kb(int(rows.ctypes.data)) > 0
    assert all(r.viewframes == want[k].viewframes for k, r in got.items())


def _most_at_once(group: list, call, monkeypatch) -> tuple[int, dict[int, object]]:
    """``call(ix)`` for every shard ``ix`` of ``group``, each in its own thread started at once, each
    shard's index ranking slowed by 0.2 s (long enough for every thread to try at once): the most
    rankings under way at once, and each shard's result."""
    import threading
    import time

    lock, inside, most = threading.Lock(), [0], [0]
    for ix in group:
        plain = ix._index.rank

        def rank(image, *, among=None, plain=plain):
            with lock:
                inside[0] += 1
                most[0] = max(most[0], inside[0])
            time.sleep(0.2)
            try:
                return plain(image, among=among)
            finally:
                with lock:
                    inside[0] -= 1

        monkeypatch.setattr(ix._index, "rank", rank)
    got: dict[int, object] = {}
    threads = [threading.Thread(target=lambda ix=ix: got.update({ix.shard: call(ix)})) for ix in group]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return most[0], got


def test_stored_shards_of_one_process_rank_a_few_at_a_time(small_rendered: dict, tmp_path: Path, monkeypatch) -> None:
    """Loaded shards map their ranking rows while they rank: at most MAPPED_RANKINGS of them rank
    at once in a process (else a camera frame ranked by every shard of a long route at once maps
    all their rows: 665 MB at 10,000 viewframes), each giving its rows back before the next
    starts; a shard built in memory is not held back. The rankings are unchanged."""
    import threading

    from knowledge_sources import indexer as indexer_module

    entry = _entry_copy(small_rendered, tmp_path)
    _run_shards(small_rendered, entry, 3, viewframes=True)  # built and stored
    loaded, want = _run_shards(small_rendered, entry, 3, viewframes=False)
    built, _ = _run_shards(small_rendered, _entry_copy(small_rendered, tmp_path / "other"), 3, viewframes=True)
    assert all(ix.loaded for ix in loaded) and not any(ix.loaded for ix in built)
    monkeypatch.setattr(indexer_module, "_MAPPED", threading.BoundedSemaphore(2))
    image = levels.Viewframe.from_hypothesis(small_rendered["viewframes"][0]).pixels(agent="test").image
    for group, bound in ((loaded, 2), (built, 3)):
        most, got = _most_at_once(group, lambda ix: ix._ranked(image, None), monkeypatch)
        assert most == bound and len(got) == 3
        assert all(list(got[ix.shard].viewframes) == want[(0, ix.shard)].viewframes for ix in group)


def test_shards_of_one_process_rank_through_the_coarse_stage_a_few_at_a_time(
    small_rendered: dict, tmp_path: Path, monkeypatch
) -> None:
    """A frame ranked in full through the coarse stage: at most MAPPED_RANKINGS shards of a process
    rank it at once, built or loaded (with the roll search each holds its candidates' rows and the
    turned queries' products and inverse FFTs: 20 shards at once held 440 MB at 10,000
    viewframes). The rankings are unchanged."""
    import threading

    from knowledge_sources import indexer as indexer_module

    entry = _entry_copy(small_rendered, tmp_path)
    _run_shards(small_rendered, entry, 3, viewframes=True, coarse_candidates=1)  # built and stored
    loaded, want = _run_shards(small_rendered, entry, 3, viewframes=False, coarse_candidates=1)
    other = _entry_copy(small_rendered, tmp_path / "other")
    built, _ = _run_shards(small_rendered, other, 3, viewframes=True, coarse_candidates=1)
    assert all(ix.loaded and ix._coarse is not None for ix in loaded) and not any(ix.loaded for ix in built)
    monkeypatch.setattr(indexer_module, "_MAPPED", threading.BoundedSemaphore(2))
    image = levels.Viewframe.from_hypothesis(small_rendered["viewframes"][0]).pixels(agent="test").image
    for group in (loaded, built):
        most, got = _most_at_once(group, lambda ix: ix._coarse_ranked(image), monkeypatch)
        assert most == 2 and len(got) == 3
        assert all(list(got[ix.shard].viewframes) == want[(0, ix.shard)].viewframes for ix in group)


def test_a_frame_ranked_in_full_ranks_the_coarse_candidates_only(small_rendered: dict, tmp_path: Path) -> None:
    """``memory.coarse_candidates`` k: a frame without a track window is ranked among the shard's
    k best by the coarse stage (the ranking holds those k, its first the full ranking's: each
    frame is a viewframe), built and loaded alike; a windowed frame is ranked in full within the
    window; k at least the shard's viewframes ranks every one."""
    from models.coarse import MemoryCoarse
    from models.index import ViewframeIndex

    entry = _entry_copy(small_rendered, tmp_path)
    n = len(small_rendered["viewframes"])
    _, full = _run_shards(small_rendered, entry, 1, viewframes=True, coarse_candidates=None)
    other = _entry_copy(small_rendered, tmp_path / "other")
    (built,), got = _run_shards(small_rendered, other, 1, viewframes=True, coarse_candidates=3)
    (loaded,), again = _run_shards(small_rendered, entry, 1, viewframes=False, coarse_candidates=3)
    assert not built.loaded and loaded.loaded and isinstance(loaded._coarse, MemoryCoarse)
    plain = ViewframeIndex(small_rendered["map"].body["memory"])
    images = [levels.Viewframe.from_hypothesis(h).pixels(agent="test").image for h in small_rendered["viewframes"]]
    plain.add(images, range(n))
    coarse = MemoryCoarse(plain.memory)
    for f in range(n):
        r = got[(f, 0)]
        assert len(r.viewframes) == 3 and r.viewframes[0] == f == full[(f, 0)].viewframes[0]
        pattern = plain.pattern(images[f])
        among = coarse.candidates(plain.memory.banks[0].query_key(pattern), k=3)  # of the frame as it is
        want = plain.rank(images[f], among=among, pattern=pattern)  # with the memory's roll search
        assert r.viewframes == want.viewframes.tolist()
        np.testing.assert_allclose(r.variances, want.variances, rtol=1e-5, atol=1e-9)
        assert again[(f, 0)].viewframes == r.viewframes
    (wide,), every = _run_shards(small_rendered, entry, 1, viewframes=False, coarse_candidates=n)
    assert wide._coarse is None and all(every[k].viewframes == full[k].viewframes for k in full)
    # a windowed frame: the window's viewframes in full, not the coarse stage's
    bb = MemoryBlackboard()
    ix = AssociativeIndexer("indexer-0", tracked=True, keep_images=True)
    bb.add(ix)
    post_map(bb, small_rendered, window_route_points=n, window_margin=1, window_full_every=10, coarse_candidates=1)
    bb.run()
    frames_from_viewframes(bb, small_rendered, [0])
    bb.run()
    levels.post(bb.user, track(0, "tracking", 4, n))
    bb.run()
    frames_from_viewframes(bb, small_rendered, [1])
    bb.run()
    first, second = (levels.Ranking.from_hypothesis(bb.user.get(levels.ranking_id(f, 0))) for f in (0, 1))
    assert first.viewframes == [0] and ix.windows[1] == (3, 5) and sorted(second.viewframes) == [3, 4, 5]


@needs_smaps
def test_the_coarse_stage_of_a_stored_index_leaves_none_of_its_rows_resident(
    small_rendered: dict, tmp_path: Path
) -> None:
    """The coarse rows are made from a loaded shard's memory-mapped ranking rows once, which are
    then given back, and a coarse ranking gives back the candidates' rows it read."""
    entry = _entry_copy(small_rendered, tmp_path)
    _run_shards(small_rendered, entry, 1, viewframes=True, coarse_candidates=3)
    (ix,), got = _run_shards(small_rendered, entry, 1, viewframes=False, coarse_candidates=3)
    assert ix.loaded and ix._coarse is not None and all(len(r.viewframes) == 3 for r in got.values())
    assert resident_kb(int(ix._index.memory.ranking_matrix.ctypes.data)) == 0
