"""Tracking benchmark: tracked against single-frame localization, side by side in one run.

Drives: the cases of the evaluation set (bench/evalset: sweeps with a frame at every route
point, drives with stops and gaps of several route points, drives with a kidnapping; camera
frames from another renderer than the viewframes', at other sizes, with larger pose errors),
split ``heldout`` (the default: for reporting, never used to choose a parameter), ``tuning`` or
``fresh`` (kept for one final measurement: other terrains, renderer, frame sizes);
``--split tuning-drives``: more drives and kidnaps on the tuning terrains, at tuning seeds
(:func:`extra_tuning_drives`; the tuning split has one drive and two kidnaps), ``tuning-drives-more``
two more instances of each tuning terrain with both (:func:`more_tuning_drives`); or ``--split sim``:
simulated drives of the bundled terrains with bench/tracking_calibrate.py's tuning seeds (a
speed that persists, stops of several frames). Each drive's frames are ranked by the real associative memory
(bench/tracking_data.py), then

* single-frame: the observed ranking's best route point per frame (the blind decision, without
  the landmark questions);
* tracked: models.tracking.RouteFilter over the same rankings, online (and smoothed offline);

each for what the tracker observes (``--observe``, side by side in one run): ``associative``,
the memory's ranking alone with its own calibration (the tracker before it observed every
source), ``fused-robust``, every ranking source fused by the scheduler's rule
(knowledge_sources.fusion) and re-standardised per frame at the first fusion rule's calibration
(the tracker before its refit), ``fused``, the same fusion's calibrated negative log
posterior with the defaults of the scenario schema (``--set KEY=VALUE`` overrides them: the
calibration's grid on the tuning split), a verified frame re-scored by its render-and-compare
verification as the tracker observes it (when the scenario's ``verify`` is on), and
``fused-unverified``, the same without the verification.

Reported per drive and pooled: top-1 after a warm-up of 3 frames and within those 3 (a frame is
right when its route point is the one nearest the true position), how often the position is within
half a mean route spacing of the truth (``half>3``, after the warm-up: for the single frame, whose
answer is a route point, about its top-1; a track between two route points can be a few metres
from the truth and still name the other point: session 11 found the track's top-1 8-12 points
below this on the tuning drives (tuning-drives, tuning-drives-more, sim), the single frame's
within a point of it), position error median and mean of the continuous estimate, frames to
recover after a kidnapping (first frame from the jump on which the tracked route point is right
again), the tracker's cost per frame on a route of 10,000 cells, and (``--runs``) whole-run
frames/s through the blackboard with and without the tracker on one drive (``mapinterp run`` and
``--no-track``).

    python bench/tracking.py [--split heldout|tuning|fresh|tuning-drives|tuning-drives-more|sim]
                             [--observe associative fused-robust fused fused-unverified]
                             [--set temperature=1.0 ...] [--runs] [--frames FILE] [--json-only]

Prints JSON, then a table.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import os  # noqa: E402

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # BLAS on one thread: idle BLAS threads spinning skew the tracker's timing

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import pickle  # noqa: E402
import platform  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Sequence  # noqa: E402

import numpy as np  # noqa: E402

from bench.evalset import SPLITS, TUNING_SPLITS  # noqa: E402
from knowledge_sources.mission import run_mission  # noqa: E402  (before bench/ is on the path: bench/blackboard.py)
from models.scenario import TrackingSpec, load_scenario  # noqa: E402
from models.tracking import RouteFilter, smooth  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
WARM_UP = 3
sys.path.insert(0, str(ROOT / "bench"))
from tracking_data import observed, views_per_leg  # noqa: E402

sys.path.pop(0)
#: the observation model's parameters fitted for the associative ranking alone on the evaluation
#: set's tuning split (bench/tracking_calibrate.py --observe associative; BENCHMARKS.md): the
#: tracker before it observed the fused ranking, run beside the defaults (fitted to the fusion)
ASSOCIATIVE_CALIBRATION = {
    "temperature": 1.11,
    "spread": 0.45,
    "eps": 1e-4,
    "margin_scale": 0.0,
    "scores": "robust",
    "speed_persistence": 0.0,
    "outlier": 0.0,
    "evidence": "points",
}
#: what a run may observe, each with its calibration: ``associative`` (above), ``fused-robust``
#: (the fused ranking re-standardised per frame at the calibration of the first fusion rule, the
#: same numbers: the tracker before its observation was refitted to the calibrated fusion),
#: ``fused`` (the defaults)
CALIBRATIONS: dict[str, dict] = {
    "associative": ASSOCIATIVE_CALIBRATION,
    "fused-robust": dict(ASSOCIATIVE_CALIBRATION),
    "fused": {},
    "fused-unverified": {},
}


def verified(observation: str) -> bool:
    """Whether an observation of :data:`CALIBRATIONS` takes a verified frame re-scored by its
    verification (``fused``, as the tracker does; ``fused-unverified``: the fusion alone, as before
    the verification was on by default)."""
    return not observation.endswith("-unverified")


def source_of(observation: str) -> str:
    """The ranking an observation of :data:`CALIBRATIONS` reads (bench/tracking_data.observed)."""
    return observation.split("-")[0]


def parse_set(items: Sequence[str]) -> dict:
    """``KEY=VALUE`` overrides of the fused observation's tracking spec (numbers, or a word)."""
    out: dict = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or key not in TrackingSpec.model_fields:
            raise SystemExit(f"--set {item!r}: must be KEY=VALUE with KEY a field of tracking")
        try:
            out[key] = float(value)
        except ValueError:
            out[key] = value
    return out


def kidnap_frames_from_truth(true_point: np.ndarray, *, max_skip: float) -> list[int]:
    """Frames whose true route point jumped from the previous frame's by more than the motion
    model allows (backwards by more than one point, or forwards by more than ``max_skip + 1``)."""
    out = []
    for t in range(1, len(true_point)):
        d = int(true_point[t]) - int(true_point[t - 1])
        if d < -1 or d > max_skip + 1:
            out.append(t)
    return out


def track_drive(
    d: dict, spec: TrackingSpec, observations: np.ndarray, *, views_per_leg: int = 1, priors: bool = False
) -> dict:
    """Run the online filter (and the smoother) over one ranked drive observing ``observations``
    ``(T, N)`` per route point, or with ``views_per_leg`` > 1 and ``spec.evidence`` ``views``
    ``(T, V)`` per viewframe (bench/tracking_data.observed); per-frame results. ``priors``: also
    each frame's predicted mass per route point before its evidence (``prior``, ``(T, N)``; asked
    before the timed step, which then reuses the prediction: the step's cost leaves it out)."""
    f = RouteFilter(d["route"], spec=spec, views_per_leg=views_per_leg)
    n = observations.shape[1]
    if n != (len(d["route"]) if not f.observes_views else f.view_arcs.size):
        raise ValueError(f"{d['name']}: {n} observed values a frame do not fit the filter's evidence places")
    times = d["times"]
    logliks, dts, online, costs, prior = [], [], [], [], []
    for t, v in enumerate(observations):
        dt = None
        if t > 0 and np.isfinite(times[t]) and np.isfinite(times[t - 1]):
            dt = float(times[t] - times[t - 1])
        if priors:
            prior.append(f.grid.point_mass(f.prior(dt)))
        t0 = time.perf_counter()
        ll = f.route_loglik(np.arange(n), v)
        online.append(f.step(ll, dt=dt))
        costs.append((time.perf_counter() - t0) * 1e3)
        logliks.append(ll)
        dts.append(dt)
    smoothed = smooth(d["route"], logliks, spec=spec, dts=dts)
    out = {"online": online, "smoothed": smoothed, "cost_ms": costs}
    if priors:
        out["prior"] = np.array(prior)
    return out


def spacing_m(route: np.ndarray) -> float:
    """The mean distance between consecutive route points (m)."""
    r = np.asarray(route, dtype=np.float64)
    return float(np.hypot(*np.diff(r, axis=0).T).mean())


def frame_table(d: dict, obs: np.ndarray, tracked: dict) -> list[dict]:
    """One row per frame of a tracked drive (``tracked`` from :func:`track_drive` with
    ``priors``), to read why the track and the single frame differ: the true route point and the
    true move since the frame before (metres along the route, in mean route spacings: the truth's
    projection), the single frame's route point and its probability under the fused posterior at
    temperature 1 (``obs`` per route point, negative log posterior), that probability of the true
    point, the track's route point, its confidence, its prior (predicted) and posterior mass on the
    true point, and both position errors (m)."""
    route = np.asarray(d["route"], dtype=np.float64)
    legs = np.hypot(*np.diff(route, axis=0).T)
    arc_pts = np.r_[0.0, np.cumsum(legs)]
    spacing = float(legs.mean())

    def arc_of(x: float, y: float) -> float:
        a, ab = route[:-1], np.diff(route, axis=0)
        u = np.clip(((x - a[:, 0]) * ab[:, 0] + (y - a[:, 1]) * ab[:, 1]) / legs**2, 0.0, 1.0)
        px, py = a[:, 0] + u * ab[:, 0], a[:, 1] + u * ab[:, 1]
        j = int(np.argmin(np.hypot(x - px, y - py)))
        return float(arc_pts[j] + u[j] * legs[j])

    truth, tp = d["truth"], d["true_point"]
    arcs = [arc_of(float(x), float(y)) if np.isfinite(x) else math.nan for x, y, _ in truth]
    rows = []
    for t, (e, v) in enumerate(zip(tracked["online"], obs)):
        p = np.exp(-(v - np.nanmin(v)))
        p = np.nan_to_num(p) / np.nansum(p)
        k, true = int(np.nanargmin(v)), int(tp[t])
        rows.append(
            {
                "frame": t,
                "true_point": true,
                "move_spacings": None if t == 0 else (arcs[t] - arcs[t - 1]) / spacing,
                "single": k,
                "p_single": float(p[k]),
                "p_true": float(p[true]) if true >= 0 else None,
                "tracked": int(e.route_point),
                "confidence": float(e.confidence),
                "prior_true": float(tracked["prior"][t][true]) if true >= 0 else None,
                "posterior_true": float(e.belief[true]) if true >= 0 and e.belief is not None else None,
                "error_single_m": math.hypot(*(route[k] - truth[t, :2])),
                "error_tracked_m": math.hypot(e.x - truth[t, 0], e.y - truth[t, 1]),
            }
        )
    return rows


def modes(observe: Sequence[str]) -> list[str]:
    """The result modes of a run observing ``observe``: single frame, tracked, smoothed of each."""
    return [f"{m}[{o}]" for o in observe for m in ("single", "tracked", "smoothed")]


def score(d: dict, runs: dict[str, tuple[np.ndarray, dict]], spec: TrackingSpec) -> dict:
    """Per-frame scores of each observation ``o`` in ``runs`` (``o -> (observations, tracked)``):
    ``single[o]`` (the observation's best route point), ``tracked[o]``, ``smoothed[o]``; kidnap
    recoveries of the first observation's online track (``recover_frames``) and of each
    (``recover[o]``)."""
    truth, tp = d["truth"], d["true_point"]
    half = 0.5 * spacing_m(d["route"])
    out: dict = {"name": d["name"], "frames": int(len(tp))}
    kid = d["kidnaps"] if d.get("kidnaps") is not None else kidnap_frames_from_truth(tp, max_skip=spec.max_skip_points)
    out["kidnaps"] = kid
    out["recover"] = {}
    for o, (obs, tracked) in runs.items():
        for mode, ests in (("tracked", tracked["online"]), ("smoothed", tracked["smoothed"])):
            pts = np.array([e.route_point for e in ests])
            err = np.array([math.hypot(e.x - x, e.y - y) for e, (x, y, _) in zip(ests, truth)])
            out[f"{mode}[{o}]"] = {
                "right": (pts == tp).tolist(),
                "within_half": (err <= half).tolist(),
                "error_m": err.tolist(),
                "lost": [e.state == "lost" for e in ests],
                "route_point": pts.tolist(),
                "confidence": [e.confidence for e in ests],
            }
        single = np.array([int(np.nanargmin(v)) for v in obs])
        serr = [math.hypot(*(d["route"][k] - truth[t, :2])) for t, k in enumerate(single)]
        out[f"single[{o}]"] = {
            "right": (single == tp).tolist(),
            "within_half": [e <= half for e in serr],
            "error_m": serr,
            "route_point": single.tolist(),
        }
        rec = []
        for k in kid:
            right = out[f"tracked[{o}]"]["right"][k:]
            rec.append(next((i for i, r in enumerate(right) if r), None))
        out["recover"][o] = rec
        out["cost_ms"] = tracked["cost_ms"]
    out["recover_frames"] = out["recover"][next(iter(runs))]
    out["true_point"] = [int(x) for x in tp]
    return out


def pooled(results: list[dict]) -> dict:
    def frac(mode: str, sel) -> float | None:
        vals = [r for res in results for t, r in enumerate(res[mode]["right"]) if sel(res, t)]
        return float(np.mean(vals)) if vals else None

    def after(res, t):
        return t >= WARM_UP

    def within(res, t):
        return t < WARM_UP

    def after_no_kidnap(res, t):
        return t >= WARM_UP and not any(k <= t < k + 5 for k in res["kidnaps"])

    out: dict = {}
    for mode in [m for m in results[0] if m.startswith(("single[", "tracked[", "smoothed["))]:
        errs = [e for res in results for t, e in enumerate(res[mode]["error_m"]) if t >= WARM_UP]
        halves = [h for res in results for t, h in enumerate(res[mode]["within_half"]) if t >= WARM_UP]
        out[mode] = {
            "top1_after_warmup": frac(mode, after),
            "within_half_spacing_after_warmup": float(np.mean(halves)) if halves else None,
            "top1_within_warmup": frac(mode, within),
            "top1_after_warmup_outside_kidnaps": frac(mode, after_no_kidnap),
            "error_m_median": float(np.median(errs)) if errs else None,
            "error_m_mean": float(np.mean(errs)) if errs else None,
        }
    for o in results[0]["recover"]:
        rec = [r for res in results for r in res["recover"][o]]
        out[f"recover[{o}]"] = rec
        out[f"recover_max[{o}]"] = None if not rec or None in rec else int(max(rec))
    return out


def cost_10000(spec: TrackingSpec, *, repeats: int = 300) -> dict:
    """Median cost of one online step (prediction, likelihood from a ranking, update, estimate)
    on a straight route of 10,000 cells, 40 m between route points: wall time, and the CPU time of
    this thread (on a loaded machine the wall time includes waiting for a core); ``frame_cpu_ms``
    a frame of the tracker agent, the step and the next frame's prior after it (the step reuses
    the prior of the frame before when its ``dt`` is the same: ``step_cpu_ms`` alone leaves the
    prediction out). Measured for
    ``spec`` and, alternating step by step in the same run, for ``spec`` without the speed state
    (``speed_persistence`` 0: the filter before it), under ``without_speed_state``."""
    points = int(10_000 * spec.cell_m / 40.0) + 1
    route = np.c_[np.arange(points) * 40.0, np.zeros(points)]
    specs = {"with": spec, "without": spec.model_copy(update={"speed_persistence": 0.0})}
    filters = {k: RouteFilter(route, spec=sp) for k, sp in specs.items()}
    rng = np.random.default_rng(0)
    variances = [rng.random(points) for _ in range(8)]
    viewframes = np.arange(points)
    per: dict[str, dict[str, list[float]]] = {}
    for k, f in filters.items():
        f.step(f.route_loglik(viewframes, variances[0]))
        per[k] = {"step_ms": [], "predict_ms": [], "step_cpu_ms": [], "frame_cpu_ms": []}
    for i in range(repeats):
        for k, f in filters.items():
            t0, c0 = time.perf_counter(), time.thread_time()
            f.step(f.route_loglik(viewframes, variances[i % 8]), dt=None)
            per[k]["step_ms"].append((time.perf_counter() - t0) * 1e3)
            c1 = time.thread_time()
            per[k]["step_cpu_ms"].append((c1 - c0) * 1e3)
            t0 = time.perf_counter()
            f.prior(None)
            per[k]["predict_ms"].append((time.perf_counter() - t0) * 1e3)
            per[k]["frame_cpu_ms"].append((time.thread_time() - c0) * 1e3)
    f = filters["with"]
    out: dict = {"cells": f.grid.cells, "route_points": points}
    out.update({k + "_p50": float(np.median(v)) for k, v in per["with"].items()})
    out["without_speed_state"] = {k + "_p50": float(np.median(v)) for k, v in per["without"].items()}
    return out


def whole_runs(path: Path) -> dict:
    """frames/s of one drive through the blackboard with and without the tracker (same run of this script)."""
    out = {}
    for label, track in (("tracking", True), ("no_track", False)):
        res = run_mission(path, track=track)
        s = res["summary"]
        out[label] = {
            "frames_per_s": s.get("frames_per_s"),
            "top1": s.get("top1"),
            "top1_frame_only": s.get("top1_frame_only"),
            "mean_queries": s.get("mean_queries"),
        }
    return out


#: ``--split tuning-drives``: the seed offset of the tuning terrains' second instances (seeds
#: 1551-1854: tuning seeds, 1xxx, apart from the held-out 2xxx)
EXTRA_SEED_OFFSET = 450
#: ``--split tuning-drives-more``: the seed offsets of two more instances of each tuning terrain
#: (seeds 1601-1954: tuning seeds, 1xxx; session 11, issue 9: the tuning drives had too few frames
#: on which the single frame is strong, as it is on the held-out drives)
MORE_SEED_OFFSETS = (500, 550)
#: the evaluation set's kinds of case that are drives (time-ordered frames at a varying speed)
DRIVE_KINDS = ("drive", "kidnap")


def extra_tuning_drives() -> list:
    """More drives on the evaluation set's TUNING terrains (the split has one drive and two
    kidnaps): each tuning terrain's drive kinds it does not have (``<name>-x``), and each tuning
    terrain again at seed + :data:`EXTRA_SEED_OFFSET` (another terrain of its family, route and
    drive; the real-DEM crop the same) with both kinds (``<name>-s``)."""
    import dataclasses

    from bench.evalset import TERRAINS

    out = []
    for t in TERRAINS:
        if t.split != "tuning":
            continue
        out.append(
            dataclasses.replace(t, name=f"{t.name}-x", drives=tuple(k for k in DRIVE_KINDS if k not in t.drives))
        )
        out.append(dataclasses.replace(t, name=f"{t.name}-s", seed=t.seed + EXTRA_SEED_OFFSET, drives=DRIVE_KINDS))
    return out


def more_tuning_drives() -> list:
    """Still more drives on the evaluation set's TUNING terrains: each tuning terrain again at
    seed + each of :data:`MORE_SEED_OFFSETS` (``<name>-m500``, ``<name>-m550``) with both drive
    kinds (tuning seeds, 1xxx)."""
    import dataclasses

    from bench.evalset import TERRAINS

    out = []
    for t in TERRAINS:
        if t.split != "tuning":
            continue
        for off in MORE_SEED_OFFSETS:
            seed = t.seed + off
            if not 1000 <= seed < 2000:
                raise ValueError(f"{t.name}: seed {seed} is not a tuning seed (1xxx)")
            out.append(dataclasses.replace(t, name=f"{t.name}-m{off}", seed=seed, drives=DRIVE_KINDS))
    return out


def ranked_cases(
    split: str, tmp: Path, *, errors: str = "standard"
) -> tuple[list[tuple[dict, TrackingSpec, Path]], str]:
    """Ranked drives of a split (``errors``: the evaluation set's pose-error profile):
    ``(drive, tracking spec, scenario path)`` each, and a label."""
    sys.path.insert(0, str(ROOT / "bench"))
    from tracking_data import ranked_drive

    out = []
    if split == "sim":
        from tracking_calibrate import TUNING_DRIVE, TUNING_SEEDS
        from tracking_data import with_drive

        for name in ("hills", "jacksboro", "contours"):
            for seed in TUNING_SEEDS:
                sc = with_drive(
                    load_scenario(ROOT / "scenarios" / f"{name}.yaml"),
                    TUNING_DRIVE,
                    seed=seed,
                    path=tmp / f"{name}-{seed}.yaml",
                )
                d = ranked_drive(sc)
                d["kind"] = "sim-drive"
                out.append((d, sc.tracking, sc.path))
                print(f"{d['name']}: {len(d['true_point'])} frames", file=sys.stderr)
        return out, f"simulated TUNING drives (seeds {list(TUNING_SEEDS)}), not held out"
    from bench.evalset import cases

    extra = split in ("tuning-drives", "tuning-drives-more")
    chosen = (
        cases(
            "tuning",
            terrains=extra_tuning_drives() if split == "tuning-drives" else more_tuning_drives(),
            kinds=DRIVE_KINDS,
            errors=errors,
        )
        if extra
        else cases(split, errors=errors)
    )
    for case in chosen:
        sc = load_scenario(case.scenario_path)
        d = ranked_drive(sc)
        d["name"] = case.name
        d["kind"] = case.kind
        d["times"] = np.array([f.time_s for f in case.frames], float)
        d["kidnaps"] = [f.index for f in case.frames if f.event == "kidnap"]
        out.append((d, sc.tracking, case.scenario_path))
        print(f"{case.name}: {len(d['true_point'])} frames", file=sys.stderr)
    if extra:
        return out, (
            f"more drives on the evaluation set's tuning terrains, {errors} pose errors "
            "(tuning seeds; parameters may be chosen here)"
        )
    return out, f"evaluation set, split {split}, {errors} pose errors" + (
        " (held out: never used to choose a parameter)"
        if split not in TUNING_SPLITS
        else " (parameters may be chosen here)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--split",
        choices=[*SPLITS, "tuning-drives", "tuning-drives-more", "sim"],
        default="heldout",
        help="evaluation-set split, more drives on the tuning terrains (tuning-drives: extra_tuning_drives; "
        "tuning-drives-more: more_tuning_drives), "
        "or simulated tuning drives (default heldout)",
    )
    ap.add_argument("--no-times", action="store_true", help="ignore the frames' times (frame-based motion bound)")
    ap.add_argument("--runs", action="store_true", help="also whole runs through the blackboard (slow)")
    ap.add_argument("--cache", type=Path, help="keep the ranked drives here (pickle) and reuse them")
    ap.add_argument(
        "--errors", choices=["standard", "large"], default="standard", help="the evaluation set's pose-error profile"
    )
    ap.add_argument(
        "--observe",
        nargs="+",
        choices=list(CALIBRATIONS),
        default=list(CALIBRATIONS),
        help="what the tracker observes, side by side: the associative ranking alone (at its own calibration, "
        "ASSOCIATIVE_CALIBRATION: the tracker before the fusion), every source fused at the first rule's "
        "calibration (fused-robust), every source fused (the defaults)",
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a tracking parameter of the fused observation (calibration on the tuning split)",
    )
    ap.add_argument(
        "--frames",
        type=Path,
        metavar="FILE",
        help="write a table of every frame (JSON: a list of drives, each with frame_table's rows per observation: "
        "truth, single-frame answer, tracked answer, prior and posterior mass on the truth)",
    )
    ap.add_argument("--json-only", action="store_true")
    args = ap.parse_args()
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    overrides = parse_set(args.set)
    spec = TrackingSpec(**overrides)
    started = time.time()
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        if args.cache is not None and args.cache.is_file():
            ranked, what = pickle.loads(args.cache.read_bytes())
        else:
            ranked, what = ranked_cases(args.split, Path(tmp), errors=args.errors)
            if args.cache is not None:
                args.cache.write_bytes(pickle.dumps((ranked, what)))
        results = []
        tables: list[dict] = []
        for d, _, path in ranked:
            if Path(path).is_file():
                sc = load_scenario(path)  # not the cached one: the defaults may have changed since
                tracking = sc.tracking
                d["memory_weight"], d["skyline_weight"] = sc.memory.weight, sc.skyline.weight
            else:  # a simulated drive's scenario was a temporary file: today's defaults, the cached weights
                tracking = TrackingSpec()
            if args.no_times:
                d["times"] = np.full(len(d["true_point"]), np.nan)
            runs = {}
            per_leg = views_per_leg(d)
            for o in args.observe:
                obs = observed(d, source_of(o), verify=verified(o))
                sp = TrackingSpec(**{**tracking.model_dump(), **overrides, **CALIBRATIONS[o]})
                want = args.frames is not None
                if per_leg > 1 and sp.evidence == "views":  # each viewframe's evidence where it stands
                    seen = observed(d, source_of(o), point="view", verify=verified(o))
                    runs[o] = (obs, track_drive(d, sp, seen, views_per_leg=per_leg, priors=want))
                else:
                    runs[o] = (obs, track_drive(d, sp, obs, priors=want))
                if want:
                    if not tables or tables[-1]["drive"] is not d:
                        tables.append({"drive": d, "name": d["name"], "kind": d["kind"], "frames": {}})
                    tables[-1]["frames"][o] = frame_table(d, obs, runs[o][1])
            r = score(d, runs, tracking)
            r["kind"] = d["kind"]
            results.append(r)
        whole = whole_runs(ranked[0][2]) if args.runs else None
    out = {
        "data": what,
        "machine": platform.platform(),
        "load_avg_start": load,
        "load_avg_end": os.getloadavg()[0],
        "started": started,
        "times_used": not args.no_times,
        "warm_up": WARM_UP,
        "pooled": pooled(results),
        "cost_10000_cells": cost_10000(spec),
        "whole_runs": whole,
        "observe": list(args.observe),
        "calibrations": CALIBRATIONS,
        "overrides": overrides,
        "drives": [
            {
                "name": r["name"],
                "frames": r["frames"],
                "kidnaps": r["kidnaps"],
                "recover": r["recover"],
                **{m: v for m, v in pooled([r]).items() if not m.startswith("recover")},
            }
            for r in results
        ],
    }
    out["pooled_by_kind"] = {
        k: pooled([r for r in results if r["kind"] == k]) for k in sorted({r["kind"] for r in results})
    }
    if args.frames is not None:
        drives = [{k: v for k, v in t.items() if k != "drive"} for t in tables]  # in run order (names may repeat)
        args.frames.write_text(json.dumps({"data": what, "overrides": overrides, "drives": drives}, indent=1))
    print(json.dumps(out, indent=1))
    if args.json_only:
        return
    print()
    print(
        f"data: {what}; {sum(r['frames'] for r in results)} frames in {len(results)} drives; "
        f"load {load:.1f} -> {out['load_avg_end']:.1f}"
    )

    def pct(x):
        return "" if x is None else f"{100 * x:.1f}%"

    def m(x):
        return "" if x is None else f"{x:.1f}"

    print(
        f"{'drive':<22} {'mode':<23} {'top1>3':>7} {'top1<3':>7} {'half>3':>7} {'med m':>6} {'mean m':>7} {'recover':>8}"
    )
    by_kind = out["pooled_by_kind"]
    rows = [*out["drives"], *({"name": f"ALL {k}", **v} for k, v in by_kind.items()), {"name": "ALL", **out["pooled"]}]
    for r in rows:
        for mode in modes(args.observe):
            p = r[mode]
            if p["top1_after_warmup"] is None and p["top1_within_warmup"] is None:
                continue
            o = mode[mode.index("[") + 1 : -1]
            recs = r["recover"][o] if "recover" in r else r[f"recover[{o}]"]
            rec = ",".join("-" if x is None else str(x) for x in recs) if mode.startswith("tracked") else ""
            print(
                f"{r['name'][:22]:<22} {mode:<23} {pct(p['top1_after_warmup']):>7} {pct(p['top1_within_warmup']):>7} "
                f"{pct(p['within_half_spacing_after_warmup']):>7} {m(p['error_m_median']):>6} {m(p['error_m_mean']):>7} "
                f"{rec:>8}"
            )
    c = out["cost_10000_cells"]
    for label, cc in (("", c), (" (without the speed state)", c["without_speed_state"])):
        print(
            f"tracker cost{label}, {c['cells']} cells: step p50 {cc['step_ms_p50']:.3f} ms wall, "
            f"{cc['step_cpu_ms_p50']:.3f} ms CPU; prediction p50 {cc['predict_ms_p50']:.3f} ms; "
            f"a frame (step and the next prior) p50 {cc['frame_cpu_ms_p50']:.3f} ms CPU"
        )
    if whole:
        for k, v in whole.items():
            print(
                f"whole run ({k}): {v['frames_per_s']:.1f} frames/s, top-1 {pct(v['top1'])}, "
                f"frame-only {pct(v['top1_frame_only'])}"
            )


if __name__ == "__main__":
    main()
