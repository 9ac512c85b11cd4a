"""The coarse first stage: its candidates contain the full ranking's best on a seeded set of
simulated camera frames (rendered with jitter and photometric changes, never stored)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.coarse import CoarseIndex
from models.index import ViewframeIndex
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


@pytest.mark.slow
def test_coarse_candidates_contain_the_full_rankings_best():
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
        viewframes, frames = world.viewframes, world.sensor_frames
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
