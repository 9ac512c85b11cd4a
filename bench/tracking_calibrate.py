"""Calibrate the tracker's observation model on tuning drives (never the evaluation set).

Tuning data: simulated drives (models.sensor drive mode, larger pose errors than the bundled
scenarios' frames) over the bundled terrains and generated serpentine routes, with the TUNING
seeds below; every frame ranked by the real associative memory (bench/tracking_data.py).

Fit: the observation model of models/tracking.py gives each route point k of a frame the
likelihood ``L_k = eps_f + exp(gain - z_k / temperature)`` (``z_k`` the observed value above the
best, in nats for the calibrated fusion, ``--scores nats``, or in robust spreads, ``robust``), ``eps_f = eps + margin_scale / margin``. Normalised over the route points, ``L_k / sum_j L_j`` is what one frame alone
says about where the camera is (a uniform prior); the parameters maximise the mean log of that
probability at the true route point (nearest to the true position) over all tuning frames
(Nelder-Mead in log-parameters). Also printed: the histograms of ``z`` for true and for other
route points (their log ratio is what ``log L`` estimates), a reliability table (the fitted
single-frame probability of the best route point against how often it is right), the fit with a
uniform outlier part instead of the floor (``tracking.outlier``; temperature, spread, outlier
weight) and each route point's probability under the observed posterior at temperature 1
against how often it is the truth (session 10: under-confident).

What a frame's ranking is (``--observe``): ``fused`` (the default, what the tracker observes),
every ranking source of the drive (associative memory and skyline) fused by the scheduler's rule
(knowledge_sources.fusion, bench/tracking_data.observed), or ``associative``, the memory's
ranking alone (the tracker before it observed the skyline).

The defaults of the scenario schema come from the evaluation set's TUNING split alone (frames of
another renderer than the viewframes', like the judged data), ranked by bench/tracking.py:

    python bench/tracking.py --split tuning --cache /tmp/tune.pkl --json-only > /dev/null
    python bench/tracking_calibrate.py --evalset-tuning /tmp/tune.pkl --no-sim --observe fused [--scores nats]

    python bench/tracking_calibrate.py [--quick] [--cache /tmp/tracking_tune.npz] [--observe fused|associative]

Prints JSON, then a table.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import pickle  # noqa: E402
import tempfile  # noqa: E402

import numpy as np  # noqa: E402
from scipy.optimize import minimize  # noqa: E402

from models.scenario import load_scenario  # noqa: E402
from models.tracking import SCORES, ObservationModel, RouteGrid, ranking_scores  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
from tracking_data import OBSERVE, observed  # noqa: E402

sys.path.pop(0)
#: seeds of the tuning drives: the evaluation set's seeds must be different (BENCHMARKS.md)
TUNING_SEEDS = (101, 202)
TUNING_DRIVE = {
    "interval_s": 3.0,
    "speed_mps": [5.0, 18.0],
    "p_stop": 0.08,
    "lateral_m": 3.0,
    "heading_deg": 4.0,
    "kidnap_at": 12,
}


def generated_route(folder: Path, *, n: int, seed: int) -> Path:
    """A serpentine procedural route (bench/end_to_end.py's generator) with a tuning seed."""
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        from end_to_end import make_scenario
    finally:
        sys.path.pop(0)
    folder.mkdir(parents=True, exist_ok=True)
    return make_scenario(n, folder, seed=seed, frames=n)


def harvest(quick: bool) -> list[dict]:
    sys.path.insert(0, str(ROOT / "bench"))
    from tracking_data import ranked_drive, with_drive

    drives = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        bases = [ROOT / "scenarios" / f"{n}.yaml" for n in ("hills", "jacksboro", "contours")]
        if not quick:
            bases += [generated_route(tmp / f"g{s}", n=80, seed=s) for s in (31, 47)]
        for base in bases:
            for seed in TUNING_SEEDS[: 1 if quick else None]:
                sc = with_drive(load_scenario(base), TUNING_DRIVE, seed=seed, path=tmp / f"{base.stem}-{seed}.yaml")
                d = ranked_drive(sc)
                d["seed"] = seed
                drives.append(d)
                print(f"harvested {d['name']} seed {seed}: {len(d['true_point'])} frames", file=sys.stderr)
    return drives


def frame_scores(drives: list[dict], scores: str) -> tuple[list[np.ndarray], list[float], list[int]]:
    zs, margins, truths = [], [], []
    for d in drives:
        for v, t in zip(d["variances"], d["true_point"]):
            if t < 0:
                continue
            z, m = ranking_scores(v, scores=scores)
            zs.append(z)
            margins.append(m)
            truths.append(int(t))
    return zs, margins, truths


def arc_frames(drives: list[dict]) -> list[tuple]:
    """Per frame: (grid, variances, true arc length): the truth projected on the route."""
    out = []
    for d in drives:
        grid = RouteGrid.build(d["route"], cell_m=1.0, tail=0.5)
        for v, (x, y, _) in zip(d["variances"], d["truth"]):
            if not np.isfinite(x):
                continue
            c = int(np.argmin(np.hypot(grid.xy[:, 0] - x, grid.xy[:, 1] - y)))
            out.append((grid, v, float(grid.centres[c])))
    return out


def _model(params: np.ndarray, scores: str) -> ObservationModel:
    temperature, eps, margin_scale, spread = np.exp(params)
    return ObservationModel(float(temperature), 0.0, float(min(eps, 1.0)), float(margin_scale), float(spread), scores)


def mean_log_density(params: np.ndarray, frames, scores: str) -> float:
    """Mean log of the single-frame density over arc length at the true arc (1/m)."""
    model = _model(params, scores)
    if not (0.05 < model.temperature < 20 and 0.02 < model.spread < 3):
        return -1e9
    total = 0.0
    for grid, v, s in frames:
        ll = model.loglik(v, grid)
        top = ll.max()
        dens = np.exp(ll - top)
        norm = np.trapezoid(dens, grid.samples)
        total += float(np.interp(s, grid.samples, ll)) - top - math.log(norm)
    return total / len(frames)


def fit(frames, scores: str) -> dict:
    x0 = np.log([1.0, 0.01, 0.3, 0.4])
    res = minimize(
        lambda p: -mean_log_density(p, frames, scores),
        x0,
        method="Nelder-Mead",
        options={"maxiter": 500, "xatol": 1e-3, "fatol": 1e-5},
    )
    m = _model(res.x, scores)
    length = float(np.mean([g.arc[-1] for g, _, _ in frames]))
    return {
        "temperature": m.temperature,
        "gain": 0.0,
        "eps": m.eps,
        "margin_scale": m.margin_scale,
        "spread": m.spread,
        "scores": scores,
        "mean_log_density": float(-res.fun),
        "uniform_log_density": float(-math.log(length)),
    }


def _mixture_model(params: np.ndarray, scores: str) -> ObservationModel:
    temperature, spread = np.exp(params[:2])
    outlier = 1.0 / (1.0 + math.exp(-float(params[2])))
    return ObservationModel(float(temperature), 0.0, 0.0, 0.0, float(spread), scores, float(outlier))


def fit_mixture(frames, scores: str) -> dict:
    """The observation with a uniform outlier part (``tracking.outlier``, session 10): temperature,
    spread and outlier weight maximising the same mean log density at the true arc length."""

    def objective(p: np.ndarray) -> float:
        m = _mixture_model(p, scores)
        if not (0.05 < m.temperature < 20 and 0.02 < m.spread < 3):
            return 1e9
        total = 0.0
        for grid, v, s in frames:
            ll = m.loglik(v, grid)
            top = ll.max()
            norm = np.trapezoid(np.exp(ll - top), grid.samples)
            total += float(np.interp(s, grid.samples, ll)) - top - math.log(norm)
        return -total / len(frames)

    res = minimize(objective, np.array([math.log(0.7), math.log(0.3), -3.0]), method="Nelder-Mead")
    m = _mixture_model(res.x, scores)
    return {"temperature": m.temperature, "spread": m.spread, "outlier": m.outlier, "mean_log_density": float(-res.fun)}


def point_reliability(zs, truths) -> list[dict]:
    """Each route point's probability under the observed posterior at temperature 1 (``exp(-z)``
    normalised over the route points: what the tracker took as it is before session 10) against
    how often the truth is that point: under-confident where the frequency is above the mean."""
    probs, hits = [], []
    for z, t in zip(zs, truths):
        p = np.exp(-np.nan_to_num(z, nan=np.inf))
        p /= p.sum()
        probs.append(p)
        hits.append(np.arange(p.size) == t)
    pr, hit = np.concatenate(probs), np.concatenate(hits)
    out = []
    for a, b in (
        (0, 1e-3),
        (1e-3, 0.01),
        (0.01, 0.03),
        (0.03, 0.1),
        (0.1, 0.2),
        (0.2, 0.3),
        (0.3, 0.5),
        (0.5, 0.7),
        (0.7, 1.01),
    ):
        sel = (pr >= a) & (pr < b)
        out.append(
            {
                "p": f"{a:g}-{min(b, 1):g}",
                "points": int(sel.sum()),
                "mean_p": float(pr[sel].mean()) if sel.any() else None,
                "truth": float(hit[sel].mean()) if sel.any() else None,
            }
        )
    return out


def histograms(zs, truths) -> list[dict]:
    edges = np.array([0, 0.25, 0.5, 1, 1.5, 2, 3, 4, 6, 8, 12, np.inf])
    true_z = np.array([z[t] for z, t in zip(zs, truths)])
    other = np.concatenate(
        [np.delete(z, [k for k in (t - 1, t, t + 1) if 0 <= k < z.size]) for z, t in zip(zs, truths)]
    )
    ht, _ = np.histogram(true_z, edges)
    ho, _ = np.histogram(other[np.isfinite(other)], edges)
    pt, po = ht / max(ht.sum(), 1), ho / max(ho.sum(), 1)
    return [
        {
            "z": f"{a:g}-{b:g}",
            "true": int(nt),
            "other": int(no),
            "log_ratio": float(np.log(max(p1, 1e-9) / max(p2, 1e-9))) if nt else None,
        }
        for a, b, nt, no, p1, p2 in zip(edges[:-1], edges[1:], ht, ho, pt, po)
    ]


def reliability(params: dict, frames) -> list[dict]:
    """Single-frame probability of the route point with the most density against how often it is right."""
    model = ObservationModel(
        params["temperature"], params["gain"], params["eps"], params["margin_scale"], params["spread"], params["scores"]
    )
    probs, right = [], []
    cache: dict[int, RouteGrid] = {}
    for grid, v, s in frames:
        fine = cache.setdefault(id(grid), RouteGrid.build(grid.route, cell_m=2.0))
        ll = fine.cell_loglik(model.loglik(v, fine))
        p = np.exp(ll - ll.max())
        mass = fine.point_mass(p / p.sum())
        k = int(np.argmax(mass))
        truth = int(fine.region[int(np.clip(s / fine.cell_m, 0, fine.cells - 1))])
        probs.append(mass[k])
        right.append(k == truth)
    probs, right = np.array(probs), np.array(right)
    out = []
    for a, b in ((0, 0.2), (0.2, 0.4), (0.4, 0.6), (0.6, 0.8), (0.8, 1.01)):
        sel = (probs >= a) & (probs < b)
        out.append(
            {
                "p": f"{a:.1f}-{min(b, 1):.1f}",
                "frames": int(sel.sum()),
                "mean_p": float(probs[sel].mean()) if sel.any() else None,
                "right": float(right[sel].mean()) if sel.any() else None,
            }
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="bundled terrains, one seed")
    ap.add_argument("--cache", type=Path, help="harvested drives are kept here (pickle) and reused")
    ap.add_argument(
        "--evalset-tuning",
        type=Path,
        metavar="PICKLE",
        help="also the evaluation set's TUNING split, ranked by bench/tracking.py --split tuning --cache",
    )
    ap.add_argument("--no-sim", action="store_true", help="without the simulated drives (with --evalset-tuning)")
    ap.add_argument("--observe", choices=OBSERVE, default="fused", help="the ranking a frame gives (module docstring)")
    ap.add_argument(
        "--scores",
        choices=SCORES,
        help="what the observed values are (models.tracking.ranking_scores): nats (the fused observation's "
        "default: the calibrated fusion's negative log posterior) or robust (standardised per frame; the "
        "associative observation's default)",
    )
    args = ap.parse_args()
    scores = args.scores or ("nats" if args.observe == "fused" else "robust")
    if args.no_sim:
        drives = []
    elif args.cache and args.cache.is_file():
        drives = pickle.loads(args.cache.read_bytes())
    else:
        drives = harvest(args.quick)
        if args.cache:
            args.cache.write_bytes(pickle.dumps(drives))
    if args.evalset_tuning is not None:
        ranked, _ = pickle.loads(args.evalset_tuning.read_bytes())
        for d, _, _ in ranked:
            d.setdefault("seed", "evalset-tuning")
            drives.append(d)
    for d in drives:
        if args.observe == "fused" and d.get("skyline") is None and "skyline_weight" not in d:
            raise SystemExit(f"drive {d['name']}: ranked without the skyline (an old cache?): rank it again")
        d["variances"] = observed(d, args.observe)
    zs, margins, truths = frame_scores(drives, scores)
    frames = arc_frames(drives)
    params = fit(frames, scores)
    top1 = float(np.mean([int(np.nanargmin(z)) == t for z, t in zip(zs, truths)]))
    out = {
        "observe": args.observe,
        "scores": scores,
        "drives": [{"name": d["name"], "seed": d["seed"], "frames": int(len(d["true_point"]))} for d in drives],
        "tuning_seeds": list(TUNING_SEEDS),
        "drive": TUNING_DRIVE,
        "frames": len(zs),
        "ranking_top1": top1,
        "fit": params,
        "histogram": histograms(zs, truths),
        "reliability": reliability(params, frames),
        "fit_outlier": fit_mixture(frames, scores),
        "point_reliability": point_reliability(zs, truths),
    }
    print(json.dumps(out, indent=1))
    print()
    print(f"{len(zs)} tuning frames, observing {args.observe}, ranking top-1 {top1:.3f}")
    print("fit: " + ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in params.items()))
    print(f"{'z':>8} {'true':>6} {'other':>7} {'log ratio':>10}")
    for h in out["histogram"]:
        lr = "" if h["log_ratio"] is None else f"{h['log_ratio']:.2f}"
        print(f"{h['z']:>8} {h['true']:>6} {h['other']:>7} {lr:>10}")
    fo = out["fit_outlier"]
    print(
        f"fit with an outlier part: temperature {fo['temperature']:.3g}, spread {fo['spread']:.3g}, "
        f"outlier {fo['outlier']:.3g}, mean log density {fo['mean_log_density']:.4g}"
    )
    print(f"{'p(point) at T 1':>16} {'points':>7} {'mean p':>7} {'truth':>6}")
    for r in out["point_reliability"]:
        mp = "" if r["mean_p"] is None else f"{r['mean_p']:.4f}"
        rt = "" if r["truth"] is None else f"{r['truth']:.4f}"
        print(f"{r['p']:>16} {r['points']:>7} {mp:>7} {rt:>6}")
    print(f"{'p(best)':>8} {'frames':>7} {'mean p':>7} {'right':>6}")
    for r in out["reliability"]:
        mp = "" if r["mean_p"] is None else f"{r['mean_p']:.2f}"
        rt = "" if r["right"] is None else f"{r['right']:.2f}"
        print(f"{r['p']:>8} {r['frames']:>7} {mp:>7} {rt:>6}")


if __name__ == "__main__":
    main()
