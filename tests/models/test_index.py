"""The viewframe index: one pipeline (preprocess, K-GEN, store, rank) with a scenario's memory settings."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from models.associative import BankedMemory
from models.errors import AssociativeMemoryError
from models.index import ViewframeIndex, memory_settings
from models.preprocess import preprocess
from models.scenario import MemorySpec
from models.synthetic import scene

SETTINGS = [
    {},
    {
        "size": 64,
        "edge": "canny",
        "blur_sigma": 3.0,
        "whiten": False,
        "bank_size": 3,
        "max_shift": (1, 4),
        "key": "quantized",
    },
]


@pytest.mark.parametrize("settings", SETTINGS)
def test_the_index_reads_every_memory_setting(settings) -> None:
    spec = MemorySpec(**settings)
    for given in (spec, spec.model_dump()):  # a spec, or the plain data the map hypothesis carries
        index = ViewframeIndex(given, seed=5)
        mem = index.memory
        assert (mem.size, mem.bank_size, mem.key_method, mem.max_shift, mem.seed) == (
            spec.size,
            spec.bank_size,
            spec.key,
            tuple(spec.max_shift),
            5,
        )
        assert index.settings == spec


@pytest.mark.parametrize("settings", SETTINGS)
def test_patterns_are_preprocess_with_the_settings(settings) -> None:
    spec = MemorySpec(**settings)
    image = np.random.default_rng(3).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    expected = preprocess(image, size=spec.size, edge=spec.edge, blur_sigma=spec.blur_sigma, whiten=spec.whiten)
    got = ViewframeIndex(spec).pattern(image)
    # two identical preprocess calls may differ in the last bits (~1e-9): compare to 1e-6, far
    # below what a different size, edge method or blur changes (unit-energy patterns)
    assert got.shape == expected.shape
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-6)


def test_ranking_equals_the_memory_built_by_hand() -> None:
    rng = np.random.default_rng(11)
    images = [scene(rng) for _ in range(7)]
    spec = MemorySpec(size=64, bank_size=3, max_shift=(1, 3), roll_search_deg=(0.0,))  # the plain match
    index = ViewframeIndex(spec, seed=2)
    index.add(images, [10, 11, 12, 13, 14, 15, 16])
    assert len(index) == 7 and index.viewframes.tolist() == [10, 11, 12, 13, 14, 15, 16]
    by_hand = BankedMemory(64, bank_size=3, seed=2, key_method="phase", max_shift=(1, 3))
    by_hand.write_many([preprocess(im, size=64, blur_sigma=spec.blur_sigma) for im in images], range(10, 17))
    query = np.roll(images[4], 2, axis=1)
    got, want = index.rank(query), by_hand.rank(preprocess(query, size=64, blur_sigma=spec.blur_sigma))
    assert got.best == 14
    assert got.viewframes.tolist() == want.viewframes.tolist()
    np.testing.assert_allclose(got.variances, want.variances, rtol=1e-5)
    assert index.rank_pattern(index.pattern(query)).viewframes.tolist() == got.viewframes.tolist()


def test_the_roll_search_keeps_each_viewframes_best_of_the_turned_queries() -> None:
    """With ``roll_search_deg`` the ranking is, per viewframe, the smallest variance of the
    rankings of the query turned by each roll (models.derotate.rolled), the same memory otherwise."""
    from models.derotate import rolled
    from models.index import best_of_rankings

    rng = np.random.default_rng(12)
    images = [scene(rng) for _ in range(6)]
    rolls = (-3.0, 0.0, 3.0)
    index = ViewframeIndex(MemorySpec(size=64, bank_size=2, max_shift=(2, 4), roll_search_deg=rolls), seed=1)
    plain = ViewframeIndex(MemorySpec(size=64, bank_size=2, max_shift=(2, 4), roll_search_deg=(0.0,)), seed=1)
    for ix in (index, plain):
        ix.add(images, range(6))
    query = rolled(images[3], 2.5)
    got = index.rank(query)
    parts = [plain.rank(rolled(query, a)) for a in rolls]
    want = best_of_rankings(parts)
    assert got.viewframes.tolist() == want.viewframes.tolist()
    np.testing.assert_allclose(got.variances, want.variances, rtol=1e-6)
    for k, v in zip(got.viewframes.tolist(), got.variances.tolist()):
        assert v == pytest.approx(min(float(p.variances[p.viewframes == k][0]) for p in parts), rel=1e-6)
    assert got.best == 3
    # among a window: the same rule over the window's viewframes only
    assert set(index.rank(query, among=[1, 2, 3]).viewframes.tolist()) == {1, 2, 3}
    # the frame's own pattern given (the indexer's coarse stage made it): the same ranking
    again = index.rank(query, pattern=index.pattern(query))
    assert again.viewframes.tolist() == got.viewframes.tolist()
    np.testing.assert_allclose(again.variances, got.variances, rtol=1e-6)


@pytest.mark.parametrize("shortlist", [1, 2, 4, 8])
def test_the_roll_search_ranks_the_turned_queries_among_the_plain_matchs_shortlist(shortlist: int) -> None:
    """``roll_shortlist`` K: the plain match's first K viewframes take their best over every roll,
    the others keep the plain match's variance; the turned queries are not ranked beyond K."""
    from models.derotate import rolled

    rng = np.random.default_rng(13)
    images = [scene(rng) for _ in range(8)]
    rolls = (-3.0, 0.0, 3.0)
    spec = {"size": 64, "bank_size": 2, "max_shift": (2, 4)}
    index = ViewframeIndex(MemorySpec(**spec, roll_search_deg=rolls, roll_shortlist=shortlist), seed=1)
    plain = ViewframeIndex(MemorySpec(**spec, roll_search_deg=(0.0,)), seed=1)
    for ix in (index, plain):
        ix.add(images, range(8))
    query = rolled(images[5], 2.5)
    base = plain.rank(query)
    turned = [plain.rank(rolled(query, a)) for a in (-3.0, 3.0)]
    got = index.rank(query)
    assert sorted(got.viewframes.tolist()) == list(range(8))
    head = set(base.viewframes[:shortlist].tolist())
    for k, v in zip(got.viewframes.tolist(), got.variances.tolist()):
        own = float(base.variances[base.viewframes == k][0])
        if k in head:
            best = min([own, *(float(t.variances[t.viewframes == k][0]) for t in turned)])
            assert v == pytest.approx(best, rel=1e-6)
        else:
            assert v == pytest.approx(own, rel=1e-6)
    if shortlist == 8:  # a shortlist as long as the shard: the whole roll search
        whole = ViewframeIndex(MemorySpec(**spec, roll_search_deg=rolls, roll_shortlist=None), seed=1)
        whole.add(images, range(8))
        np.testing.assert_allclose(whole.rank(query).variances, got.variances, rtol=1e-6)


def test_best_of_rankings_of_partly_ranked_viewframes() -> None:
    from models.associative import Ranking
    from models.index import best_of_rankings

    a = Ranking(np.array([1, 2, 3]), np.array([0.3, 0.1, 0.5]))
    b = Ranking(np.array([3, 4]), np.array([0.05, 0.2]))
    got = best_of_rankings([a, b])
    assert got.viewframes.tolist() == [3, 2, 4, 1]
    assert got.variances.tolist() == [0.05, 0.1, 0.2, 0.3]
    assert len(best_of_rankings([])) == 0


@pytest.mark.parametrize(
    ("settings", "field"),
    [
        ({"size": 100}, "size"),
        ({"roll_search_deg": []}, "roll_search_deg"),
        ({"roll_search_deg": [0, 50]}, "roll_search_deg"),
        ({"roll_search_deg": [1, 1]}, "roll_search_deg"),
        ({"roll_shortlist": 0}, "roll_shortlist"),
        ({"max_shift": [2, 65]}, "max_shift"),
        ({"key": "linear"}, "key"),
        ({"bank_size": 0}, "bank_size"),
        ({"colour": True}, "colour"),
    ],
)
def test_malformed_settings_name_the_field(settings, field) -> None:
    with pytest.raises(AssociativeMemoryError, match=rf"memory settings: {field}"):
        ViewframeIndex({**MemorySpec().model_dump(), **settings})


def test_missing_settings_take_the_schema_defaults() -> None:
    assert memory_settings({"size": 64}) == MemorySpec(size=64)
    assert memory_settings(None) == MemorySpec()


def test_whiten_is_a_setting_that_changes_the_pattern() -> None:
    image = np.random.default_rng(4).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    on, off = ViewframeIndex(MemorySpec()).pattern(image), ViewframeIndex(MemorySpec(whiten=False)).pattern(image)
    np.testing.assert_allclose(on, preprocess(image), rtol=0, atol=1e-6)  # preprocess' defaults are the schema's
    assert np.abs(on - off).max() > 1e-3


def _route_index(count: int, *, bank_size: int, max_shift: tuple[int, int], seed: int) -> tuple[ViewframeIndex, list]:
    rng = np.random.default_rng(seed)
    images = [scene(rng) for _ in range(count)]
    index = ViewframeIndex(MemorySpec(size=64, bank_size=bank_size, max_shift=max_shift), seed=1)
    index.add(images, range(count))
    return index, images


@pytest.mark.parametrize(
    ("count", "bank_size", "max_shift"),
    [
        (30, 1, (2, 6)),  # the full ranking shift-searches every row (at most SHIFT_SEARCH_TOP)
        (30, 2, (2, 6)),
        (160, 2, (0, 0)),  # no shift search: every row keeps its zero-lag variance
        (160, 1, (0, 0)),
    ],
)
def test_a_ranking_among_a_window_is_the_full_rankings_order_within_it(count, bank_size, max_shift) -> None:
    index, images = _route_index(count, bank_size=bank_size, max_shift=max_shift, seed=count + bank_size)
    for frame, (first, last) in [(7, (0, 20)), (12, (5, 18)), (25, (19, 29))]:
        query = np.roll(images[frame], 2, axis=1)
        full = index.rank(query)
        window = index.rank(query, among=np.arange(first, last + 1))
        inside = [(int(k), v) for k, v in zip(full.viewframes, full.variances) if first <= k <= last]
        assert window.viewframes.tolist() == [k for k, _ in inside]
        np.testing.assert_allclose(window.variances, [v for _, v in inside], rtol=1e-5)
        assert window.best == frame
    # viewframes named but not stored are ignored; none stored: an empty ranking
    assert index.rank(images[3], among=[3, 4, count + 50]).viewframes.tolist() in ([3, 4], [4, 3])
    assert len(index.rank(images[3], among=[count + 1, count + 2])) == 0


def test_a_window_on_a_long_route_is_searched_among_its_own_rows() -> None:
    """Beyond SHIFT_SEARCH_TOP rows the full ranking shift-searches only its best candidates; a
    window's ranking chooses its candidates among its rows, so it never ranks a row worse than
    the full ranking does (the search only raises a similarity)."""
    index, images = _route_index(160, bank_size=1, max_shift=(2, 6), seed=4)
    query = np.roll(images[90], 3, axis=1)
    full = index.rank(query)
    window = index.rank(query, among=np.arange(70, 111))
    v_full = dict(zip(full.viewframes.tolist(), full.variances.tolist()))
    assert set(window.viewframes.tolist()) == set(range(70, 111))
    assert all(v <= v_full[k] * (1 + 1e-5) for k, v in zip(window.viewframes.tolist(), window.variances.tolist()))
    assert window.best == full.best == 90


@pytest.mark.parametrize(
    ("prior", "margin", "want"),
    [
        (np.eye(1, 100, 40).ravel(), 5, (35, 45)),  # all mass on point 40
        (np.eye(1, 100, 2).ravel(), 5, (0, 7)),  # clipped at the route's start
        (np.exp(-0.5 * ((np.arange(1000) - 600) / 10.0) ** 2), 16, (600 - 33 - 16, 600 + 33 + 16)),
        (np.ones(100), 0, None),  # spread over the route: rank everything
        (np.eye(1, 100, 40).ravel(), 30, None),  # the margin alone covers half the route
        (np.zeros(100), 3, None),  # no mass
    ],
)
def test_the_track_window_holds_the_predicted_mass_and_a_margin(prior, margin, want) -> None:
    from models.index import track_window

    assert track_window(prior, margin=margin) == want


def test_track_windows_follow_the_memory_settings() -> None:
    from models.index import TrackWindows
    from models.scenario import MemorySpec

    spec = MemorySpec(window_route_points=100, window_margin=2, window_full_every=5)
    w = TrackWindows(spec, viewframes=200, tracked=True)
    w.add(0, "tracking", [50, 50])
    w.add(1, "lost", [50, 50])
    w.add(3, "tracking", [50, 51])
    w.add(4, "tracking", [50, 50])
    w.add(6, "tracking", None)
    w.add(7, "tracking", [0, 120])
    assert w.window(1) == (48, 52)
    assert w.window(0) is None and w.window(2) is None  # frame 0; the track before is lost
    assert w.window(3) is None  # no track of frame 2
    assert w.window(4) == (48, 53) and w.window(5) is None  # every 5th frame: everything
    assert w.window(7) is None and w.window(8) is None  # no window; half the route or more
    assert TrackWindows(spec, viewframes=99, tracked=True).enabled is False  # a short route
    assert TrackWindows(spec, viewframes=200, tracked=False).enabled is False


@pytest.mark.parametrize("bank_size", [1, 3])
@pytest.mark.parametrize("featureless", [[0], [12], [4, 5, 6]])
def test_featureless_viewframes_are_listed_and_never_ranked(bank_size, featureless, caplog) -> None:
    """A constant image (a camera inside a landmark, facing the sky) has no pattern to store: the
    index leaves it out and names it, and the others are stored and ranked as without it."""
    rng = np.random.default_rng(5)
    images = [scene(rng) for _ in range(13)]
    flat = [np.full_like(images[0], 0.4) if k in featureless else im for k, im in enumerate(images)]
    spec = MemorySpec(size=64, bank_size=bank_size)
    index = ViewframeIndex(spec, seed=1)
    with caplog.at_level("WARNING", logger="models.index"):
        index.add(iter(flat), range(13))
    kept = [k for k in range(13) if k not in featureless]
    assert index.featureless == featureless and index.viewframes.tolist() == kept
    assert all(f"viewframe {k}: featureless" in caplog.text for k in featureless)
    alone = ViewframeIndex(spec, seed=1)  # the same viewframes without the featureless ones
    alone.add([images[k] for k in kept], kept)
    query = np.roll(images[8], 2, axis=1)
    got, want = index.rank(query), alone.rank(query)
    assert got.best == 8 and not set(featureless) & set(got.viewframes.tolist())
    assert got.viewframes.tolist() == want.viewframes.tolist()
    with pytest.raises(AssociativeMemoryError, match="12 patterns but 13 viewframes"):
        ViewframeIndex(spec).add(iter(images[:12]), range(13))


def _same_pattern(a: np.ndarray, b: np.ndarray) -> None:
    """The same pattern up to float32 rounding: preprocessing one image twice is not bitwise
    reproducible in numpy (its SIMD sums depend on where the arrays lie in memory), main's too."""
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-6 * float(np.abs(b).max()))


def _same_ranking(a, b) -> None:
    """The same order, the same variances up to that rounding."""
    assert a.viewframes.tolist() == b.viewframes.tolist()
    np.testing.assert_allclose(a.variances, b.variances, rtol=1e-6)


def test_query_patterns_are_the_turned_images_patterns_made_once_for_every_shard() -> None:
    """``query_pattern``: the pattern of the image turned by the roll; shards of one process with
    the same preprocessing (any seed) share it, one array; other preprocessing makes its own."""
    from models.derotate import rolled
    from models.query_patterns import SHARED

    rng = np.random.default_rng(21)
    img = scene(rng)
    spec = MemorySpec(size=64, bank_size=2, max_shift=(2, 4))
    shards = [ViewframeIndex(spec, seed=s) for s in range(3)]
    SHARED.clear()
    made = SHARED.made
    for roll in (-3.0, 0.0, 1.5):
        patterns = [ix.query_pattern(img.copy(), roll=roll) for ix in shards]
        _same_pattern(patterns[0], shards[0].pattern(rolled(img, roll)))
        assert all(p is patterns[0] for p in patterns)
    assert SHARED.made - made == 3
    other = ViewframeIndex(MemorySpec(size=64, blur_sigma=2.0, bank_size=2, max_shift=(2, 4)))
    _same_pattern(other.query_pattern(img), other.pattern(img))
    assert SHARED.made - made == 4


def _shards(rng: np.random.Generator, count: int, shards: int) -> tuple[list[ViewframeIndex], list[np.ndarray]]:
    images = [scene(rng) for _ in range(count)]
    spec = MemorySpec(size=64, bank_size=1, max_shift=(2, 4), roll_search_deg=(-3.0, -1.5, 0.0, 1.5, 3.0))
    out = []
    for s in range(shards):
        ix = ViewframeIndex(spec, seed=s)
        ix.add(images[s::shards], range(s, count, shards))
        out.append(ix)
    return out, images


def test_shards_sharing_the_query_patterns_rank_as_each_alone_and_as_by_hand() -> None:
    """The roll search of several shards of one process (the patterns made once, by whichever
    shard ranks first, the rows among a set picked once) ranks exactly as each shard with the
    patterns made for it alone, and as the roll search written out: each turned image's pattern,
    its memory ranking, each viewframe's best (the same order, the same variances up to float32
    rounding, :func:`_same_pattern`)."""
    from models.derotate import rolled
    from models.index import best_of_rankings
    from models.query_patterns import SHARED

    rng = np.random.default_rng(22)
    shards, images = _shards(rng, 24, 3)
    query = rolled(np.roll(images[7], 2, axis=1), 2.0)
    among = [1, 4, 7, 8, 10, 13, 19]
    SHARED.clear()
    shared = [[ix.rank(query), ix.rank(query, among=among)] for ix in shards]
    alone = []
    for ix in shards:
        SHARED.clear()
        alone.append([ix.rank(query), ix.rank(query, among=among)])
    for ix, got, own in zip(shards, shared, alone):
        rolls = ix.settings.roll_search_deg
        by_hand = [
            best_of_rankings([ix.memory.rank(ix.pattern(rolled(query, a)), among=w) for a in rolls])
            for w in (None, among)
        ]
        for g, o, h in zip(got, own, by_hand):
            _same_ranking(g, o)
            _same_ranking(g, h)
    from models.associative import merge_rankings

    assert merge_rankings([r[0] for r in shared]).best == 7


def test_shards_ranking_one_frame_in_threads_rank_as_one_after_another() -> None:
    """Shards of one process ranking the same frame at once (each its own copy of the frame, as
    each agent decodes its message): the same rankings as one after another, each pattern made once."""
    from models.derotate import rolled
    from models.query_patterns import SHARED

    rng = np.random.default_rng(23)
    shards, images = _shards(rng, 32, 4)
    query = rolled(images[12], -2.0)
    SHARED.clear()
    serial = [ix.rank(query) for ix in shards]
    SHARED.clear()
    made = SHARED.made
    barrier = threading.Barrier(len(shards))
    got: dict[int, object] = {}

    def run(i: int) -> None:
        barrier.wait(10)
        got[i] = shards[i].rank(query.copy())

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(shards))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert SHARED.made - made == 2 * len(shards[0].settings.roll_search_deg)  # a pattern and a phase per roll
    for i, want in enumerate(serial):
        _same_ranking(got[i], want)


def test_query_keys_are_the_memorys_keys_of_the_query_patterns() -> None:
    """``query_key``: each shard's own key (its seed) of the shared pattern, from the phase made
    once per process; an index holding nothing has no key."""
    from models.query_patterns import SHARED

    rng = np.random.default_rng(24)
    images = [scene(rng) for _ in range(6)]
    shards = [ViewframeIndex(MemorySpec(size=64, bank_size=2, max_shift=(2, 4)), seed=s) for s in range(3)]
    for ix in shards:
        ix.add(images, range(6))
    SHARED.clear()
    made = SHARED.made
    for roll in (0.0, 1.5):
        keys = [ix.query_key(images[2], roll=roll) for ix in shards]
        for ix, key in zip(shards, keys):
            want = ix.memory.banks[0].query_key(ix.query_pattern(images[2], roll=roll))
            np.testing.assert_allclose(key, want, rtol=0, atol=1e-9)
        assert not np.allclose(keys[0], keys[1])  # the seeds differ
    assert SHARED.made - made == 4  # a pattern and a phase per roll
    with pytest.raises(AssociativeMemoryError, match="holds no viewframe"):
        ViewframeIndex(MemorySpec(size=64)).query_key(images[0])
