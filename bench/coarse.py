"""Coarse first stage: recall of the truth and of the full ranking's best among its candidates,
on simulated camera frames of a generated route (the ``bench/end_to_end.py`` generator); and
the effect of keeping the banks' memory spectrum in complex64 instead of complex128 (the same
frames ranked by both: top-1 agreement, largest relative change of a variance).

The truth is the route point nearest the frame's true position (as ``mapinterp run`` scores
top-1). Prints JSON, then a table.

    python bench/coarse.py [--size 500] [--frames 60] [--json-only]
    python bench/coarse.py --evalset heldout     # the held-out sweeps of bench/evalset instead

With ``--evalset SPLIT`` it runs on the sweeps of ``bench.evalset`` (other terrains, camera
frames from another renderer, other sizes, larger pose errors), one route per terrain; the
truth is the frame's ``route_index``.
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=500, help="route length (viewframes)")
    parser.add_argument("--frames", type=int, default=60, help="simulated camera frames")
    parser.add_argument("--evalset", default=None, metavar="SPLIT", help="the sweeps of bench.evalset instead")
    parser.add_argument("--json-only", action="store_true")
    args = parser.parse_args(argv)
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
