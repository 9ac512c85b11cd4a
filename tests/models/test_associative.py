"""Holographic memory: formulas, order independence, recall, ranking, banks, transport."""

from __future__ import annotations

import cv2
import msgpack
import numpy as np
import pytest

from models.associative import BankedMemory, HolographicMemory, Ranking, merge_rankings, reliability
from models.errors import AssociativeMemoryError
from models.memory_keys import make_key
from models.preprocess import normalise, preprocess
from models.synthetic import scene


def _perturb(img: np.ndarray, rng: np.random.Generator, *, shift: float, noise: float, gain: float) -> np.ndarray:
    h, w = img.shape
    dx, dy = rng.uniform(-shift, shift, 2) if shift else (0.0, 0.0)
    out = cv2.warpAffine(img, np.float32([[1, 0, dx], [0, 1, dy]]), (w, h), borderMode=cv2.BORDER_REPLICATE)
    out = out * gain + 20.0 + rng.normal(0.0, noise, out.shape)
    return np.clip(out, 0, 255).astype(np.uint8)


def _conv(k: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Direct circular convolution: out(x) = sum_y k(y) p(x - y)."""
    n = k.shape[0]
    out = np.zeros((n, n))
    for r in range(n):
        for c in range(n):
            out += k[r, c] * np.roll(p, (r, c), axis=(0, 1))
    return out


def _corr(k: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Direct circular correlation: out(x) = sum_y k(y) m(x + y)."""
    n = k.shape[0]
    out = np.zeros((n, n))
    for r in range(n):
        for c in range(n):
            out += k[r, c] * np.roll(m, (-r, -c), axis=(0, 1))
    return out


def _random_patterns(n: int, count: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [normalise(rng.standard_normal((n, n))) for _ in range(count)]


def test_fft_write_and_read_equal_the_direct_sums() -> None:
    n = 8
    pats = _random_patterns(n, 3, seed=0)
    mem = HolographicMemory(n, seed=4)
    for i, p in enumerate(pats):
        mem.write(p, i)
    keys = [make_key(p, seed=4).astype(np.float64) for p in pats]
    m_direct = sum(_conv(k, p.astype(np.float64)) for k, p in zip(keys, pats))
    assert np.allclose(
        np.fft.irfft2(mem.spectrum, s=(n, n)), m_direct, atol=1e-5
    )  # the spectrum is complex64 (SPECTRUM_DTYPE)
    q = pats[1]
    assert np.allclose(mem.recall(q), _corr(keys[1], m_direct), atol=1e-5)


def test_storage_order_does_not_matter() -> None:
    pats = _random_patterns(16, 6, seed=1)
    a, b = HolographicMemory(16), HolographicMemory(16)
    a.write_many(pats, range(6))
    order = [4, 1, 5, 0, 3, 2]
    for i in order:
        b.write(pats[i], i)
    assert np.allclose(a.spectrum, b.spectrum, atol=1e-5)
    for q in pats:
        ra, rb = a.rank(q), b.rank(q)
        assert ra.viewframes.tolist() == rb.viewframes.tolist()
        assert np.allclose(ra.variances, rb.variances, atol=1e-10)


@pytest.mark.parametrize("n", [16, 32])
def test_single_pattern_recalls_itself_exactly(n: int) -> None:
    p = _random_patterns(n, 1, seed=2)[0]
    mem = HolographicMemory(n)
    mem.write(p, 7)
    r = mem.recall(p)
    assert np.allclose(r / np.linalg.norm(r), p, atol=1e-6)
    assert mem.rank(p).top(1)[0][1] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("key_method", ["phase", "quantized"])
def test_every_stored_pattern_is_recalled_from_its_own_key(key_method: str) -> None:
    pats = _random_patterns(32, 12, seed=3)
    mem = HolographicMemory(32, key_method=key_method)
    mem.write_many(pats, range(100, 112))
    for i, p in enumerate(pats):
        r = mem.rank(p)
        assert r.best == 100 + i
        assert r.reliability > 3.0


@pytest.mark.parametrize("max_shift", [(0, 0), (1, 2), (4, 6)])
def test_error_variance_is_the_variance_of_the_error_matrix(max_shift: tuple[int, int]) -> None:
    # v_h = min over searched shifts d of var(roll(R / ||R||, d) - P_h), computed directly
    pats = _random_patterns(16, 5, seed=4)
    mem = HolographicMemory(16, max_shift=max_shift)
    mem.write_many(pats, range(5))
    q = np.roll(pats[2], (1, -2), axis=(0, 1))
    r = mem.recall(q)
    r_hat = r / np.linalg.norm(r)
    lags = [(a, b) for a in range(-max_shift[0], max_shift[0] + 1) for b in range(-max_shift[1], max_shift[1] + 1)]
    direct = [min(np.var(np.roll(r_hat, d, axis=(0, 1)) - p) for d in lags) for p in pats]
    labels, variances = mem.error_variances(q)
    assert labels.tolist() == list(range(5))
    assert np.allclose(variances, direct, rtol=1e-4)
    assert (mem.rank(q).best == 2) == (max_shift != (0, 0))  # the shifted query needs the search


@pytest.mark.parametrize(
    ("case", "shift", "noise", "gain"),
    [("brightness", 0.0, 0.0, 0.6), ("noise", 0.0, 10.0, 1.0), ("shift", 3.0, 0.0, 1.0), ("all", 3.0, 8.0, 1.3)],
)
def test_top1_under_perturbation(case: str, shift: float, noise: float, gain: float) -> None:
    rng = np.random.default_rng(5)
    images = [scene(rng) for _ in range(12)]
    mem = BankedMemory(128)
    mem.write_many([preprocess(im) for im in images], range(12))
    hits = [
        mem.rank(preprocess(_perturb(im, rng, shift=shift, noise=noise, gain=gain))).best == i
        for i, im in enumerate(images)
    ]
    assert all(hits), f"{case}: top-1 failed for {[i for i, h in enumerate(hits) if not h]}"


def test_banked_and_single_memory_agree_on_small_sets() -> None:
    rng = np.random.default_rng(6)
    images = [scene(rng) for _ in range(10)]
    pats = [preprocess(im, size=64) for im in images]
    single = HolographicMemory(64)
    single.write_many(pats, range(10))
    banked = BankedMemory(64, bank_size=4)
    banked.write_many(pats, range(10))
    assert [len(b) for b in banked.banks] == [4, 4, 2] and len(banked) == 10
    full = BankedMemory(64, bank_size=10)
    full.write_many(pats, range(10))
    for i, im in enumerate(images):
        q = preprocess(_perturb(im, rng, shift=1.0, noise=4.0, gain=0.9), size=64)
        assert single.rank(q).best == banked.rank(q).best == i
        a, b = single.rank(q), full.rank(q)
        assert a.viewframes.tolist() == b.viewframes.tolist() and np.allclose(a.variances, b.variances)


def test_banked_memory_draws_its_patterns_one_bank_at_a_time() -> None:
    rng = np.random.default_rng(8)
    pats = [preprocess(scene(rng), size=32) for _ in range(7)]
    drawn: list[int] = []
    held: list[int] = []  # patterns drawn but not yet in a bank, as each is drawn

    def lazily():
        for i, p in enumerate(pats):
            drawn.append(i)
            held.append(len(drawn) - len(banked))
            yield p

    banked = BankedMemory(32, bank_size=3)
    banked.write_many(lazily(), range(7))
    assert drawn == list(range(7)) and max(held) <= 3  # never more than a bank's worth waiting
    listed = BankedMemory(32, bank_size=3)
    listed.write_many(pats, range(7))
    q = pats[4] + 0.01 * rng.standard_normal(pats[4].shape).astype(np.float32)
    a, b = banked.rank(q), listed.rank(q)
    assert a.viewframes.tolist() == b.viewframes.tolist() and np.array_equal(a.variances, b.variances)
    with pytest.raises(AssociativeMemoryError, match="2 patterns but 3 viewframes"):
        BankedMemory(32, bank_size=2).write_many(iter(pats[:2]), [0, 1, 2])
    with pytest.raises(AssociativeMemoryError, match="more patterns than the 2 viewframes"):
        BankedMemory(32, bank_size=2).write_many(iter(pats[:3]), [0, 1])
    with pytest.raises(AssociativeMemoryError, match="3 patterns but 2 viewframes"):
        BankedMemory(32, bank_size=2).write_many(pats[:3], [0, 1])


def test_state_round_trips_through_msgpack() -> None:
    pats = _random_patterns(16, 5, seed=7)
    mem = BankedMemory(16, bank_size=2, seed=3)
    mem.write_many(pats, [10, 11, 12, 13, 14])

    def pack(obj):
        if isinstance(obj, np.ndarray):
            return {"__nd__": True, "dtype": obj.dtype.str, "shape": list(obj.shape), "data": obj.tobytes()}
        return obj

    def unpack(d):
        if d.get("__nd__"):
            return np.frombuffer(d["data"], dtype=d["dtype"]).reshape(d["shape"])
        return d

    blob = msgpack.packb(mem.state(), default=pack)
    back = BankedMemory.from_state(msgpack.unpackb(blob, object_hook=unpack))
    for q in pats:
        assert back.rank(q).to_dict() == mem.rank(q).to_dict()
    with pytest.raises(AssociativeMemoryError, match="already stored"):
        back.write(pats[0], 12)
    single = HolographicMemory.from_state(
        msgpack.unpackb(msgpack.packb(mem.banks[0].state(), default=pack), object_hook=unpack)
    )
    assert single.rank(pats[1]).to_dict() == mem.banks[0].rank(pats[1]).to_dict()


def test_ranking_plain_data_and_merge() -> None:
    a = Ranking(np.array([3, 1]), np.array([1e-5, 2e-5]), 1.0)
    b = Ranking(np.array([2]), np.array([1.5e-5]), 0.0)
    merged = merge_rankings([a, b])
    assert merged.viewframes.tolist() == [3, 2, 1]
    assert merged.top(2) == [(3, 1e-5), (2, 1.5e-5)]
    assert Ranking.from_dict(merged.to_dict()).to_dict() == merged.to_dict()
    with pytest.raises(AssociativeMemoryError, match="more than one"):
        merge_rankings([a, a])
    with pytest.raises(AssociativeMemoryError, match="malformed"):
        Ranking.from_dict({"viewframes": [1]})
    assert len(merge_rankings([])) == 0


@pytest.mark.parametrize(
    ("variances", "expected"),
    [([1.0], 0.0), ([1.0, 1.0, 1.0, 1.0], 0.0), ([0.0, 1.0, 1.1, 0.9, 1.0, 1.05, 0.95], 10.0)],
)
def test_reliability(variances: list[float], expected: float) -> None:
    assert reliability(variances) == pytest.approx(expected, rel=0.5, abs=1e-9)


def test_featureless_query_ranks_with_zero_reliability() -> None:
    mem = HolographicMemory(16)
    mem.write_many(_random_patterns(16, 4, seed=8), range(4))
    r = mem.rank(np.zeros((16, 16)))
    assert len(r) == 4 and r.reliability == 0.0


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda m: m.write(np.ones((8, 8)), 0), "featureless"),
        (lambda m: m.write(np.zeros((4, 4)), 0), "shape"),
        (lambda m: m.write(np.full((8, 8), np.nan), 0), "finite"),
        (lambda m: m.rank(np.zeros((9, 9))), "shape"),
        (lambda m: (m.write(np.eye(8), 1), m.write(np.eye(8)[::-1], 1)), "already stored"),
    ],
)
def test_bad_input_raises_memory_errors(call, match: str) -> None:
    with pytest.raises(AssociativeMemoryError, match=match):
        call(HolographicMemory(8))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"size": 2}, "size"),
        ({"seed": -3}, "seed"),
        ({"key_method": "linear"}, "key_method"),
        ({"bank_size": 0}, "bank_size"),
        ({"max_shift": -1}, "max_shift"),
        ({"max_shift": (1, 2, 3)}, "max_shift"),
    ],
)
def test_bad_configuration(kwargs: dict, match: str) -> None:
    with pytest.raises(AssociativeMemoryError, match=match):
        BankedMemory(**kwargs)


def test_banks_of_one_reduce_to_ncc_of_whitened_patterns() -> None:
    # <R, P_h> = sum w |FP_h|^2 exp(i (phi_h - phi_Q)): with whitened patterns (flat envelope),
    # one pattern per bank is the NCC of the patterns (module docstring, "Capacity")
    rng = np.random.default_rng(9)
    images = [scene(rng) for _ in range(6)]
    pats = [preprocess(im, size=64) for im in images]
    mem = BankedMemory(64, bank_size=1, max_shift=0)
    mem.write_many(pats, range(6))
    for im in images:
        q = preprocess(_perturb(im, rng, shift=2.0, noise=6.0, gain=0.8), size=64)
        ncc = np.array([float(np.sum(q * p)) for p in pats])
        r = mem.rank(q)
        assert r.viewframes.tolist() == np.argsort(-ncc, kind="stable").tolist()
        assert np.allclose(np.sort(1 - r.variances * 64 * 64 / 2), np.sort(ncc), atol=0.02)


def test_shift_search_on_the_best_candidates_matches_the_full_search(monkeypatch: pytest.MonkeyPatch) -> None:
    import models.associative as assoc

    # blurred patterns (as preprocessed images are) keep part of their zero-shift similarity
    # when shifted, so the true one is among the best candidates that the search refines
    rng = np.random.default_rng(10)
    pats = [preprocess(scene(rng), size=32) for _ in range(40)]
    mem = BankedMemory(32, bank_size=2, max_shift=(1, 1))
    mem.write_many(pats, range(40))
    queries = [np.roll(pats[i], (1, -1), axis=(0, 1)) for i in (3, 17, 38)]
    fast = [mem.rank(q) for q in queries]
    monkeypatch.setattr(assoc, "SHIFT_SEARCH_TOP", 10_000)
    full = [mem.rank(q) for q in queries]
    for i, f, g in zip((3, 17, 38), fast, full):
        assert f.best == g.best == i
        assert f.top(1)[0][1] == pytest.approx(g.top(1)[0][1], rel=1e-6)
        # the search only lowers variances: the refined ones agree, the others are upper bounds
        fv = dict(zip(f.viewframes.tolist(), f.variances))
        gv = dict(zip(g.viewframes.tolist(), g.variances))  # noqa: E702
        assert all(fv[k] >= gv[k] * (1 - 1e-5) for k in fv)


def test_wide_vertical_search_recovers_a_pitched_query() -> None:
    # a camera pitched by 2 degrees sees the scene about 6 memory rows off: a +-2 row search
    # leaves it far from a match, a +-8 row one (the default window) matches it exactly
    rng = np.random.default_rng(12)
    pats = [preprocess(scene(rng), size=64, blur_sigma=1.0) for _ in range(12)]
    narrow, wide = BankedMemory(64, bank_size=1, max_shift=(2, 4)), BankedMemory(64, bank_size=1, max_shift=(8, 4))
    for m in (narrow, wide):
        m.write_many(pats, range(12))
    for i in (1, 5, 9):
        q = np.roll(pats[i], 6, axis=0)
        w = wide.rank(q)
        assert w.best == i and w.variances[0] == pytest.approx(0.0, abs=1e-6)
        n = narrow.rank(q)
        assert dict(zip(n.viewframes.tolist(), n.variances))[i] > 10 * w.variances[0] + 1e-5


def test_low_pass_preselection_rescues_an_offset_truth(monkeypatch: pytest.MonkeyPatch) -> None:
    import models.associative as assoc

    # 80 viewframes, queries 6 rows and 8 columns off theirs: at zero shift the truth falls out of
    # the 32 candidates the shift search refines; its low-passed similarity keeps it in
    rng = np.random.default_rng(21)
    pats = [preprocess(scene(rng), size=64, blur_sigma=1.0) for _ in range(80)]
    mem = BankedMemory(64, bank_size=1, max_shift=(8, 10))
    mem.write_many(pats, range(80))
    targets = list(range(0, 80, 8))
    queries = [np.roll(pats[i], (6, -8), axis=(0, 1)) for i in targets]
    found = [mem.rank(q).best for q in queries]
    assert found == targets
    monkeypatch.setattr(assoc, "PRESELECT_SIGMA", 1e-6)  # the low-pass does nothing: zero-shift candidates only
    assoc._lowpass.cache_clear()
    without = [mem.rank(q).best for q in queries]
    assoc._lowpass.cache_clear()
    assert sum(a != b for a, b in zip(without, targets)) >= 5


@pytest.mark.parametrize("key_method", ["phase", "quantized"])
@pytest.mark.parametrize("max_shift", [(0, 0), (2, 6)])
@pytest.mark.parametrize("bank_size", [1, 2, 3])
def test_a_compact_memory_ranks_as_the_whole_memory(bank_size: int, max_shift: tuple[int, int], key_method) -> None:
    """Finalized banks keep only their ranking rows and a scalar recall energy; every ranking
    (full, among a window, after later writes) is the whole memory's, to float32 rounding."""
    rng = np.random.default_rng(17)
    pats = [preprocess(scene(rng), size=64, blur_sigma=1.0) for _ in range(40)]
    whole = BankedMemory(64, bank_size=bank_size, max_shift=max_shift, key_method=key_method)
    whole.write_many(pats, range(40))
    reserved = BankedMemory(64, bank_size=bank_size, max_shift=max_shift, key_method=key_method, compact=True)
    reserved.reserve(40)
    reserved.write_many(pats, range(40))
    grown = BankedMemory(64, bank_size=bank_size, max_shift=max_shift, key_method=key_method, compact=True)
    grown.write_many(pats[:19], range(19))
    grown.rank(pats[2])  # finalizes the partial last bank: the next write opens another
    grown.write_many(pats[19:], range(19, 40))
    for q in (pats[5], np.roll(pats[7], 2, axis=1), pats[33], np.zeros((64, 64), np.float32)):
        for among in (None, range(10, 25)):
            want, got = whole.rank(q, among=among), reserved.rank(q, among=among)
            assert got.viewframes.tolist() == want.viewframes.tolist()
            np.testing.assert_allclose(got.variances, want.variances, rtol=0, atol=1e-7 * want.variances.max())
        assert sorted(grown.rank(q).viewframes.tolist()) == list(range(40))
    if bank_size == 1:  # banks of one: nothing else in it changes its layout
        np.testing.assert_allclose(grown.rank(pats[9]).variances, whole.rank(pats[9]).variances, atol=1e-9)
    assert whole.rank(pats[5]).best == reserved.rank(pats[5]).best == grown.rank(pats[5]).best == 5
    # a third of the bytes: the ranking rows only
    kept = reserved.ranking_matrix.nbytes + sum(b._fprotos.nbytes + b._spectrum.nbytes for b in reserved.banks)
    full = whole.ranking_matrix.nbytes + sum(b._fprotos.nbytes + b._spectrum.nbytes for b in whole.banks)
    assert kept == reserved.ranking_matrix.nbytes and kept < 0.5 * full


@pytest.mark.parametrize(
    "call",
    [
        lambda m: m.state(),
        lambda m: m.banks[0].recall(np.ones((64, 64))),
        lambda m: m.banks[0].prototypes,
        lambda m: m.banks[0].write(np.eye(64), 99),
        lambda m: m.banks[0].state(),
    ],
)
def test_a_compact_memory_refuses_what_needs_the_dropped_spectra(call) -> None:
    mem = BankedMemory(64, bank_size=2, compact=True)
    mem.write_many(_random_patterns(64, 4, seed=3), range(4))
    with pytest.raises(AssociativeMemoryError, match="compact"):
        call(mem)


def _search_by_irfft2(matrix: np.ndarray, key: np.ndarray, max_shift: tuple[int, int]) -> np.ndarray:
    """The shift search over every row with the whole inverse FFT (irfft2) of each: the
    similarities at every circular lag, their maximum over the window, at least the zero lag's."""
    from models.associative import _parseval_weights, _zero_lag_query

    n = key.shape[0]
    c = (matrix @ _zero_lag_query(key)).astype(np.float64)
    rows = np.ascontiguousarray(matrix).view(np.complex64).reshape(matrix.shape[0], n, n // 2 + 1)
    lag = np.fft.irfft2(rows * (key / _parseval_weights(n)).astype(np.complex64)[None], s=(n, n), axes=(-2, -1))
    rr = np.arange(-max_shift[0], max_shift[0] + 1) % n
    cc = np.arange(-max_shift[1], max_shift[1] + 1) % n
    best = lag[:, rr][:, :, cc].reshape(matrix.shape[0], -1).max(axis=1).astype(np.float64)
    return np.maximum(best, c)


@pytest.mark.parametrize(
    ("n", "count", "max_shift"), [(32, 12, (1, 3)), (32, 20, (0, 5)), (16, 9, (8, 8)), (33, 7, (2, 2))]
)
def test_the_shift_search_gives_the_whole_inverse_ffts_numbers(n: int, count: int, max_shift: tuple[int, int]) -> None:
    """Every row searched (at most SHIFT_SEARCH_TOP): the search's inverse FFT taken only on the
    window's rows gives exactly (bitwise) the maxima of the whole irfft2, wrapped windows included."""
    from models.associative import _search, _zero_lag_query

    mem = BankedMemory(n, bank_size=2, max_shift=max_shift, compact=True)
    pats = _random_patterns(n, count, seed=31)
    mem.write_many(pats, range(count))
    matrix = mem.ranking_matrix
    key = mem.banks[0].query_key(np.roll(pats[3], (1, 2), axis=(0, 1)) + 0.1 * pats[5])
    got = _search(matrix, key, mem.max_shift, np.ones(count))
    np.testing.assert_array_equal(got, _search_by_irfft2(matrix, key, mem.max_shift))
    assert not np.array_equal(got, (matrix @ _zero_lag_query(key)).astype(np.float64))  # the search did raise some


def test_rank_many_ranks_each_query_as_rank_does() -> None:
    """Several queries among the same rows (the roll search's): each ranking the same numbers as
    its own rank, among every row, a subset, and none; compact and whole memories."""
    rng = np.random.default_rng(32)
    pats = [preprocess(scene(rng), size=32) for _ in range(40)]
    queries = [np.roll(pats[i], (1, -2), axis=(0, 1)) for i in (4, 9, 33)]
    for compact in (True, False):
        mem = BankedMemory(32, bank_size=3, max_shift=(1, 3), compact=compact)
        mem.write_many(pats, range(40))
        for among in (None, [2, 4, 9, 11, 33, 35], [100]):
            many = mem.rank_many(queries, among=among)
            assert len(many) == len(queries)
            for q, r in zip(queries, many):
                one = mem.rank(q, among=among)
                assert r.viewframes.tolist() == one.viewframes.tolist()
                np.testing.assert_array_equal(r.variances, one.variances)
            if among == [100]:
                assert all(len(r) == 0 for r in many)
    assert [len(r) for r in BankedMemory(32).rank_many(queries)] == [0, 0, 0]  # nothing stored


def test_row_viewframes_follow_the_writes() -> None:
    """The viewframe of each ranking row is made once per matrix and follows a later write."""
    pats = _random_patterns(16, 7, seed=33)
    for compact in (True, False):
        mem = BankedMemory(16, bank_size=2, compact=compact)
        mem.write_many(pats[:5], [10, 11, 12, 13, 14])
        _ = mem.ranking_matrix
        first = mem.row_viewframes
        assert first.tolist() == [10, 11, 12, 13, 14]
        assert mem.row_viewframes is first  # not made again
        with pytest.raises(ValueError):
            first[0] = 3  # read only
        mem.write_many(pats[5:], [20, 21])
        _ = mem.ranking_matrix
        assert mem.row_viewframes.tolist() == [10, 11, 12, 13, 14, 20, 21]
        assert mem.rank(pats[6]).best == 21
