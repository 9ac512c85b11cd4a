"""Single-frame ranking by source (associative, skyline, fused) and pose refinement, on the evaluation set.

For every sweep case of a split of :mod:`bench.evalset` it builds the viewframes from the case's
scenario (as the map renderer does), ranks every camera frame with the associative memory (the
indexer's model calls) and with the skyline (the skyline ranker's), fuses them with
:func:`knowledge_sources.fusion.fuse_rankings` at each skyline weight given (nats per degree, the
associative ranking at the scenario's ``memory.weight``; default the scenario's ``skyline.weight``),
and refines the pose
from the fused ranking's first viewframe (:func:`models.refine.refine_pose`, the refiner's call).
Truth is the case's ``route_index`` (the results' criterion). No blackboard and no landmark
verification: this measures the ranking sources and the refinement alone.

    python bench/skyline_eval.py --split tuning --weights 1 2 4 8 --no-refine
    python bench/skyline_eval.py --split heldout

Prints JSON (per case and overall), then a table.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from bench.evalset import cases, one_view_a_point  # noqa: E402
from knowledge_sources.fusion import fuse_rankings  # noqa: E402
from models.index import ViewframeIndex  # noqa: E402
from models.refine import refine_pose  # noqa: E402
from models.scenario import SkylineSpec, load_scenario  # noqa: E402
from models.sensor import load_frame_image  # noqa: E402
from models.skyline import match_skylines, skyline_from_image  # noqa: E402
from models.world import World  # noqa: E402


def _rank_of(truth: int, ranking: list[tuple[int, float]]) -> int:
    return next(i for i, (k, _) in enumerate(ranking) if k == truth)


def _wrap(d: float) -> float:
    return abs((d + 180.0) % 360.0 - 180.0)


def evaluate_case(
    case, *, weights: list[float], refine: bool, max_frames: int | None, roll_candidates: list[str] = ()
) -> dict:
    """``roll_candidates``: also rank with each of these skyline ``roll_candidates`` ("none": all),
    as sources ``skyline rc=K`` and ``fused@w rc=K`` (w the first weight), in the same run."""
    scenario = one_view_a_point(load_scenario(case.scenario_path))
    cam_spec, sky = scenario.camera, scenario.skyline
    match = sky.match_options()
    variants = {rc: {**match, "roll_candidates": None if rc == "none" else int(rc)} for rc in roll_candidates}
    out: dict = {"case": case.name, "frames": 0, "ranks": {}, "cost_ms": {}}
    with World(scenario) as world:
        emulator = world.emulator
        vfs = world.viewframes
        index = ViewframeIndex(scenario.memory, seed=0)
        index.add((v.image for v in vfs), [v.index for v in vfs])
        refs = np.stack([v.skyline for v in vfs])
        labels = [v.index for v in vfs]
        ranks: dict[str, list[int]] = {"associative": [], "skyline": [], **{f"fused@{w:g}": [] for w in weights}}
        for rc in variants:
            ranks[f"skyline rc={rc}"], ranks[f"fused@{weights[0]:g} rc={rc}"] = [], []
        t_assoc = t_sky = t_ref = 0.0
        pos_err, pos_err_route, head_err, head_err_route, renders, scores = [], [], [], [], [], []
        frames = case.frames[:max_frames] if max_frames else case.frames
        for fr in frames:
            image = load_frame_image(fr.image, width=cam_spec.width, height=cam_spec.height)
            truth = int(fr.route_index)
            t0 = time.perf_counter()
            rk = index.rank(image)
            t1 = time.perf_counter()
            q = skyline_from_image(image, fov_y_deg=cam_spec.fov_y_deg, step_deg=sky.step_deg)
            m = match_skylines(q, refs, **match)
            t2 = time.perf_counter()
            t_assoc += t1 - t0
            t_sky += t2 - t1
            per = {
                "associative": (rk.viewframes.tolist(), rk.variances.tolist()),
                "skyline": (labels, m.error.tolist()),
            }
            ranks["associative"].append(_rank_of(truth, fuse_rankings({"associative": per["associative"]})))
            ranks["skyline"].append(_rank_of(truth, fuse_rankings({"skyline": per["skyline"]})))
            for rc, opts in variants.items():
                e = match_skylines(q, refs, **opts).error.tolist()
                ranks[f"skyline rc={rc}"].append(_rank_of(truth, fuse_rankings({"skyline": (labels, e)})))
                both = {"associative": per["associative"], "skyline": (labels, e)}
                fused = fuse_rankings(both, weights={"associative": scenario.memory.weight, "skyline": weights[0]})
                ranks[f"fused@{weights[0]:g} rc={rc}"].append(_rank_of(truth, fused))
            fused_first = None
            for w in weights:
                fused = fuse_rankings(per, weights={"associative": scenario.memory.weight, "skyline": w})
                ranks[f"fused@{w:g}"].append(_rank_of(truth, fused))
                if w == weights[0]:
                    fused_first = fused[0][0]
            if refine and fused_first is not None:
                p = vfs[fused_first].pose
                t3 = time.perf_counter()
                r = refine_pose(
                    image,
                    emulator,
                    p,
                    along_m=scenario.refine.along_m,
                    across_m=scenario.refine.across_m,
                    levels=scenario.refine.levels,
                    grid=scenario.refine.grid,
                    edge_weight=scenario.refine.edge_weight,
                    **{k: v for k, v in match.items() if k != "roll_candidates"},  # one reference per match
                    max_roll_deg=scenario.refine.max_roll_deg,
                )
                t_ref += time.perf_counter() - t3
                pos_err.append(math.hypot(r.x - fr.x, r.y - fr.y))
                pos_err_route.append(math.hypot(p.x - fr.x, p.y - fr.y))
                head_err.append(_wrap(r.heading_deg - fr.heading_deg))
                head_err_route.append(_wrap(p.heading_deg - fr.heading_deg))
                renders.append(r.renders)
                scores.append([r.start_score, r.score, int(fused_first == truth)])
        n = len(frames)
        out["frames"] = n
        out["ranks"] = ranks
        out["cost_ms"] = {"associative": 1000 * t_assoc / n, "skyline": 1000 * t_sky / n}
        if refine:
            out["cost_ms"]["refine"] = 1000 * t_ref / n
            out["refine"] = {
                "error_m": pos_err,
                "route_error_m": pos_err_route,
                "heading_error_deg": head_err,
                "route_heading_error_deg": head_err_route,
                "renders": renders,
            }
    return out


def summarize(results: list[dict]) -> dict:
    def topk(ranks: list[int], k: int) -> float:
        return float(np.mean(np.asarray(ranks) < k)) if ranks else float("nan")

    sources = list(results[0]["ranks"]) if results else []
    total: dict = {"frames": sum(r["frames"] for r in results), "cases": {}, "overall": {}}
    for r in results:
        total["cases"][r["case"]] = {
            s: {"top1": topk(r["ranks"][s], 1), "top5": topk(r["ranks"][s], 5)} for s in sources
        }
        if "refine" in r:
            e = r["refine"]
            total["cases"][r["case"]]["refine"] = {
                "median_m": float(np.median(e["error_m"])),
                "mean_m": float(np.mean(e["error_m"])),
                "route_median_m": float(np.median(e["route_error_m"])),
                "heading_median_deg": float(np.median(e["heading_error_deg"])),
            }
    for s in sources:
        allr = [x for r in results for x in r["ranks"][s]]
        total["overall"][s] = {"top1": topk(allr, 1), "top5": topk(allr, 5)}
    refs = [r["refine"] for r in results if "refine" in r]
    if refs:
        cat = {k: [x for e in refs for x in e[k]] for k in refs[0]}
        total["overall"]["refine"] = {
            "median_m": float(np.median(cat["error_m"])),
            "mean_m": float(np.mean(cat["error_m"])),
            "route_median_m": float(np.median(cat["route_error_m"])),
            "route_mean_m": float(np.mean(cat["route_error_m"])),
            "heading_median_deg": float(np.median(cat["heading_error_deg"])),
            "route_heading_median_deg": float(np.median(cat["route_heading_error_deg"])),
            "renders_mean": float(np.mean(cat["renders"])),
        }
    n = max(1, len(results))
    total["overall"]["cost_ms"] = {
        k: float(np.mean([r["cost_ms"][k] for r in results])) for k in (results[0]["cost_ms"] if results else {})
    }
    del n
    return total


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="tuning", choices=("tuning", "heldout"))
    ap.add_argument(
        "--weights", type=float, nargs="+", default=[SkylineSpec().weight], help="skyline weights to fuse with"
    )
    ap.add_argument("--no-refine", action="store_true")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--names", nargs="*", default=None, help="terrain names (default all of the split)")
    ap.add_argument(
        "--roll-candidates",
        nargs="*",
        default=[],
        help="also rank with these skyline roll_candidates (integers, or none: all), in the same run",
    )
    args = ap.parse_args(argv)
    results = []
    for case in cases(args.split, kinds=["sweep"], names=args.names):
        results.append(
            evaluate_case(
                case,
                weights=args.weights,
                refine=not args.no_refine,
                max_frames=args.max_frames,
                roll_candidates=args.roll_candidates,
            )
        )
        print(f"# {case.name}: " + json.dumps(summarize(results[-1:])["cases"][case.name]), file=sys.stderr, flush=True)
    summary = summarize(results)
    print(json.dumps({"split": args.split, "summary": summary}, indent=1))
    sources = list(summary["overall"].keys())
    print(f"\n{'case':28s} " + " ".join(f"{s:>16s}" for s in sources if s not in ("refine", "cost_ms")))
    for name, c in summary["cases"].items():
        cells = [f"{c[s]['top1']:.2f}/{c[s]['top5']:.2f}" for s in sources if s in c and s != "refine"]
        extra = ""
        if "refine" in c:
            rf = c["refine"]
            extra = (
                f"  refine med {rf['route_median_m']:.1f}->{rf['median_m']:.1f} m, head {rf['heading_median_deg']:.2f}"
            )
        print(f"{name:28s} " + " ".join(f"{x:>16s}" for x in cells) + extra)
    o = summary["overall"]
    print(
        f"{'ALL (top1/top5)':28s} "
        + " ".join(
            f"{o[s]['top1']:.2f}/{o[s]['top5']:.2f}".rjust(16) for s in sources if s not in ("refine", "cost_ms")
        )
    )
    if "refine" in o:
        rf = o["refine"]
        print(
            f"refined error median {rf['median_m']:.1f} m (route point {rf['route_median_m']:.1f}), mean "
            f"{rf['mean_m']:.1f} m (route point {rf['route_mean_m']:.1f}); heading median "
            f"{rf['heading_median_deg']:.2f} deg (route {rf['route_heading_median_deg']:.2f}); "
            f"{rf['renders_mean']:.0f} renders/frame"
        )
    print("cost ms/frame: " + ", ".join(f"{k} {v:.1f}" for k, v in o["cost_ms"].items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
