"""Coarse first stage: recall of the truth and of the full ranking's best among its candidates,
on simulated camera frames of a generated route (the ``bench/end_to_end.py`` generator); and
the effect of keeping the banks' memory spectrum in complex64 instead of complex128 (the same
frames ranked by both: top-1 agreement, largest relative change of a variance).

The truth is the route point nearest the frame's true position (as ``mapinterp run`` scores
top-1). Prints JSON, then a table.

    python bench/coarse.py [--size 500] [--frames 60] [--json-only]
    python bench/coarse.py --evalset heldout     # the held-out sweeps of bench/evalset instead
    python bench/coarse.py --memory tuning [--variant SIGMA STEP_R STEP_C ...]
    python bench/coarse.py --route ROUTE.yaml --cache-dir DIR [--stride 50]

With ``--evalset SPLIT`` it runs the prototype (:class:`models.coarse.CoarseIndex`) on the sweeps
of ``bench.evalset`` (other terrains, camera frames from another renderer, other sizes, larger
pose errors), one route per terrain; the truth is the frame's ``route_index``. ``--memory SPLIT``
measures the indexer's coarse stage (:class:`models.coarse.MemoryCoarse`, what
``memory.coarse_candidates`` uses) on the split's routes pooled in one index
(:func:`memory_coarse`), ``--variant`` its low-pass and shift grid; ``--route`` on a long route's
shards as the indexer loads them from a viewframe cache (:func:`route_coarse`). Run them with
``OPENBLAS_NUM_THREADS=1`` for single-thread CPU times.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]
sys.path.insert(0, str(HERE.parent))

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

KS = (10, 25, 50, 100, 200)


def evalset(split: str, ks: tuple[int, ...] = (1, 3, 5, 10)) -> dict:
    """Coarse recall on the sweeps of ``bench.evalset`` (see the module docstring)."""
    import cv2

    from bench.evalset import cases, one_view_a_point
    from models.coarse import CoarseIndex
    from models.index import ViewframeIndex
    from models.scenario import load_scenario
    from models.world import World

    out: dict = {"split": split, "ks": list(ks), "cases": {}}
    total = {"frames": 0, "full_top1": 0, **{f"truth@{k}": 0 for k in ks}, **{f"best@{k}": 0 for k in ks}}
    for case in cases(split, kinds=["sweep"]):
        with World(one_view_a_point(load_scenario(case.scenario_path))) as world:
            viewframes = world.viewframes
            memory = world.scenario.memory
        images, ids = [vf.image for vf in viewframes], [vf.index for vf in viewframes]
        full, coarse = ViewframeIndex(memory), CoarseIndex()
        full.add(images, ids)
        coarse.add(images, ids)
        row = {
            "viewframes": len(ids),
            "frames": 0,
            "full_top1": 0,
            **{f"truth@{k}": 0 for k in ks},
            **{f"best@{k}": 0 for k in ks},
        }
        for f in case.frames:
            image = cv2.cvtColor(cv2.imread(str(f.image)), cv2.COLOR_BGR2RGB)
            best = full.rank(image).best
            cand = coarse.candidates(image, k=max(ks)).tolist()
            row["frames"] += 1
            row["full_top1"] += best == f.route_index
            for k in ks:
                row[f"truth@{k}"] += f.route_index in cand[:k]
                row[f"best@{k}"] += best in cand[:k]
        out["cases"][case.name] = row
        for key in total:
            total[key] += row[key]
    out["total"] = total
    return out


MEMORY_KS = (4, 8, 12, 16, 24, 32, 48, 64)


def memory_coarse(
    split: str, ks: tuple[int, ...] = MEMORY_KS, *, variants: list[tuple[float, tuple[int, int]]] | None = None
) -> dict:
    """The memory's coarse stage (:class:`models.coarse.MemoryCoarse`, what the indexer's
    ``memory.coarse_candidates`` uses) on a split of ``bench.evalset``, its routes **pooled**: the
    viewframes of every terrain's route (one a route point) in one index, as a shard holds a stretch
    of a long route among others; every frame of every case (sweeps, drives, kidnaps: the ray
    caster's images, other resolutions, pose errors) is a query, its truth the frame's
    ``route_index`` on its own terrain's route. For each candidate count k: ``truth``, the truth is
    among the coarse k best; ``truth_full``, among the full ranking's k best (what any k candidates
    can hold at most); ``best``, the full ranking's first is among them; ``same_top1``, the ranking
    among the k candidates (the indexer's) has the full ranking's first; ``top1``, its first is the
    truth (``full_top1``: the full ranking's). ``variants``: (sigma, step) of the coarse stage to
    compare (default: the module's)."""
    import cv2

    from bench.evalset import cases, one_view_a_point
    from models.coarse import MemoryCoarse
    from models.index import ViewframeIndex
    from models.scenario import load_scenario
    from models.world import World

    routes: dict[str, int] = {}  # terrain -> offset of its viewframes in the pool
    images: list = []
    memory = None
    queries: list[tuple[str, str, int]] = []  # (case, image path, pooled truth)
    for case in cases(split):
        scenario = one_view_a_point(load_scenario(case.scenario_path))
        if memory is None:
            memory = scenario.memory
        if case.terrain not in routes:
            with World(scenario) as world:
                routes[case.terrain] = len(images)
                images.extend(vf.image for vf in world.viewframes)
        queries += [(case.name, str(f.image), routes[case.terrain] + f.route_index) for f in case.frames]
    pool = ViewframeIndex(memory)
    pool.add(images, range(len(images)))
    from models.coarse import COARSE_SHIFT_STEP, COARSE_SIGMA

    variants = variants or [(COARSE_SIGMA, COARSE_SHIFT_STEP)]
    images_n = len(images)
    pats = [pool.pattern(cv2.cvtColor(cv2.imread(path), cv2.COLOR_BGR2RGB)) for _n, path, _t in queries]
    fulls = [pool.rank_pattern(p) for p in pats]
    out = {}
    for sigma, step in variants:
        t0 = time.process_time()
        coarse = MemoryCoarse(pool.memory, sigma=sigma, step=step)
        build_s = time.process_time() - t0
        r = _memory_variant(pool, coarse, pats, fulls, queries, ks)
        r.update(
            {
                "split": split,
                "viewframes": images_n,
                "terrains": len(routes),
                "sigma": sigma,
                "step": list(step),
                "lags": len(coarse.lags),
                "coarse_build_s": build_s,
                "coarse_bytes_per_viewframe": coarse.nbytes / max(1, len(coarse)),
            }
        )
        out[f"sigma={sigma:g} step={step[0]},{step[1]}"] = r
    return out


def _memory_variant(pool, coarse, pats, fulls, queries, ks) -> dict:
    keys = ["truth", "truth_full", "truth_kept", "best", "same_top1", "top1"]
    counts = {k: {key: 0 for key in keys} for k in ks}
    full_top1 = 0
    worst_best = []  # the full ranking's first's coarse rank, per frame
    t_coarse = 0.0
    for (_name, _path, truth), pattern, full in zip(queries, pats, fulls):
        t1 = time.process_time()
        order = coarse.candidates(pool.memory.banks[0].query_key(pattern), k=len(coarse)).tolist()
        t_coarse += time.process_time() - t1
        best = full.best
        full_top1 += best == truth
        worst_best.append(order.index(best))
        full_order = full.viewframes.tolist()
        for k in ks:
            cand = order[:k]
            fine = pool.rank_pattern(pattern, among=cand).best
            c = counts[k]
            c["truth"] += truth in cand
            c["truth_kept"] += best == truth and truth in cand
            c["truth_full"] += truth in full_order[:k]
            c["best"] += best in cand
            c["same_top1"] += fine == best
            c["top1"] += fine == truth
    n = len(queries)
    return {
        "frames": n,
        "full_top1": full_top1 / n,
        "ks": list(ks),
        "recall": _recall(counts, n, full_top1),
        "best_coarse_rank_max": int(max(worst_best)),
        "best_coarse_rank_p99": float(np.percentile(worst_best, 99)),
        "coarse_cpu_ms_per_frame": 1000 * t_coarse / n,
    }


def _recall(counts: dict, n: int, full_top1: int) -> dict:
    """Fractions of the frames; ``truth_kept``: of the frames whose full ranking's first is the truth."""
    return {
        str(k): {key: v / (max(1, full_top1) if key == "truth_kept" else n) for key, v in c.items()}
        for k, c in counts.items()
    }


def route_coarse(path: Path, cache_dir: Path, *, stride: int, ks: tuple[int, ...] = MEMORY_KS) -> dict:
    """The memory's coarse stage per shard on a long generated route (``bench/scale.py``'s; its
    viewframes and stored indices from the viewframe cache ``cache_dir``, read only: each shard as
    the indexer loads it). Queries: the scenario's own simulated frames (its drive) and frames
    simulated at every ``stride``-th route point (the scenario's ``sensor.simulate`` settings
    without its drive), truth the route point nearest the frame. Per frame, every shard ranks in
    full (the full ranking: the shards' rankings merged) and through the coarse stage at each k;
    ``best``: the full ranking's first is among its shard's coarse k; ``same_top1``: the merged
    coarse + fine ranking's first is the full ranking's; ``top1`` / ``full_top1``: is the truth;
    ``truth`` / ``truth_full``: the truth is among the coarse candidates of its shard / among its
    shard's full k best. CPU ms per frame of all shards (one thread)."""
    from models.associative import merge_rankings
    from models.coarse import MemoryCoarse
    from models.index_store import cached_index
    from models.scenario import load_scenario
    from models.viewframe_cache import ViewframeCache
    from models.world import World

    base = load_scenario(path)
    sim = base.sensor.simulate
    assert sim is not None, f"{path}: no sensor.simulate"
    frames = []
    for label, simulate in (("drive", sim), ("stride", sim.model_copy(update={"drive": None, "stride": stride}))):
        scenario = base.model_copy(update={"sensor": base.sensor.model_copy(update={"simulate": simulate})})
        with World(scenario, cache=ViewframeCache(cache_dir)) as world:
            views = len(world.viewframes)
            entry = world.entry
            frames += [(label, f) for f in world.sensor_frames]
    route = np.asarray(base.route)
    mem = base.memory
    shards = []
    for s in range(int(np.ceil(views / mem.shard_size))):
        mine = [k for k in range(views) if min(k // mem.shard_size, int(np.ceil(views / mem.shard_size)) - 1) == s]

        def fail(s: int = s) -> list:
            raise RuntimeError(f"shard {s}: no stored index in {entry}")

        index, _hit = cached_index(entry, mem, mine, seed=s, images=fail)
        shards.append((index, MemoryCoarse(index.memory)))
    keys = ["truth", "truth_full", "truth_kept", "best", "same_top1", "top1"]
    counts = {k: {key: 0 for key in keys} for k in ks}
    full_top1, ranks = 0, []
    timed = mem.coarse_candidates if mem.coarse_candidates in ks else ks[len(ks) // 2]  # the fine stage timed at
    t_full = t_coarse = 0.0
    for _label, f in frames:
        truth = int(np.argmin(np.hypot(route[:, 0] - f.truth[0], route[:, 1] - f.truth[1])))
        pattern = shards[0][0].pattern(f.image)
        t0 = time.process_time()
        parts = [index.rank_pattern(pattern) for index, _ in shards]
        t1 = time.process_time()
        full = merge_rankings(parts)
        best = int(full.best)
        full_top1 += best == truth
        owner = next(i for i, (index, _) in enumerate(shards) if best in set(index.viewframes.tolist()))
        towner = next(i for i, (index, _) in enumerate(shards) if truth in set(index.viewframes.tolist()))
        t2 = time.process_time()  # each shard's keys have their own seed
        orders = [coarse.candidates(index.memory.banks[0].query_key(pattern), k=max(ks)) for index, coarse in shards]
        t_coarse += time.process_time() - t2
        t_full += t1 - t0
        ranks.append(int(np.flatnonzero(orders[owner] == best)[0]) if best in orders[owner] else max(ks))
        for k in ks:
            t3 = time.process_time()
            fine = merge_rankings([index.rank_pattern(pattern, among=o[:k]) for (index, _), o in zip(shards, orders)])
            if k == timed:
                t_coarse += time.process_time() - t3
            c = counts[k]
            c["truth"] += truth in orders[towner][:k]
            c["truth_kept"] += best == truth and truth in orders[towner][:k]
            c["truth_full"] += truth in parts[towner].viewframes[:k]
            c["best"] += best in orders[owner][:k]
            c["same_top1"] += int(fine.best) == best
            c["top1"] += int(fine.best) == truth
    n = len(frames)
    return {
        "route": str(path),
        "viewframes": views,
        "shards": len(shards),
        "frames": n,
        "full_top1": full_top1 / n,
        "ks": list(ks),
        "recall": _recall(counts, n, full_top1),
        "best_coarse_rank_max": int(max(ranks)),
        "best_coarse_rank_p99": float(np.percentile(ranks, 99)),
        "cpu_ms_per_frame": {"full": 1000 * t_full / n, f"coarse + fine (k={timed})": 1000 * t_coarse / n},
    }


def _print_recall(recall: dict[str, dict[str, float]]) -> None:
    """The table of a coarse stage's recall per candidate count k (``--route``, ``--memory``)."""
    print(f"{'k':>4} {'truth':>7} {'truth full':>10} {'kept':>7} {'best':>7} {'same top-1':>10} {'top-1':>7}")
    for k, x in recall.items():
        print(
            f"{k:>4} {x['truth']:>7.1%} {x['truth_full']:>10.1%} {x['truth_kept']:>7.1%} {x['best']:>7.1%} "
            f"{x['same_top1']:>10.1%} {x['top1']:>7.1%}"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=500, help="route length (viewframes)")
    parser.add_argument("--frames", type=int, default=60, help="simulated camera frames")
    parser.add_argument("--evalset", default=None, metavar="SPLIT", help="the sweeps of bench.evalset instead")
    parser.add_argument(
        "--memory", default=None, metavar="SPLIT", help="the memory's coarse stage on a pooled split of bench.evalset"
    )
    parser.add_argument(
        "--variant",
        nargs=3,
        action="append",
        type=float,
        metavar=("SIGMA", "STEP_ROWS", "STEP_COLS"),
        help="--memory: a coarse stage's low-pass and shift grid to compare (repeatable; default the module's)",
    )
    parser.add_argument("--route", type=Path, default=None, help="the memory's coarse stage per shard on this route")
    parser.add_argument("--cache-dir", type=Path, default=None, help="--route: its viewframe cache (read only)")
    parser.add_argument("--stride", type=int, default=50, help="--route: also frames at every stride-th route point")
    parser.add_argument("--json-only", action="store_true")
    args = parser.parse_args(argv)
    if args.route and args.cache_dir is None:
        parser.error("--route needs --cache-dir (the viewframe cache holding the route's entry and stored indices)")
    if args.route and not args.route.is_file():
        parser.error(f"--route {args.route}: no such scenario file")
    if args.variant and any(v[0] <= 0 or v[1] < 1 or v[2] < 1 for v in args.variant):
        parser.error("--variant: SIGMA must be > 0 and the steps >= 1")
    if args.route:
        load0 = os.getloadavg()
        res = route_coarse(args.route, args.cache_dir, stride=args.stride)
        res["load_avg"] = [load0, os.getloadavg()]
        print(json.dumps(res, indent=1))
        if not args.json_only:
            print(
                f"\n{res['viewframes']} viewframes in {res['shards']} shards, {res['frames']} frames; full ranking "
                f"top-1 {res['full_top1']:.1%}; its first at coarse rank <= {res['best_coarse_rank_max']} of its "
                f"shard (p99 {res['best_coarse_rank_p99']:.0f}); CPU ms/frame {res['cpu_ms_per_frame']}"
            )
            _print_recall(res["recall"])
        return 0
    if args.memory:
        load0 = os.getloadavg()
        variants = [(v[0], (int(v[1]), int(v[2]))) for v in args.variant] if args.variant else None
        res = memory_coarse(args.memory, variants=variants)
        print(json.dumps({"variants": res, "load_avg": [load0, os.getloadavg()]}, indent=1))
        if not args.json_only:
            for name, r in res.items():
                print(
                    f"\n{args.memory}, {name} ({r['lags']} lags, {r['coarse_bytes_per_viewframe']:.0f} B/vf, "
                    f"{r['coarse_cpu_ms_per_frame']:.2f} ms/frame): {r['frames']} frames, {r['viewframes']} viewframes "
                    f"pooled from {r['terrains']} terrains; full ranking top-1 {r['full_top1']:.1%}; its first at "
                    f"coarse rank <= {r['best_coarse_rank_max']} (p99 {r['best_coarse_rank_p99']:.0f})"
                )
                _print_recall(r["recall"])
        return 0
    if args.evalset:
        load0 = os.getloadavg()
        res = evalset(args.evalset)
        res["load_avg"] = [load0, os.getloadavg()]
        print(json.dumps(res, indent=1))
        if not args.json_only:
            ks = res["ks"]
            print(
                f"\n{'case':<28} {'vf':>4} {'frames':>6} {'full top-1':>10} "
                + " ".join(f"{'truth@' + str(k):>9}" for k in ks)
                + " "
                + " ".join(f"{'best@' + str(k):>8}" for k in ks)
            )
            for name, r in [*res["cases"].items(), ("total", res["total"])]:
                n = r["frames"]
                print(
                    f"{name:<28} {r.get('viewframes', ''):>4} {n:>6} {r['full_top1'] / n:>10.1%} "
                    + " ".join(f"{r['truth@' + str(k)] / n:>9.1%}" for k in ks)
                    + " "
                    + " ".join(f"{r['best@' + str(k)] / n:>8.1%}" for k in ks)
                )
        return 0
    from models.coarse import CoarseIndex
    from models.index import ViewframeIndex
    from models.world import World

    spec = importlib.util.spec_from_file_location("end_to_end", HERE / "end_to_end.py")
    e2e = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(e2e)
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        path = e2e.make_scenario(args.size, Path(tmp), frames=args.frames)
        with World.from_scenario(path) as world:
            viewframes, frames = world.viewframes, world.sensor_frames
            scenario = world.scenario
    route = np.asarray(scenario.route)
    full, coarse = ViewframeIndex(scenario.memory, compact=False), CoarseIndex()
    images, ids = [vf.image for vf in viewframes], [vf.index for vf in viewframes]
    full.add(images, ids)
    coarse.add(images, ids)
    hits_truth = {k: 0 for k in KS}
    hits_best = {k: 0 for k in KS}
    full_top1 = 0
    t_full = t_coarse = 0.0
    for f in frames:
        truth = int(np.argmin(np.hypot(route[:, 0] - f.truth[0], route[:, 1] - f.truth[1])))
        t0 = time.perf_counter()
        best = full.rank(f.image).best
        t1 = time.perf_counter()
        cand = coarse.candidates(f.image, k=max(KS))
        t2 = time.perf_counter()
        t_full += t1 - t0
        t_coarse += t2 - t1
        full_top1 += best == truth
        for k in KS:
            top = set(cand[:k].tolist())
            hits_truth[k] += truth in top
            hits_best[k] += best in top
    from models import associative

    saved = associative.SPECTRUM_DTYPE
    associative.SPECTRUM_DTYPE = np.complex64 if saved == np.complex128 else np.complex128
    try:
        other = ViewframeIndex(scenario.memory, compact=False)
        other.add(images, ids)
    finally:
        associative.SPECTRUM_DTYPE = saved
    agree, worst = 0, 0.0
    for f in frames:
        a, b = full.rank(f.image), other.rank(f.image)
        agree += a.best == b.best
        va = dict(zip(a.viewframes.tolist(), a.variances.tolist()))
        worst = max(
            worst, max(abs(va[v] - x) / max(va[v], 1e-30) for v, x in zip(b.viewframes.tolist(), b.variances.tolist()))
        )
    n = len(frames)
    spectrum = {
        "dtypes": [np.dtype(saved).name, np.dtype(other.memory.banks[0].spectrum.dtype).name],
        "top1_agreement": agree / n,
        "max_relative_variance_change": worst,
        "bank_bytes_per_viewframe": [sum(b.spectrum.nbytes for b in m.memory.banks) / len(m) for m in (full, other)],
    }
    out = {
        "spectrum": spectrum,
        "viewframes": len(viewframes),
        "frames": n,
        "load_avg": [load0, os.getloadavg()],
        "full_top1": full_top1 / n,
        "full_rank_ms": 1000 * t_full / n,
        "coarse_ms": 1000 * t_coarse / n,
        "coarse_bytes_per_viewframe": coarse.nbytes / len(coarse),
        "recall_truth": {str(k): hits_truth[k] / n for k in KS},
        "recall_full_best": {str(k): hits_best[k] / n for k in KS},
    }
    print(json.dumps(out, indent=1))
    if not args.json_only:
        print(
            f"\n{len(viewframes)} viewframes, {n} frames; full ranking top-1 {out['full_top1']:.1%}, "
            f"{out['full_rank_ms']:.1f} ms/frame; coarse {out['coarse_ms']:.1f} ms/frame"
        )
        print(f"{'k':>6} {'truth in top-k':>16} {'full best in top-k':>20}")
        for k in KS:
            print(f"{k:>6} {hits_truth[k] / n:>16.1%} {hits_best[k] / n:>20.1%}")
        print(
            f"spectrum {spectrum['dtypes'][0]} vs {spectrum['dtypes'][1]}: top-1 agreement "
            f"{spectrum['top1_agreement']:.1%}, largest relative variance change "
            f"{spectrum['max_relative_variance_change']:.2e}, spectrum bytes/viewframe "
            f"{spectrum['bank_bytes_per_viewframe'][0]:.0f} vs {spectrum['bank_bytes_per_viewframe'][1]:.0f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
