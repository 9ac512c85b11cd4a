"""Benchmark of the associative indexer against NCC and ORB bag-of-visual-words baselines.

Run::

    /tmp/venv/bin/python bench/index.py            # H = 100, 1000, 5000; N = 64, 128
    /tmp/venv/bin/python bench/index.py --quick    # H = 100, 1000; fewer queries

Images are synthetic, viewframe-like 160 x 120 gray scenes (random filled rectangles, discs and
lines on a flat background, seeded): rendering thousands of real viewframes would take longer
than the benchmark itself, and the memory only sees edges anyway. A query is a stored image
perturbed like a camera frame: a random shift of up to ``--shift`` pixels (non-circular,
replicated border), a brightness gain 0.6..1.4 and offset -30..30, gaussian noise of ``--noise``
gray levels.

For each (N, H) and method it reports: ``store_s`` (preprocess + store all H images),
``rank_ms`` (median time to rank one preprocessed query against all H; ORB: detection included,
as it has no separate preprocessing), ``top1`` (fraction of queries whose first label is the
true one). For the memory also the bandwidth floor ``floor_ms`` (median time of one
``prototypes.sum()`` over the (H, N*N) float32 prototype matrix, i.e. reading it once) and
``ratio`` = rank_ms / floor_ms. A capacity sweep stores H = 4 .. 256 patterns in ONE bank and
reports top-1 and recall quality (cosine of the recall with the true prototype). Finally, top-1
counts on the bundled route scenarios (rendered viewframes, simulated camera frames) for NCC and
the memory at several bank sizes and shift searches; the defaults (``bank_size`` and
``max_shift`` of :class:`models.scenario.MemorySpec`) come from these two. Preprocessing uses the
scenario schema's defaults (``MemorySpec``: size, edge method, blur) unless an option says otherwise.

BLAS runs on one thread (``OPENBLAS_NUM_THREADS=1`` unless set): the floor is single-threaded.

Output: one JSON document on stdout (``--json-only`` for nothing else) and a table on stderr.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

# one BLAS thread: the bandwidth floor (numpy sum) is single-threaded too, and on a shared
# 2-core machine a second BLAS thread waits for time slices (8 ms stalls); override with
# OPENBLAS_NUM_THREADS=2 to measure the threaded case
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# bench/ holds other scripts (e.g. bench/blackboard.py) whose names shadow the packages when
# this file runs as a script: the repository root first, bench/ last
_HERE = Path(__file__).resolve().parent
sys.path[:] = [str(_HERE.parent)] + [p for p in sys.path if Path(p or ".").resolve() != _HERE] + [str(_HERE)]

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from baselines import HolographicIndex, NCCIndex, OrbBowIndex  # noqa: E402

from models.associative import HolographicMemory  # noqa: E402
from models.preprocess import preprocess  # noqa: E402
from models.scenario import MemorySpec  # noqa: E402
from models.synthetic import scene  # noqa: E402

#: the shipped memory defaults
DEFAULTS = MemorySpec()

logger = logging.getLogger("bench.index")

SHAPE = (120, 160)


def perturb(img: np.ndarray, rng: np.random.Generator, *, shift: float, noise: float) -> np.ndarray:
    """Camera-like perturbation: shift, gain/offset, noise (see the module docstring)."""
    h, w = img.shape
    dx, dy = rng.uniform(-shift, shift, 2)
    out = cv2.warpAffine(
        img.astype(np.float32), np.float32([[1, 0, dx], [0, 1, dy]]), (w, h), borderMode=cv2.BORDER_REPLICATE
    )
    out = out * rng.uniform(0.6, 1.4) + rng.uniform(-30, 30) + rng.normal(0.0, noise, out.shape)
    return np.clip(out, 0, 255).astype(np.uint8)


def _median_ms(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1000.0 * statistics.median(times)


def capacity(
    sizes: list[int], hs: list[int], *, queries: int, shift: float, noise: float, seed: int, max_shift: tuple[int, int]
) -> list[dict]:
    """Top-1 and recall quality of ONE bank as the number of stored patterns grows."""
    rng = np.random.default_rng(seed)
    images = [scene(rng) for _ in range(max(hs))]
    rows = []
    for n in sizes:
        pats = [preprocess(im, size=n) for im in images]
        for h in hs:
            mem = HolographicMemory(n, max_shift=max_shift)
            mem.write_many(pats[:h], range(h))
            hits, quality, rel = 0, [], []
            for _ in range(queries):
                i = int(rng.integers(h))
                q = preprocess(perturb(images[i], rng, shift=shift, noise=noise), size=n)
                r = mem.rank(q)
                hits += r.best == i
                rel.append(r.reliability)
                rec = mem.recall(q)
                quality.append(float(np.sum(rec * pats[i]) / max(np.linalg.norm(rec), 1e-12)))
            rows.append(
                {
                    "N": n,
                    "H": h,
                    "top1": hits / queries,
                    "recall_cos": float(np.median(quality)),
                    "reliability": float(np.median(rel)),
                }
            )
            logger.info("capacity N=%s H=%s top1=%.2f", n, h, hits / queries)
    return rows


def scenario_top1(paths: list[str], *, bank_sizes: list[int], shifts: list[tuple[int, int]]) -> list[dict]:
    """Top-1 on rendered route viewframes against the scenario's camera frames (real renders,
    simulated sensor; truth = the route point nearest the true pose), for NCC and the memory."""
    from knowledge_sources.results import nearest_viewframe
    from models.index import ViewframeIndex
    from models.world import World

    rows = []
    for path in paths:
        with World.from_scenario(path) as world:
            sc, vfs, frames = world.scenario, world.viewframes, world.sensor_frames
        truth = [nearest_viewframe(f.truth[0], f.truth[1], sc.route) for f in frames]
        own = ViewframeIndex(sc.memory)  # the scenario's own preprocessing (size, edge method, blur)
        pats = [own.pattern(v.image) for v in vfs]
        queries = [own.pattern(f.image) for f in frames]
        matrix = np.stack([p.ravel() for p in pats])
        ncc = sum(int(np.argmax(matrix @ q.ravel())) == t for q, t in zip(queries, truth))
        row = {"scenario": sc.name, "viewframes": len(vfs), "frames": len(frames), "ncc": ncc}
        # NCC given the same heading search as the memory: the best over horizontal shifts of the query
        cols = max(ms[1] for ms in shifts)
        best = np.full((len(queries), len(pats)), -np.inf)
        for dc in range(-cols, cols + 1):
            qs = np.stack([np.roll(q, dc, axis=1).ravel() for q in queries])
            best = np.maximum(best, qs @ matrix.T)
        shifted = best.argmax(axis=1)
        row[f"ncc shift=0,{cols}"] = int(sum(int(k) == t for k, t in zip(shifted, truth)))
        for b in bank_sizes:
            for ms in shifts:
                index = ViewframeIndex(sc.memory.model_copy(update={"bank_size": b, "max_shift": ms}))
                index.add_patterns(pats, range(len(pats)))
                row[f"memory b={b} shift={ms[0]},{ms[1]}"] = sum(
                    index.rank_pattern(q).best == t for q, t in zip(queries, truth)
                )
        rows.append(row)
        logger.info("%s", row)
    return rows


def run_case(
    n: int,
    h: int,
    images: list[np.ndarray],
    queries: list[tuple[int, np.ndarray]],
    *,
    bank_size: int,
    max_shift: tuple[int, int],
    with_orb: bool,
    with_single: bool,
) -> list[dict]:
    """All methods on one (N, H) case."""
    out = []
    methods: list = [HolographicIndex(n, bank_size=bank_size, max_shift=max_shift)]
    if with_single:
        single = HolographicIndex(n, bank_size=h, max_shift=max_shift)
        single.name = "memory-1bank"
        methods.append(single)
    methods.append(NCCIndex(n))
    if with_orb:
        methods.append(OrbBowIndex())
    labels = list(range(h))
    for m in methods:
        t0 = time.perf_counter()
        m.store(images[:h], labels)
        store_s = time.perf_counter() - t0
        if hasattr(m, "rank_pattern"):
            pats = [(i, m.pattern(q)) for i, q in queries]
            t_pre = _median_ms(lambda m=m: m.pattern(queries[0][1]), 5)
            rank = m.rank_pattern
        else:
            pats, t_pre, rank = queries, 0.0, m.rank
        times, hits = [], 0
        for i, p in pats:
            t0 = time.perf_counter()
            order = rank(p)
            times.append(time.perf_counter() - t0)
            hits += int(order[0]) == i
        row = {
            "method": m.name,
            "N": n,
            "H": h,
            "store_s": round(store_s, 3),
            "rank_ms": round(1000 * statistics.median(times), 3),
            "preprocess_ms": round(t_pre, 3),
            "top1": hits / len(pats),
        }
        if isinstance(m, HolographicIndex):
            matrix = m.memory.ranking_matrix
            floor = _median_ms(lambda matrix=matrix: matrix.sum(), 7)
            row.update(
                {"banks": len(m.memory.banks), "floor_ms": round(floor, 3), "ratio": round(row["rank_ms"] / floor, 2)}
            )
        out.append(row)
        logger.info("%s", row)
        del m
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="H = 100, 1000 only, fewer queries")
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--hs", type=int, nargs="+", default=None, help="stored viewframes (default 100 1000 5000)")
    parser.add_argument("--queries", type=int, default=None, help="perturbed queries per case (default 100, quick 40)")
    parser.add_argument("--bank-size", type=int, default=DEFAULTS.bank_size)
    parser.add_argument(
        "--max-shift",
        type=int,
        nargs=2,
        default=list(DEFAULTS.max_shift),
        metavar=("ROWS", "COLS"),
        help="shift search of the memory, memory pixels",
    )
    parser.add_argument("--shift", type=float, default=3.0, help="max shift of a query in image pixels")
    parser.add_argument("--noise", type=float, default=8.0, help="gaussian noise of a query, gray levels")
    parser.add_argument("--no-orb", action="store_true", help="skip the ORB baseline")
    parser.add_argument("--no-capacity", action="store_true")
    parser.add_argument(
        "--scenarios",
        nargs="*",
        default=None,
        metavar="YAML",
        help="also top-1 on these scenarios' rendered viewframes and simulated frames "
        "(default: the bundled hills, contours, jacksboro; none with --quick)",
    )
    parser.add_argument("--json-only", action="store_true")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING if args.json_only else logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s"
    )
    hs = args.hs or ([100, 1000] if args.quick else [100, 1000, 5000])
    nq = args.queries or (40 if args.quick else 100)

    rng = np.random.default_rng(args.seed)
    images = [scene(rng) for _ in range(max(hs))]
    results = []
    for h in hs:
        queries = [
            (i, perturb(images[i], rng, shift=args.shift, noise=args.noise))
            for i in rng.integers(0, h, size=nq).tolist()
        ]
        for n in args.sizes:
            results += run_case(
                n,
                h,
                images,
                queries,
                bank_size=args.bank_size,
                max_shift=tuple(args.max_shift),
                with_orb=not args.no_orb and n == args.sizes[0],
                with_single=h <= 1000,
            )
    cap = (
        []
        if args.no_capacity
        else capacity(
            args.sizes,
            [4, 8, 16, 32, 64, 128] + ([] if args.quick else [256]),
            queries=nq,
            shift=args.shift,
            noise=args.noise,
            seed=args.seed + 1,
            max_shift=tuple(args.max_shift),
        )
    )
    if args.scenarios is None:
        root = Path(__file__).resolve().parent.parent / "scenarios"
        args.scenarios = [] if args.quick else [str(root / f"{n}.yaml") for n in ("hills", "contours", "jacksboro")]
    scen = (
        scenario_top1(
            args.scenarios, bank_sizes=[1, DEFAULTS.bank_size, 4, 8], shifts=[(0, 0), (2, 6), DEFAULTS.max_shift]
        )
        if args.scenarios
        else []
    )
    doc = {
        "machine": {
            "cpus": os.cpu_count(),
            "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "opencv": cv2.__version__,
        },
        "params": {
            "hs": hs,
            "sizes": args.sizes,
            "queries": nq,
            "shift_px": args.shift,
            "noise": args.noise,
            "bank_size": args.bank_size,
            "max_shift": args.max_shift,
            "image": list(SHAPE),
            "seed": args.seed,
        },
        "results": results,
        "capacity": cap,
        "scenarios": scen,
    }
    print(json.dumps(doc, indent=1))
    if not args.json_only:
        _table(doc)
    return 0


def _table(doc: dict) -> None:
    try:
        from rich.console import Console
        from rich.table import Table
    except ImportError:  # pragma: no cover
        Console = None
    cols = ["method", "N", "H", "banks", "store_s", "preprocess_ms", "rank_ms", "floor_ms", "ratio", "top1"]
    rows = [[str(r.get(c, "")) for c in cols] for r in doc["results"]]
    ccols = ["N", "H", "top1", "recall_cos", "reliability"]
    crows = [[f"{r[c]:.3g}" if isinstance(r[c], float) else str(r[c]) for c in ccols] for r in doc["capacity"]]
    if doc["scenarios"]:
        scols = list(doc["scenarios"][0])
        srows = [[str(r[c]) for c in scols] for r in doc["scenarios"]]
    else:
        scols, srows = [], []
    if Console is not None:
        console = Console(stderr=True)
        for title, cs, rs in (
            ("index benchmark", cols, rows),
            ("capacity of one bank", ccols, crows),
            ("top-1 on scenario frames (counts)", scols, srows),
        ):
            if not rs:
                continue
            t = Table(title=title)
            for c in cs:
                t.add_column(c, justify="right")
            for r in rs:
                t.add_row(*r)
            console.print(t)
    else:
        for cs, rs in ((cols, rows), (ccols, crows), (scols, srows)):
            if not rs:
                continue
            print("\t".join(cs), file=sys.stderr)
            for r in rs:
                print("\t".join(r), file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
