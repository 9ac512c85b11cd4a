"""Associative ranking alone, offline, over memory settings: how the defaults were chosen.

For each case of an evaluation split (``tuning`` by default: choose there, report on
``heldout``), the viewframes are rendered once (as the map renderer does) and the camera frames
read as the camera agent does (resized to the scenario camera); then, for every memory setting
of the grid, the memory is built and every frame ranked exactly as the indexer does
(:class:`models.index.ViewframeIndex` with the scenario's memory settings, one shard). Reports the ranking's top-1 and truth-in-top-5 per terrain and overall, and the mean
ranking time per frame.

A grid is a JSON list of memory-block overrides (each merged into the scenario's defaults), or
the name of a built-in grid (:data:`GRIDS`). Prints JSON, then a table.

    python bench/ranking_sweep.py [--split tuning|heldout] [--grid NAME | --configs JSON] [--names ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402

from bench.evalset import cases, one_view_a_point  # noqa: E402
from knowledge_sources.results import nearest_viewframe  # noqa: E402
from models.index import ViewframeIndex  # noqa: E402
from models.scenario import load_scenario  # noqa: E402
from models.world import World  # noqa: E402

#: built-in grids of memory overrides
GRIDS: dict[str, list[dict[str, Any]]] = {
    "defaults": [{}],
    "bank": [{"bank_size": b} for b in (1, 2, 4)],
    "shift": [{"bank_size": 1, "max_shift": [r, 16]} for r in (2, 4, 6, 8)],
    "blur": [{"bank_size": 1, "max_shift": [6, 16], "blur_sigma": s} for s in (0.7, 1.0, 1.5, 2.0, 3.0)],
}


def prepare(case) -> dict[str, Any]:
    """Viewframe images, camera images (camera size), truth route points of one case."""
    with World(one_view_a_point(load_scenario(case.scenario_path))) as world:
        sc = world.scenario
        vfs = [v.image for v in world.viewframes]
        frames = world.sensor_frames
    truth = [nearest_viewframe(f.truth[0], f.truth[1], sc.route) for f in frames]
    return {
        "name": case.name,
        "terrain": case.terrain,
        "memory": sc.memory.model_dump(),
        "viewframes": vfs,
        "frames": [f.image for f in frames],
        "truth": truth,
    }


def rank_case(data: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """Ranks (position of the truth, 0 = first) of every frame of one prepared case."""
    index = ViewframeIndex({**data["memory"], **overrides}, seed=0)
    index.add(data["viewframes"], range(len(data["viewframes"])))
    places, t = [], 0.0
    for img, truth in zip(data["frames"], data["truth"]):
        q = index.pattern(img)
        t0 = time.perf_counter()
        r = index.rank_pattern(q)
        t += time.perf_counter() - t0
        places.append(int(np.nonzero(r.viewframes == truth)[0][0]))
    return {"places": places, "rank_ms": 1000 * t / max(1, len(places))}


def _summary(places: list[int]) -> dict[str, float]:
    p = np.asarray(places)
    return {
        "frames": int(p.size),
        "top1": float(np.mean(p == 0)),
        "top5": float(np.mean(p < 5)),
        "median_place": float(np.median(p)),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("tuning", "heldout"), default="tuning")
    parser.add_argument("--grid", default="defaults", choices=sorted(GRIDS))
    parser.add_argument("--configs", type=json.loads, default=None, help="JSON list of memory overrides")
    parser.add_argument("--names", nargs="*", default=None)
    parser.add_argument("--json-only", action="store_true")
    args = parser.parse_args(argv)
    configs = args.configs if args.configs is not None else GRIDS[args.grid]
    prepared = []
    for c in cases(args.split, names=args.names):
        prepared.append(prepare(c))
        print(f"prepared {c.name}", file=sys.stderr, flush=True)
    out: dict[str, Any] = {"split": args.split, "configs": []}
    for cfg in configs:
        by_terrain: dict[str, list[int]] = {}
        ms = []
        for data in prepared:
            r = rank_case(data, cfg)
            by_terrain.setdefault(data["terrain"], []).extend(r["places"])
            ms.append(r["rank_ms"])
        allp = [p for v in by_terrain.values() for p in v]
        print(f"{json.dumps(cfg)}: top-1 {np.mean(np.asarray(allp) == 0):.3f}", file=sys.stderr, flush=True)
        out["configs"].append(
            {
                "memory": cfg,
                "terrains": {t: _summary(v) for t, v in by_terrain.items()},
                "all": _summary(allp),
                "rank_ms": float(np.mean(ms)),
            }
        )
    print(json.dumps(out, indent=1))
    if not args.json_only:
        terrains = list(out["configs"][0]["terrains"]) if out["configs"] else []
        print(f"\nsplit {args.split}: ranking top-1 / truth in top-5 per terrain")
        head = ["memory overrides"] + terrains + ["all", "ms/frame"]
        rows = []
        for c in out["configs"]:
            rows.append(
                [json.dumps(c["memory"]) if c["memory"] else "(defaults)"]
                + [f"{c['terrains'][t]['top1']:.2f}/{c['terrains'][t]['top5']:.2f}" for t in terrains]
                + [f"{c['all']['top1']:.3f}/{c['all']['top5']:.3f}", f"{c['rank_ms']:.1f}"]
            )
        widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
        for r in [head, *rows]:
            print("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
