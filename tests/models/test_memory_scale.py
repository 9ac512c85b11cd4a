"""Memory per viewframe is bounded: a route of 1,000 viewframes, rendered and described into the
viewframe cache (held memory-mapped, as the map renderer holds them), stored in a viewframe index
and posted as the blackboard's viewframe messages into a node store (kept compressed), grows a
fresh process's resident memory by no more than a fixed bound per viewframe (a fresh process: in
the test run's own, memory freed by earlier tests would hide the growth)."""

from __future__ import annotations

import gc
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from blackboard.codec import encode
from knowledge_sources import levels
from models.index import ViewframeIndex
from models.scenario import scenario_from_dict
from models.world import World

N_VIEWFRAMES = 1000
#: the bound on resident memory growth per viewframe (camera 80 x 60, memory size 32): the
#: payload is about 67 KB of arrays (on disk, memory-mapped, pages given back once posted), 4 KB
#: of index (compact banks: their ranking rows; 14 KB whole) and 30 KB of encoded message (4 KB compressed in the store) per viewframe, and the
#: symbolic descriptions as Python objects; 62 KB were measured (the arrays in memory and the
#: messages kept decoded, as before, would be over 150 KB)
BOUND_KB = 80


def _rss_kb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1024.0


def _route(n: int) -> list[list[float]]:
    per_row = 50
    return [
        [
            100.0 + (i % per_row if (i // per_row) % 2 == 0 else per_row - 1 - i % per_row) * 20.0,
            100.0 + (i // per_row) * 60.0 + 5.0 * math.sin(i / 5.0),
        ]
        for i in range(n)
    ]


def measure() -> dict:
    """Build the route in this process; resident growth and payload per viewframe (KB)."""
    scenario = scenario_from_dict(
        {
            "name": "memory",
            "seed": 3,
            "terrain": {"cell_size": 10.0, "procedural": {"size": 144, "relief": 60.0, "seed": 5}},
            "landmarks": [
                {
                    "id": f"H{j}",
                    "kind": "house",
                    "x": 120.0 + 40.0 * (j % 25),
                    "y": 130.0 + 120.0 * (j // 25),
                    "width": 16,
                    "depth": 10,
                    "height": 8,
                }
                for j in range(100)
            ],
            "route": _route(N_VIEWFRAMES),
            "camera": {"width": 80, "height": 60, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 3000.0},
            "memory": {"size": 32},
        }
    )
    import tempfile

    from blackboard.codec import decode
    from blackboard.hypothesis import Hypothesis
    from blackboard.store import Store
    from models.viewframe_cache import ViewframeCache, release_pages

    folder = tempfile.mkdtemp(prefix="memory-scale-")
    world = World(scenario, cache=ViewframeCache(folder))
    _ = world.environment, world.emulator, world.poses  # the fixed costs: terrain, meshes, renderer
    world.emulator.render(world.poses[0])
    gc.collect()
    before = _rss_kb()
    viewframes = world.viewframes  # rendered into the cache as they come, then memory-mapped
    index = ViewframeIndex(scenario.memory)
    index.add((vf.image for vf in viewframes), (vf.index for vf in viewframes))
    index.rank(viewframes[7].image)  # builds the packed ranking matrix
    store = Store(unpack=lambda data: Hypothesis.from_record(decode(data)["hyp"]))
    sizes = []
    for k, vf in enumerate(viewframes):  # as the map renderer posts them and the node keeps them
        msg = levels.Viewframe.of(vf)
        hyp = Hypothesis.new(msg.level, msg.to_body(), source="map-renderer", id=msg.id())
        data = encode({"op": "post", "hyp": hyp.to_record(), "sender": "map-renderer"})
        store.put(hyp, data, sender="map-renderer")
        sizes.append(len(data))
        if (k + 1) % 64 == 0 or k + 1 == len(viewframes):
            release_pages(a for v in viewframes[max(0, k - 127) : k + 1] for a in (v.image, v.mask, v.background))
    del msg, hyp, data
    gc.collect()
    growth_kb = (_rss_kb() - before) / N_VIEWFRAMES
    world.close()
    payload_kb = (
        (sum(vf.image.nbytes + vf.depth.nbytes + vf.mask.nbytes for vf in viewframes) + sum(sizes))
        / 1024.0
        / N_VIEWFRAMES
    )
    got = store.get(levels.viewframe_id(11))
    assert got is not None and np.array_equal(levels.Viewframe.from_hypothesis(got).image, viewframes[11].image)
    # a lower bound of the index's own arrays: its ranking matrix (compact: the banks keep nothing else)
    index_kb = index.memory.ranking_matrix.nbytes / 1024.0
    return {
        "growth_kb": growth_kb,
        "payload_kb": payload_kb,
        "index_kb": index_kb / N_VIEWFRAMES,
        "kept_kb": store.kept_bytes() / 1024.0 / N_VIEWFRAMES,
        "stored": len(index),
    }


@pytest.mark.slow
def test_resident_memory_per_viewframe_is_bounded():
    code = f"import json, runpy; print(json.dumps(runpy.run_path({str(Path(__file__))!r})['measure']()))"
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl"}
    done = subprocess.run(
        [sys.executable, "-c", code],
        cwd=Path(__file__).resolve().parents[2],
        env=env,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    m = json.loads(done.stdout.strip().splitlines()[-1])
    assert m["stored"] == N_VIEWFRAMES
    assert m["index_kb"] < m["growth_kb"]  # the measure sees what is resident: the index at least
    assert m["kept_kb"] < m["payload_kb"] / 4  # the node store's messages are kept compressed
    assert m["growth_kb"] < BOUND_KB, f"{m['growth_kb']:.1f} KB of resident memory per viewframe (bound {BOUND_KB} KB)"
