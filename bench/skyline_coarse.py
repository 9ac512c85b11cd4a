"""The skyline ranking's coarse stage (:mod:`models.skyline_coarse`): its recall and its cost.

For each data set it takes camera-frame profiles (queries) and reference profiles, matches every
query with every reference in full (:func:`models.skyline.match_skylines`, the scenario's
``skyline`` settings: the exact ranking) and with the coarse stage (:func:`coarse_errors`), and
reports, for each candidate count M:

* ``best``: how often the full ranking's first (ties: the lowest label) is among the coarse
  stage's M best; for the Ms of ``--check``, how often the coarse + fine ranking's first is the
  full ranking's (``same_top1``: not always when it is among the candidates, since the roll is
  fitted for the ``skyline.roll_candidates`` best of the roll-free pass over the references
  matched, and a candidate may enter that set) and is the truth (``top1``, next to
  ``full_top1``);
* ``truth``: how often the true viewframe is among the coarse M best, next to ``truth_full``,
  how often it is among the full ranking's M best (the coarse stage cannot do better than the
  full ranking's own recall);

and the coarse ranks of the full ranking's first (max, p99).

Data sets (``--sets``):

* ``tuning`` / ``heldout``: the evaluation set's split (:mod:`bench.evalset`; every case, sweeps
  and drives: camera frames from its ray caster, other resolutions, pose errors with pitch and
  roll). A case has 32 viewframes only, so the references are *padded*: all the split's
  terrains' viewframes pooled, plus views rendered (as the map
  renderer renders viewframes, the scenario camera on the terrain) along random routes on the
  same terrain (random walks at the case's route spacing, heading along the walk, away from the
  border by 10 %): about 10,000 references per split by default, most of them from the same
  terrains as the frames.
* ``route``: a long generated route (``bench/scale.py``'s generator, ``--route-size``
  viewframes, its references read from a viewframe cache entry, ``--route-cache``, read-only)
  with the simulated frames of its drive (``bench/scale.py``'s, ``--route-drive`` frames along
  the start of the route) plus simulated frames at every ``--route-stride``-th route point
  (``sensor.simulate``: jitter, lighting and photometric degradation), truth the route point
  nearest the frame.

Cost (``--timing``): CPU ms per frame (``time.process_time``) of the skyline ranking's match on a
set's first ``--timing-frames`` queries, against its first ``K`` references for each K of
``--timing-sizes``: the full ranking and the coarse + fine ranking (at ``--timing-m``),
alternating per frame (full first on even frames) so that load changes hit both; the horizon
extraction from the image is not included (it is the same in both). BLAS runs on one thread
(``OPENBLAS_NUM_THREADS=1`` unless set; the threaded BLAS spins on a loaded machine).

Profiles are cached in ``--data-dir`` (queries and references per set; a change of the skyline
settings or of ``--references`` makes new files).

    python bench/skyline_coarse.py --sets tuning --ms 50 100 200 300 500
    python bench/skyline_coarse.py --sets heldout route --timing

Prints JSON, then a table.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
# bench/blackboard.py would shadow the blackboard package: drop this folder from the path
HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]
sys.path.insert(0, str(HERE.parent))

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from models.scenario import load_scenario  # noqa: E402
from models.skyline import match_skylines, skyline_from_depth, skyline_from_image  # noqa: E402
from models.skyline_coarse import (  # noqa: E402
    COARSE_FACTOR,
    CoarseSkylines,
    coarse_errors,
    coarse_options,
    ranked_references,
)


def _walk(terrain, count: int, spacing: float, rng: np.random.Generator) -> list[tuple[float, float, float]]:
    """``count`` (x, y, heading_deg) along random walks of ``spacing`` metres on ``terrain``,
    10 % away from its border; a walk that would leave turns back."""
    x0, x1, y0, y1 = terrain.extent
    mx, my = 0.1 * (x1 - x0), 0.1 * (y1 - y0)
    lo, hi = np.array([x0 + mx, y0 + my]), np.array([x1 - mx, y1 - my])
    out: list[tuple[float, float, float]] = []
    while len(out) < count:
        p = rng.uniform(lo, hi)
        h = rng.uniform(0, 2 * math.pi)
        for _ in range(min(60, count - len(out))):
            h += rng.normal(0, 0.15)
            step = spacing * np.array([math.cos(h), math.sin(h)])
            if not np.all((p + step >= lo) & (p + step <= hi)):
                h += math.pi
                step = -step
            p = p + step
            out.append((float(p[0]), float(p[1]), math.degrees(h)))
    return out


def _hash(*parts: object) -> str:
    return hashlib.sha1(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:12]


def evalset_data(split: str, *, references: int, data_dir: Path) -> dict:
    """Queries and padded references (about ``references`` in all) of one evaluation-set split
    (module docstring)."""
    from bench.evalset import cases
    from models.sensor import load_frame_image
    from models.world import World

    out_refs, out_q, out_truth, out_case = [], [], [], []
    offset = 0
    sweeps = list(cases(split, kinds=["sweep"]))
    for case in sweeps:
        distractors = max(0, math.ceil(references / len(sweeps)) - len(case.route))
        scenario = load_scenario(case.scenario_path)
        cam, step = scenario.camera, scenario.skyline.step_deg
        f = data_dir / f"{split}-{case.terrain}-{_hash(distractors, step, cam.model_dump())}.npz"
        if not f.is_file():
            with World(scenario, cache=None) as world:
                own = np.stack([v.skyline for v in world.viewframes])
                rng = np.random.default_rng(case.seed)
                emu = world.emulator
                extra = [
                    skyline_from_depth(emu.render(emu.pose_at(x, y, h)).depth, fov_y_deg=cam.fov_y_deg, step_deg=step)
                    for x, y, h in _walk(world.environment.terrain, distractors, case.spacing_m, rng)
                ]
            queries, truth, names = [], [], []
            for c in cases(split, names=[case.terrain]):  # the sweep and the drives of the terrain
                for fr in c.frames:
                    img = load_frame_image(fr.image, width=cam.width, height=cam.height)
                    queries.append(skyline_from_image(img, fov_y_deg=cam.fov_y_deg, step_deg=step))
                    truth.append(int(fr.route_index))
                    names.append(c.name)
            tmp = f.with_suffix(".tmp.npz")
            np.savez(
                tmp,
                own=own,
                extra=np.stack(extra) if extra else np.zeros((0, own.shape[1]), np.float32),
                queries=np.stack(queries),
                truth=np.asarray(truth),
                names=np.asarray(names),
            )
            os.replace(tmp, f)
        with np.load(f) as z:
            own, extra, queries, truth, names = z["own"], z["extra"], z["queries"], z["truth"], z["names"]
        out_refs.append(own)
        out_q.append(queries)
        out_truth.append(truth + offset)
        out_case.extend(names.tolist())
        offset += len(own)
        out_refs.append(extra)  # labels after the route points of this terrain
        offset += len(extra)
    return {
        "references": np.concatenate(out_refs).astype(np.float32),
        "queries": np.concatenate(out_q).astype(np.float32),
        "truth": np.concatenate(out_truth),
        "cases": out_case,
        "match": load_scenario(case.scenario_path).skyline.match_options(),
    }


def route_data(size: int, *, cache: Path, drive: int, stride: int, data_dir: Path) -> dict:
    """References (from the viewframe cache entry, read-only) and simulated frames of the
    ``bench/scale.py`` route of ``size`` viewframes (module docstring)."""
    import importlib.util

    from models.scenario import SimulateSpec
    from models.sensor import simulate_frames
    from models.viewframe_cache import cache_key
    from models.world import World

    spec = importlib.util.spec_from_file_location("scale", HERE / "scale.py")
    assert spec is not None and spec.loader is not None
    scale = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(scale)
    folder = data_dir / f"route{size}"
    folder.mkdir(parents=True, exist_ok=True)
    path = scale._make_scenario(size, folder, 40)
    drive_path = scale.drive_scenario(path, frames=drive)
    scenario = load_scenario(path)
    cam, step = scenario.camera, scenario.skyline.step_deg
    f = data_dir / f"route{size}-{_hash(drive, stride, step, cam.model_dump())}.npz"
    if not f.is_file():
        with World(scenario, cache=None) as world:
            key = cache_key(scenario, world.environment.terrain)
            entry = cache / key
            if not (entry / "meta.json").is_file():
                raise SystemExit(f"route{size}: no viewframe cache entry {entry} (fill it with bench/scale.py first)")
            refs = np.load(entry / "skyline.npy", mmap_mode="r")
            route = np.asarray([[p.x, p.y] for p in world.poses])
            frames = list(World(load_scenario(drive_path), cache=None, terrain=world.environment.terrain).sensor_frames)
            sim = SimulateSpec(stride=stride)
            frames += simulate_frames(scenario, world.emulator, world.poses, spec=sim, rng=12345)
            queries = [skyline_from_image(fr.image, fov_y_deg=cam.fov_y_deg, step_deg=step) for fr in frames]
            truth = [int(np.argmin(np.hypot(*(route - np.asarray(fr.truth[:2])).T))) for fr in frames]
            kinds = ["drive"] * drive + ["stride"] * (len(frames) - drive)
            tmp = f.with_suffix(".tmp.npz")
            np.savez(tmp, refs=np.asarray(refs), queries=np.stack(queries), truth=np.asarray(truth), kinds=kinds)
            os.replace(tmp, f)
    with np.load(f) as z:
        return {
            "references": z["refs"].astype(np.float32),
            "queries": z["queries"].astype(np.float32),
            "truth": z["truth"],
            "cases": z["kinds"].tolist(),
            "match": scenario.skyline.match_options(),
        }


def _position(order: np.ndarray, k: int) -> int:
    return int(np.nonzero(order == k)[0][0])


def recall(data: dict, ms: list[int], *, check: list[int], factor: int) -> dict:
    """Ranks of the full ranking's first and of the truth in the coarse and the full orders."""
    refs, queries, truth = data["references"], data["queries"], data["truth"]
    match = dict(data["match"])
    roll = match.pop("roll_candidates")
    coarse = CoarseSkylines.prepare(refs, factor=factor)
    labels = np.arange(len(refs))
    rank_best, rank_truth, rank_truth_full = [], [], []
    same: dict[int, list[bool]] = {m: [] for m in check}
    top1: dict[int, list[bool]] = {m: [] for m in check}
    for q, t in zip(queries, truth):
        full = match_skylines(q, refs, roll_candidates=roll, **match)
        order_full = np.lexsort((labels, full.error))
        best = int(order_full[0])
        order = np.argsort(coarse_errors(q, coarse, **coarse_options(match)), kind="stable")
        rank_best.append(_position(order, best))
        rank_truth.append(_position(order, int(t)))
        rank_truth_full.append(_position(order_full, int(t)))
        for m in check:
            idx, sub = ranked_references(q, refs, coarse, candidates=m, roll_candidates=roll, **match)
            first = int(idx[np.lexsort((idx, sub.error))[0]])
            same[m].append(first == best)
            top1[m].append(first == int(t))
    rb, rt, rf = np.asarray(rank_best), np.asarray(rank_truth), np.asarray(rank_truth_full)
    return {
        "frames": len(queries),
        "references": len(refs),
        "factor": factor,
        "recall": {
            str(m): {
                "best": float(np.mean(rb < m)),
                "truth": float(np.mean(rt < m)),
                "truth_full": float(np.mean(rf < m)),
                "best_missed": int(np.sum(rb >= m)),
            }
            for m in ms
        },
        "same_top1": {str(m): float(np.mean(v)) for m, v in same.items()},
        "top1": {str(m): float(np.mean(v)) for m, v in top1.items()},
        "full_top1": float(np.mean(rf == 0)),
        "coarse_rank_of_best": {
            "max": int(rb.max()),
            "p99": float(np.percentile(rb, 99)),
            "median": float(np.median(rb)),
        },
        "ranks_best": rb.tolist(),
    }


def timing(data: dict, sizes: list[int], *, frames: int, m: int, factor: int) -> dict:
    """CPU ms per frame of the full and the coarse + fine match, alternating (module docstring)."""
    match = dict(data["match"])
    roll = match.pop("roll_candidates")
    out = {}
    for size in sizes:
        refs = data["references"][:size]
        coarse = CoarseSkylines.prepare(refs, factor=factor)
        t_full, t_two = [], []
        for i, q in enumerate(data["queries"][:frames]):
            for which in ("full", "two") if i % 2 == 0 else ("two", "full"):
                t0 = time.process_time()
                if which == "full":
                    match_skylines(q, refs, roll_candidates=roll, **match)
                    t_full.append(time.process_time() - t0)
                else:
                    ranked_references(q, refs, coarse, candidates=m, roll_candidates=roll, **match)
                    t_two.append(time.process_time() - t0)
        t0 = time.process_time()
        for q in data["queries"][:frames]:
            coarse_errors(q, coarse, **coarse_options(match))
        t_coarse = (time.process_time() - t0) / max(1, frames)
        out[str(size)] = {
            "frames": frames,
            "m": m,
            "full_ms": 1000 * float(np.mean(t_full)),
            "coarse_fine_ms": 1000 * float(np.mean(t_two)),
            "coarse_only_ms": 1000 * t_coarse,
            "ratio": float(np.mean(t_full) / np.mean(t_two)),
            "load_avg": os.getloadavg(),
            "utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        }
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", nargs="+", default=["tuning"], choices=["tuning", "heldout", "route"])
    ap.add_argument("--ms", nargs="+", type=int, default=[25, 50, 100, 200, 300, 500, 1000])
    ap.add_argument("--check", nargs="*", type=int, default=[200, 300], help="Ms whose coarse + fine top-1 is checked")
    ap.add_argument("--factor", type=int, default=COARSE_FACTOR, help="bins per coarse block")
    ap.add_argument(
        "--references", type=int, default=10000, help="evaluation-set splits: references in all, with the padding"
    )
    ap.add_argument("--route-size", type=int, default=10000)
    ap.add_argument("--route-cache", type=Path, default=Path("/work/cache/scale10k"))
    ap.add_argument("--route-drive", type=int, default=40)
    ap.add_argument("--route-stride", type=int, default=50)
    ap.add_argument("--timing", action="store_true")
    ap.add_argument("--timing-sizes", nargs="+", type=int, default=[2000, 10000])
    ap.add_argument("--timing-frames", type=int, default=40)
    ap.add_argument("--timing-m", type=int, default=None, help="default: the scenario's skyline.coarse_candidates")
    ap.add_argument("--data-dir", type=Path, default=Path.home() / ".cache" / "mapinterp-bench" / "skyline_coarse")
    ap.add_argument("--json-only", action="store_true")
    args = ap.parse_args(argv)
    args.data_dir.mkdir(parents=True, exist_ok=True)
    result: dict = {
        "utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
        "load_avg_start": os.getloadavg(),
        "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
        "argv": sys.argv[1:] if argv is None else argv,
        "sets": {},
    }
    for name in args.sets:
        if name == "route":
            data = route_data(
                args.route_size,
                cache=args.route_cache,
                drive=args.route_drive,
                stride=args.route_stride,
                data_dir=args.data_dir,
            )
        else:
            data = evalset_data(name, references=args.references, data_dir=args.data_dir)
        res = recall(data, args.ms, check=args.check, factor=args.factor)
        if args.timing:
            m = args.timing_m
            if m is None:
                from models.scenario import SkylineSpec

                m = SkylineSpec().coarse_candidates or args.ms[-1]
            res["timing"] = timing(data, args.timing_sizes, frames=args.timing_frames, m=m, factor=args.factor)
        res["load_avg_end"] = os.getloadavg()
        res["utc_end"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        result["sets"][name] = res
    text = json.dumps(result, indent=1)
    print(text)
    if args.json_only:
        return 0
    print()
    print(f"skyline coarse stage (factor {args.factor}), {result['utc']}, load {result['load_avg_start']}")
    print(f"  {'set':<9}{'frames':>7}{'refs':>7}{'M':>6}{'best':>9}{'truth':>9}{'truth full':>12}{'missed':>8}")
    for name, res in result["sets"].items():
        for m, r in res["recall"].items():
            print(
                f"  {name:<9}{res['frames']:>7}{res['references']:>7}{m:>6}{r['best']:>9.4f}{r['truth']:>9.4f}"
                f"{r['truth_full']:>12.4f}{r['best_missed']:>8}"
            )
        for m, v in res["top1"].items():
            print(
                f"  {name}: truth first, full {res['full_top1']:.4f}, coarse+fine (M={m}) {v:.4f}; "
                f"same first as the full ranking {res['same_top1'][m]:.4f}"
            )
        for size, t in res.get("timing", {}).items():
            print(
                f"  {name} at {size} refs: full {t['full_ms']:.1f} ms, coarse+fine (M={t['m']}) "
                f"{t['coarse_fine_ms']:.1f} ms (coarse alone {t['coarse_only_ms']:.1f}), x{t['ratio']:.1f}, load {t['load_avg']}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
