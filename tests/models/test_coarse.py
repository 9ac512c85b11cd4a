"""The coarse first stages: the memory's (:class:`MemoryCoarse`) is the full ranking's low-passed
similarity at its grid's lags; the candidates of both contain the full ranking's best on a seeded
set of simulated camera frames (rendered with jitter and photometric changes, never stored)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.associative import BankedMemory, _lowpass, _parseval_weights
from models.coarse import CoarseIndex, MemoryCoarse
from models.index import ViewframeIndex
from models.preprocess import preprocess
from models.scenario import scenario_from_dict
from models.world import World


def _route(n: int) -> list[list[float]]:
    per_row = 40
    return [
        [
            150.0 + (i % per_row if (i // per_row) % 2 == 0 else per_row - 1 - i % per_row) * 25.0,
            150.0 + (i // per_row) * 200.0 + 15.0 * math.sin((i % per_row) / 6.0),
        ]
        for i in range(n)
    ]


@pytest.mark.parametrize("compact", [True, False])
def test_the_memory_coarse_score_is_the_low_passed_similarity_at_the_grid_lags(compact: bool) -> None:
    """Against the direct sums: the low-passed recall's similarity with each prototype at every lag
    (one inverse FFT of the whole spectrum), divided by the bank's recall energy, at the grid's lags."""
    rng = np.random.default_rng(3)
    n, h = 64, 24
    pats = [preprocess(rng.random((60, 80)), size=n, edge="sobel", blur_sigma=1.0, whiten=True) for _ in range(h)]
    mem = BankedMemory(n, bank_size=2, compact=compact, max_shift=(6, 10))
    mem.write_many(pats, range(100, 100 + h))
    coarse = MemoryCoarse(mem, sigma=3.0, step=(3, 4))
    assert sorted(set(coarse.lags[:, 0].tolist())) == [-6, -3, 0, 3, 6]
    assert sorted(set(coarse.lags[:, 1].tolist())) == [-10, -8, -4, 0, 4, 8, 10]
    query = np.roll(pats[7], (2, 5), axis=(0, 1)) + 0.5 * pats[3]
    key = mem.banks[0].query_key(query)
    rows = mem.ranking_matrix.view(np.complex64).reshape(h, n, n // 2 + 1)
    lag = np.fft.irfft2(rows * (key * _lowpass(n, 3.0) / _parseval_weights(n))[None], s=(n, n))
    banks = np.repeat(np.arange(h // 2), 2)
    energy = np.sqrt([b._energy_sq for b in mem.banks]) if compact else np.sqrt(mem._bank_power.sum(axis=1))
    want = np.array([[lag[i, r % n, c % n] for r, c in coarse.lags] for i in range(h)]).max(axis=1) / energy[banks]
    got = coarse.scores(key)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-4 * np.abs(want).max())
    top = coarse.candidates(key, k=5)
    assert top[0] == 107 and len(top) == 5  # the shifted pattern is its own best
    assert top.tolist() == (100 + np.argsort(-want, kind="stable")[:5]).tolist()
    assert coarse.candidates(key, k=100).tolist() == (100 + np.argsort(-want, kind="stable")).tolist()
    assert coarse.nbytes < mem.ranking_matrix.nbytes / 4
    with pytest.raises(ValueError, match="k must be"):
        coarse.candidates(key, k=0)


@pytest.fixture(scope="module")
def seeded_route() -> tuple:
    """A seeded route of 240 viewframes on a procedural terrain with 40 landmarks and its simulated
    camera frames (every 8th route point, jittered): ``(scenario, viewframes, frames)``."""
    n = 240
    rng = np.random.default_rng(8)
    landmarks = [
        {
            "id": f"L{j}",
            "kind": "house" if j % 3 else "tower",
            "x": float(150 + rng.uniform(0, 975)),
            "y": float(160 + rng.uniform(0, 1000)),
            "width": 16,
            "depth": 12,
            "height": 8 if j % 3 else 30,
        }
        for j in range(40)
    ]
    scenario = scenario_from_dict(
        {
            "name": "coarse",
            "seed": 6,
            "terrain": {"cell_size": 10.0, "procedural": {"size": 140, "relief": 120.0, "seed": 6}},
            "landmarks": landmarks,
            "route": _route(n),
            "camera": {"width": 80, "height": 60, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 4000.0},
            "sensor": {"simulate": {"stride": 8}},
            "memory": {"size": 64},
            "render": {"views_per_leg": 1},
        }
    )
    with World(scenario, cache=None) as world:
        return scenario, world.viewframes, world.sensor_frames


@pytest.mark.slow
def test_coarse_candidates_contain_the_full_rankings_best(seeded_route: tuple) -> None:
    scenario, viewframes, frames = seeded_route
    n = len(viewframes)
    full = ViewframeIndex(scenario.memory)
    full.add((vf.image for vf in viewframes), (vf.index for vf in viewframes))
    coarse = CoarseIndex()
    coarse.add((vf.image for vf in viewframes), (vf.index for vf in viewframes))
    k = n // 5
    assert len(frames) == n // 8 and len(coarse) == n
    missed = [f.index for f in frames if full.rank(f.image).best not in set(coarse.candidates(f.image, k=k).tolist())]
    assert missed == [], f"coarse top-{k} of {n} missed the full ranking's best for frames {missed}"
    assert coarse.nbytes < full.memory.ranking_matrix.nbytes / 4  # compact: a fraction of the full stage's
    # the candidates are ordered: a stored view is its own best candidate
    assert all(coarse.candidates(vf.image, k=3)[0] == vf.index for vf in viewframes[::40])


@pytest.mark.slow
def test_memory_coarse_candidates_contain_the_full_rankings_best(seeded_route: tuple) -> None:
    """The memory's coarse stage at the default low-pass and grid: for every frame of the seeded
    route its 10 % best hold the full ranking's first, and the ranking among them (what the
    indexer posts) puts first a viewframe at least as good as that one (the candidates' shift
    search covers all of them)."""
    scenario, viewframes, frames = seeded_route
    index = ViewframeIndex(scenario.memory)
    index.add((vf.image for vf in viewframes), (vf.index for vf in viewframes))
    coarse = MemoryCoarse(index.memory)
    k = len(viewframes) // 10
    missed = []
    for f in frames:
        pattern = index.pattern(f.image)
        full = index.rank_pattern(pattern)
        cand = coarse.candidates(index.memory.banks[0].query_key(pattern), k=k)
        if full.best not in set(cand.tolist()):
            missed.append(f.index)
            continue
        fine = index.rank_pattern(pattern, among=cand)
        assert sorted(fine.viewframes.tolist()) == sorted(cand.tolist())
        assert fine.variances[0] <= full.variances[0] + 1e-9
    assert missed == [], f"coarse top-{k} of {len(viewframes)} missed the full ranking's best for frames {missed}"
    assert coarse.nbytes < index.memory.ranking_matrix.nbytes / 8
