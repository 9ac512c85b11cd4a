"""End-to-end benchmark: the whole agent ensemble on routes of 50, 500 and 2000 viewframes.

For each route length it generates a scenario (procedural hills, a serpentine route with 25 m
between route points, a landmark near every eighth route point, simulated camera frames at every
``stride``-th route point) and runs it through the blackboard twice, with the ``associative`` and
the ``prior`` strategy, in one process. It reports

* map build time (rendering and posting every viewframe, indexing them),
* localization throughput: camera frames / (last position posted - first frame posted), frames
  posted all at once (a burst: the system's capacity),
* per-frame latency p50/p99 in a second, paced run (frames at ``--rate`` Hz, as a camera would),
* top-1 accuracy (the chosen viewframe is the route point nearest the truth), the same within one
  route point, the associative ranking's own top-1, mean error and mean detector queries per
  strategy, and their ratio.

Prints JSON, then a table. ``--quick`` runs 50 and 500 only.

    python bench/end_to_end.py [--quick] [--json-only]
"""

from __future__ import annotations

import sys
from pathlib import Path

# bench/blackboard.py would shadow the blackboard package: drop this folder from the path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

from knowledge_sources.mission import run_mission  # noqa: E402

KINDS = ("house", "house", "tower", "barn")


def make_scenario(n: int, folder: Path, *, seed: int = 11, frames: int = 60) -> Path:
    """A scenario with ``n`` route points; about ``frames`` simulated camera frames."""
    rng = np.random.default_rng(seed)
    spacing = 25.0
    per_row = max(10, min(n, 160))
    rows = math.ceil(n / per_row)
    row_gap = 300.0
    extent_x = per_row * spacing + 600.0
    extent_y = rows * row_gap + 600.0
    cell = 10.0
    size = int(max(extent_x, extent_y) / cell) + 1
    route = []
    for i in range(n):
        r, c = divmod(i, per_row)
        c = c if r % 2 == 0 else per_row - 1 - c
        x = 300.0 + c * spacing
        y = 300.0 + r * row_gap + 15.0 * math.sin(c / 6.0)
        route.append([round(x, 1), round(y, 1)])
    landmarks = []
    for j, i in enumerate(range(4, n - 1, 8)):
        (x0, y0), (x1, y1) = route[i], route[i + 1]
        heading = math.atan2(y1 - y0, x1 - x0)
        side = 1 if rng.random() < 0.5 else -1
        ahead, off = rng.uniform(40, 90), side * rng.uniform(15, 45)
        kind = KINDS[j % len(KINDS)]
        w, d, h = {"house": (18, 12, 8), "tower": (4, 4, 30), "barn": (30, 16, 10)}[kind]
        landmarks.append(
            {
                "id": f"L{j}",
                "kind": kind,
                "x": round(x0 + ahead * math.cos(heading) - off * math.sin(heading), 1),
                "y": round(y0 + ahead * math.sin(heading) + off * math.cos(heading), 1),
                "width": w,
                "depth": d,
                "height": h,
                "yaw_deg": round(float(rng.uniform(0, 90)), 1),
            }
        )
    data = {
        "name": f"route{n}",
        "seed": seed,
        "terrain": {"cell_size": cell, "procedural": {"size": size, "relief": 120.0, "seed": seed}},
        "landmarks": landmarks,
        "route": route,
        "camera": {"width": 160, "height": 120, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 5000.0},
        "sensor": {"simulate": {"stride": max(1, n // frames)}},
    }
    path = folder / f"route{n}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def run_one(path: Path, *, rate: float) -> dict:
    out = {}
    for strategy in ("associative", "prior"):
        t0 = time.perf_counter()
        res = run_mission(path, strategy=strategy)
        wall = time.perf_counter() - t0
        s = res["summary"]
        frames = res["frames"]
        out[strategy] = {
            "frames": s["frames"],
            "top1": s["top1"],
            # the same criterion relaxed to the neighbouring route points (25 m away here)
            "within_one_point": sum(
                f["viewframe"] is not None and abs(f["viewframe"] - f["truth_viewframe"]) <= 1 for f in frames
            )
            / len(frames),
            "ranking_top1": sum(bool(f["ranking"]) and f["ranking"][0][0] == f["truth_viewframe"] for f in frames)
            / len(frames),
            "mean_error_m": s["mean_error_m"],
            "mean_queries": s["mean_queries"],
            "frames_per_s": s["frames_per_s"],
            "map_and_setup_s": wall - (s["localization_s"] or 0.0),
            "wall_s": wall,
        }
    paced = run_mission(path, strategy="associative", frame_rate=rate)["summary"]
    out["associative"]["latency_ms_p50"] = paced["latency_ms_p50"]
    out["associative"]["latency_ms_p99"] = paced["latency_ms_p99"]
    a, p = out["associative"]["mean_queries"], out["prior"]["mean_queries"]
    out["queries_ratio_associative_to_prior"] = (a / p) if p else None
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="routes of 50 and 500 only")
    parser.add_argument("--sizes", type=int, nargs="*", default=None, help="route lengths (default 50 500 2000)")
    parser.add_argument("--rate", type=float, default=5.0, help="camera rate of the paced latency run (Hz)")
    parser.add_argument("--json-only", action="store_true")
    args = parser.parse_args(argv)
    sizes = args.sizes or ([50, 500] if args.quick else [50, 500, 2000])
    results = {
        "machine": {
            "python": platform.python_version(),
            "cpus": __import__("os").cpu_count(),
            "platform": platform.platform(),
        },
        "routes": {},
    }
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            results["routes"][str(n)] = run_one(make_scenario(n, Path(tmp)), rate=args.rate)
    print(json.dumps(results, indent=1))
    if not args.json_only:
        print()
        head = (
            "viewframes",
            "strategy",
            "frames",
            "top-1",
            "within 1",
            "rank top-1",
            "err m",
            "queries",
            "frames/s",
            "p50 ms",
            "p99 ms",
            "setup s",
        )
        print("  ".join(f"{h:>10}" for h in head))
        for n, r in results["routes"].items():
            for strategy in ("associative", "prior"):
                x = r[strategy]
                cells = (
                    n,
                    strategy,
                    x["frames"],
                    f"{x['top1']:.1%}" if x["top1"] is not None else "-",
                    f"{x['within_one_point']:.1%}",
                    f"{x['ranking_top1']:.1%}",
                    f"{x['mean_error_m']:.1f}" if x["mean_error_m"] is not None else "-",
                    f"{x['mean_queries']:.2f}",
                    f"{x['frames_per_s']:.1f}",
                    f"{x.get('latency_ms_p50', float('nan')):.0f}",
                    f"{x.get('latency_ms_p99', float('nan')):.0f}",
                    f"{x['map_and_setup_s']:.1f}",
                )
                print("  ".join(f"{c:>10}" for c in cells))
            print(f"{'':>10}  queries associative/prior = {r['queries_ratio_associative_to_prior']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
