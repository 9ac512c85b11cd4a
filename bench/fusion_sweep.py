"""Fusion rules of the ranking sources, compared on the evaluation set from cached per-frame errors.

Step 1 (``--dump``): for every case of a split of :mod:`bench.evalset` (sweeps, drives, kidnaps)
it builds the viewframes (:class:`models.world.World`, as the map renderer does), ranks every
camera frame with the associative memory (``ViewframeIndex.rank``, the indexer's call) and
extracts its skyline profile (``skyline_from_image``, the skyline ranker's call), and writes the
per-frame associative errors over all viewframes, the query profile, the viewframes' profiles,
the route and the truth to ``<out>/<split>.npz``. Step 2 (default): reads that file, matches the
skylines (``match_skylines``, the schema's settings or ``--truncate``/``--max-roll``; and once
without the roll, ``skyline_flat``), fuses the two sources by each rule of :data:`RULES` (the
first rule, both standardised, at fixed weights: ``robust@w``, ``flat_robust@4`` being the
merged tree's default; the calibrated rule of :mod:`knowledge_sources.fusion` at the schema's
weights; ``--fit``: at the weights fitted on this split) and prints top-1 / top-5 per terrain
and overall, and the calibrated rule's position error: its first route point against estimates
between it and its neighbours from the fused posterior (:func:`position_errors`).

With ``--views`` the scenarios' own viewframes (``render.views_per_leg``: between the route points
too) are dumped and ranked, and a rule is judged by route point: a point ranks where its best
viewframe does (the scene analysis's candidates), and ``--fit`` maximises the true point's total
posterior over its viewframes (the tracker's observation of a point).

    python bench/fusion_sweep.py --split tuning --dump [--views]
    python bench/fusion_sweep.py --split tuning --fit [--views] [--rules ...] [--truncate 2] [--max-roll 3]

Prints JSON, then a table.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))

import numpy as np  # noqa: E402

from bench.evalset import SPLITS, cases, one_view_a_point  # noqa: E402
from knowledge_sources.fusion import fuse_rankings, fused_log_posterior  # noqa: E402
from models.scenario import MemorySpec, SkylineSpec  # noqa: E402
from models.skyline import match_skylines  # noqa: E402


def dump(split: str, out: Path, *, views: bool = False) -> Path:
    """Step 1 of the module docstring; returns the file written. ``views``: the scenario's own
    viewframes (``render.views_per_leg``) with each one's route point, instead of one a point."""
    from models.index import ViewframeIndex
    from models.route_views import route_points_of
    from models.scenario import load_scenario
    from models.sensor import load_frame_image
    from models.skyline import skyline_from_image
    from models.world import World

    rec: dict[str, list[Any]] = {k: [] for k in ("case", "truth", "assoc", "query", "xy", "arc")}
    refs: dict[str, np.ndarray] = {}
    routes: dict[str, np.ndarray] = {}
    points: dict[str, np.ndarray] = {}
    for case in cases(split):
        scenario = load_scenario(case.scenario_path)
        scenario = scenario if views else one_view_a_point(scenario)
        on = route_points_of(scenario)
        cam, sky = scenario.camera, scenario.skyline
        t0 = time.perf_counter()
        with World(scenario) as world:
            vfs = world.viewframes
            index = ViewframeIndex(scenario.memory, seed=0)
            index.add((v.image for v in vfs), [v.index for v in vfs])
            refs[case.name] = np.stack([v.skyline for v in vfs]).astype(np.float32)
            routes[case.name] = np.array([[v.pose.x, v.pose.y, v.pose.heading_deg] for v in vfs])
            points[case.name] = np.arange(len(vfs)) if on is None else np.asarray(on, dtype=np.int64)
            for fr in case.frames:
                image = load_frame_image(fr.image, width=cam.width, height=cam.height)
                rk = index.rank(image)
                err = np.empty(len(vfs))
                err[rk.viewframes] = rk.variances
                rec["case"].append(case.name)
                rec["truth"].append(int(fr.route_index))
                rec["assoc"].append(err)
                rec["query"].append(skyline_from_image(image, fov_y_deg=cam.fov_y_deg, step_deg=sky.step_deg))
                rec["xy"].append((fr.x, fr.y))
                rec["arc"].append(fr.arc_m)
        print(
            f"# {case.name}: {len(case.frames)} frames, {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True
        )
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{split}{'-views' if views else ''}.npz"
    np.savez(
        path,
        case=np.array(rec["case"]),
        truth=np.array(rec["truth"]),
        assoc=np.array(rec["assoc"], dtype=object),
        query=np.array(rec["query"]),
        xy=np.array(rec["xy"]),
        arc=np.array(rec["arc"]),
        ref_names=np.array(list(refs)),
        **{f"ref:{k}": v for k, v in refs.items()},
        **{f"route:{k}": v for k, v in routes.items()},
        **{f"points:{k}": v for k, v in points.items()},
    )
    return path


Rule = Callable[[dict[str, tuple[list[int], list[float]]]], list[tuple[int, float]]]

_MEM, _SKY = MemorySpec(), SkylineSpec()


def _robust(w: float, sky: str = "skyline") -> Rule:
    """The first rule: both sources standardised per frame, the skyline (``sky``: matched with
    the roll fitted or, ``"skyline_flat"``, without) at weight ``w``."""
    return lambda per: fuse_rankings(
        {"associative": per["associative"], "skyline": per[sky]},
        weights={"associative": 1.0, "skyline": w},
        absolute=(),
    )


def _calibrated(wa: float, ws: float) -> Rule:
    """The calibrated rule (:mod:`knowledge_sources.fusion`) at the given weights."""
    return lambda per: fuse_rankings(
        {"associative": per["associative"], "skyline": per["skyline"]}, weights={"associative": wa, "skyline": ws}
    )


#: name -> rule over {source: (labels, errors)}; the sources alone first
RULES: dict[str, Rule] = {
    "associative": lambda per: fuse_rankings({"associative": per["associative"]}),
    "skyline_flat": lambda per: fuse_rankings({"skyline": per["skyline_flat"]}),
    "skyline": lambda per: fuse_rankings({"skyline": per["skyline"]}),
    "flat_robust@4": _robust(4.0, "skyline_flat"),
    **{f"robust@{w:g}": _robust(w) for w in (1, 2, 4)},
    "calibrated": _calibrated(_MEM.weight, _SKY.weight),
}


def per_frame(data: dict[str, Any], *, truncate: float, max_roll: float) -> list[dict[str, Any]]:
    """Each frame's two sources' (labels, errors) with its truth and terrain."""
    match = {**_SKY.match_options(), "truncate_deg": truncate, "max_roll_deg": max_roll}
    out = []
    for i, name in enumerate(data["case"]):
        refs = data[f"ref:{name}"]
        m = match_skylines(data["query"][i], refs, **match)
        flat = match_skylines(data["query"][i], refs, **{**match, "max_roll_deg": 0.0})
        labels = list(range(len(refs)))
        key = f"points:{name}"
        out.append(
            {
                "per": {
                    "associative": (labels, list(data["assoc"][i])),
                    "skyline": (labels, m.error.tolist()),
                    "skyline_flat": (labels, flat.error.tolist()),
                },
                "truth": int(data["truth"][i]),
                "points": data[key] if key in data else np.arange(len(refs)),
                "terrain": str(name).split("/")[0],
            }
        )
    return out


def fit_weights(frames: list[dict[str, Any]]) -> tuple[float, float, float]:
    """The calibrated rule's (w_associative, w_skyline) that maximise the log posterior of the
    true route points (:func:`fused_log_posterior`; a point's is the total of its viewframes'),
    and that negative log-likelihood (nats)."""
    from scipy.optimize import minimize
    from scipy.special import logsumexp

    def nll(p: np.ndarray) -> float:
        w = {"associative": float(np.exp(p[0])), "skyline": float(np.exp(p[1]))}
        total = 0.0
        for f in frames:
            lab, lp = fused_log_posterior({s: f["per"][s] for s in w}, weights=w)
            total -= float(logsumexp(lp[f["points"][lab] == f["truth"]]))
        return total

    r = minimize(nll, np.log([_MEM.weight, _SKY.weight]), method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-3})
    return float(np.exp(r.x[0])), float(np.exp(r.x[1])), float(r.fun)


def position_errors(data: dict[str, Any], frames: list[dict[str, Any]], rule_weights: dict[str, float]) -> dict:
    """Metres from the true position: the calibrated rule's first route point, against two
    estimates between it and its route neighbours from the fused log posterior ``lp``: the
    posterior-weighted mean of the three points' (x, y), and the vertex of the parabola through
    ``lp`` at the three, moved along the route (at most half a spacing)."""
    out: dict[str, list[float]] = {"route_point": [], "mean_of_3": [], "parabola": []}
    for i, f in enumerate(frames):
        route = data[f"route:{data['case'][i]}"][:, :2]
        xy = np.asarray(data["xy"][i], dtype=np.float64)
        lab, lp = fused_log_posterior({s: f["per"][s] for s in rule_weights}, weights=rule_weights)
        k = int(lab[int(np.argmax(lp))])
        out["route_point"].append(float(np.hypot(*(route[k] - xy))))
        nb = [j for j in (k - 1, k, k + 1) if 0 <= j < len(route)]
        p = np.exp(lp[nb] - lp[k])
        out["mean_of_3"].append(float(np.hypot(*((p[:, None] * route[nb]).sum(0) / p.sum() - xy))))
        pos = route[k]
        if 0 < k < len(route) - 1:
            a, b, c = lp[k - 1], lp[k], lp[k + 1]
            den = a - 2 * b + c
            off = float(np.clip(0.5 * (a - c) / den, -0.5, 0.5)) if den < 0 else 0.0
            pos = route[k] + abs(off) * (route[k + (1 if off > 0 else -1)] - route[k])
        out["parabola"].append(float(np.hypot(*(pos - xy))))
    return {m: {"median_m": float(np.median(e)), "mean_m": float(np.mean(e))} for m, e in out.items()}


def evaluate(frames: list[dict[str, Any]], rules: dict[str, Rule]) -> dict[str, Any]:
    """Top-1 / top-5 of each rule per terrain and over all frames, by route point (a point ranked
    where its best viewframe is, as the scene analysis takes it)."""
    from models.route_views import first_per_point

    ranks: dict[str, list[int]] = {r: [] for r in rules}
    for f in frames:
        for r, rule in rules.items():
            best = first_per_point(rule(f["per"]), f["points"])
            ranks[r].append(next(j for j, (k, _) in enumerate(best) if int(f["points"][k]) == f["truth"]))
    terr = np.array([f["terrain"] for f in frames])
    out: dict[str, Any] = {"frames": len(frames), "terrains": {}, "overall": {}}
    for r in rules:
        rk = np.array(ranks[r])
        out["overall"][r] = {"top1": float(np.mean(rk < 1)), "top5": float(np.mean(rk < 5))}
        for t in sorted(set(terr)):
            sel = rk[terr == t]
            out["terrains"].setdefault(t, {})[r] = {"top1": float(np.mean(sel < 1)), "top5": float(np.mean(sel < 5))}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="tuning", choices=SPLITS)
    ap.add_argument("--dump", action="store_true", help="compute and cache the per-frame errors first")
    ap.add_argument("--out", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / "mapinterp-fusion")
    ap.add_argument("--rules", nargs="*", default=None, help=f"of {', '.join(RULES)} (default all)")
    ap.add_argument("--truncate", type=float, default=_SKY.truncate_deg, help="skyline truncate_deg")
    ap.add_argument("--max-roll", type=float, default=_SKY.max_roll_deg, help="skyline max_roll_deg")
    ap.add_argument("--fit", action="store_true", help="fit the calibrated rule's weights on this split")
    ap.add_argument(
        "--views", action="store_true", help="the scenarios' own viewframes (views_per_leg), judged by route point"
    )
    args = ap.parse_args(argv)
    path = args.out / f"{args.split}{'-views' if args.views else ''}.npz"
    if args.dump or not path.exists():
        path = dump(args.split, args.out, views=args.views)
    with np.load(path, allow_pickle=True) as z:
        data = {k: z[k] for k in z.files}
    frames = per_frame(data, truncate=args.truncate, max_roll=args.max_roll)
    rules = dict(RULES)
    fitted = None
    if args.fit:
        wa, ws, nll = fit_weights(frames)
        fitted = {"associative": wa, "skyline": ws, "nll": nll, "frames": len(frames)}
        rules["fitted"] = _calibrated(wa, ws)
    unknown = [r for r in (args.rules or []) if r not in rules]
    if unknown:
        ap.error(f"unknown rules {unknown}; known: {', '.join(rules)}")
    chosen = {r: rules[r] for r in (args.rules or rules)}
    res = evaluate(frames, chosen)
    res["position"] = position_errors(data, frames, {"associative": _MEM.weight, "skyline": _SKY.weight})
    settings = {"truncate_deg": args.truncate, "max_roll_deg": args.max_roll, "weights": [_MEM.weight, _SKY.weight]}
    print(json.dumps({"split": args.split, "settings": settings, "fitted": fitted, **res}, indent=1))
    if fitted:
        print(
            f"\nfitted weights: associative {fitted['associative']:.3f}, skyline {fitted['skyline']:.3f} (nll {fitted['nll']:.1f})"
        )
    print(f"\n{'terrain':22s} " + " ".join(f"{r:>14s}" for r in chosen))
    for t, row in {**res["terrains"], "ALL": res["overall"]}.items():
        print(f"{t:22s} " + " ".join(f"{row[r]['top1']:.3f}/{row[r]['top5']:.3f}".rjust(14) for r in chosen))
    print(
        "position of the calibrated rule's answer, median / mean m: "
        + ", ".join(f"{m} {v['median_m']:.1f} / {v['mean_m']:.1f}" for m, v in res["position"].items())
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
