"""Render-and-compare verification of the fused ranking's first K candidates (issue 10), offline.

For every camera frame of the split (``tuning`` by default: choose there), the frame is ranked as
the mission's agents rank it (:func:`bench.pose_ablation.rank_frame`: the associative memory, the
skyline and their fusion at the scenario's weights), and the fused ranking's first ``K`` route
points (each by its best viewframe, the scene analysis's candidates) are each compared with the
camera image by the pose refiner's score (:mod:`models.refine`: skyline error in degrees after
the best heading/pitch shift, plus ``edge_weight`` times one minus the edge correlation), at
three depths of refinement:

* ``s0``: the candidate's own viewframe (image and depth as rendered for the map, no render),
  heading and pitch from the skyline shift: the refiner with ``position: false``;
* ``s1``: a view rendered at that heading and pitch (``recheck``: one render);
* ``sp``: a small position search around the candidate (one level of a ``grid`` x ``grid``
  pattern over ``+-along`` of the route spacing and ``+-across_m``, at the heading and pitch of
  ``s1``: ``grid**2 - 1`` renders), its best view's score and components; ``sp_point`` the route
  point nearest the best position.

Each score is kept with its two parts (``sky``: degrees; ``ncc``: edge correlation). Then,
offline on those features, every rule re-ranks the K candidates and the table gives fused top-1
before, the oracle ceiling (truth among the K), top-1 after, the frames fixed (first wrong, truth
among the K, re-ranked first right) and broken (first right, re-ranked first wrong), and the
CPU per frame of the features. A combined rule ``F + w * score`` (``F`` the fused ranking's
score, nats) takes ``w`` from a conditional logit of the truth among the K candidates (the
likelihood calibrated on the frames, as the fusion's weights are, ``bench/fusion_sweep.py``),
optionally only on frames whose posterior margin (``F`` of the second candidate minus the
first's) is below a threshold.

    python bench/rerank.py [--split tuning] [--errors standard large] [--k 5] [--grid 3]
        [--names ...] [--kinds ...] [--features-out F.json] [--features-in F.json] [--json-only]

``--features-in``: analyse features saved by ``--features-out`` (no rendering). Prints JSON, then a table.

    python bench/rerank.py --compare BEFORE.out AFTER.out

``--compare``: two outputs of ``bench/single_frame.py`` (its JSON, then its table) of the same
split and errors, frame by frame: per terrain the frames the second run fixed (wrong in the first,
right in the second) and broke (right in the first, wrong in the second).
"""

from __future__ import annotations

import sys
from pathlib import Path

_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import os  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402

from bench.evalset import ERROR_PROFILES, cases  # noqa: E402

#: the refiner's scores compared (the features of each candidate)
DEPTHS = ("s0", "s1", "sp")


class Terrain:
    """One terrain's viewframes (rendered once, kept open for their depths), index, skyline
    references and the camera emulator of its map."""

    def __init__(self, scenario) -> None:
        from models.index import ViewframeIndex
        from models.route_views import route_points_of
        from models.world import World

        self.world = World(scenario)
        vfs = self.world.viewframes
        self.viewframes = vfs
        self.index = ViewframeIndex(scenario.memory, seed=0)
        self.index.add((v.image for v in vfs), [v.index for v in vfs])
        self.refs = np.stack([v.skyline for v in vfs]).astype(np.float32)
        self.emulator = self.world.emulator
        on = route_points_of(scenario)
        self.points = np.arange(len(vfs)) if on is None else np.asarray(on, dtype=np.int64)

    def close(self) -> None:
        self.world.close()


def _parts(scorer: Any) -> tuple[float, float]:
    """The refiner's scorer's last score in its parts (skyline error, 99 for none; edge correlation)."""
    sky, ncc = scorer.parts
    return (sky if math.isfinite(sky) else 99.0, ncc)


def candidate_features(
    image: np.ndarray,
    terrain: Terrain,
    scenario,
    viewframe: int,
    *,
    query_skyline: np.ndarray,
    camera_pattern: np.ndarray,
    spacing_m: float,
    grid: int,
    along: float,
    across_m: float,
) -> dict[str, Any]:
    """The refiner's scores of one candidate ``viewframe`` against the camera ``image`` (module docstring)."""
    from models.camera_emulator import View
    from models.refine import _Scorer
    from models.route_views import view_route
    from models.scenario import RefineSpec
    from models.verify import pattern_correlation

    spec, sky = RefineSpec(), scenario.skyline
    sc = _Scorer(
        image,
        terrain.emulator,
        step_deg=sky.step_deg,
        max_heading_deg=sky.max_heading_deg,
        max_pitch_deg=sky.max_pitch_deg,
        truncate_deg=sky.truncate_deg,
        max_roll_deg=spec.max_roll_deg,
        edge_weight=spec.edge_weight,
        query_skyline=query_skyline,
    )
    v = terrain.viewframes[viewframe]
    start = terrain.emulator.pose_at(v.pose.x, v.pose.y, v.pose.heading_deg, pitch_deg=v.pose.pitch_deg)
    out: dict[str, Any] = {"viewframe": int(viewframe), "point": int(terrain.points[viewframe])}
    t0 = time.perf_counter()
    view = View(image=np.asarray(v.image), depth=np.asarray(v.depth), mask=np.asarray(v.mask), pose=start)
    s0, h, p, _ = sc.score(start.x, start.y, start.heading_deg, start.pitch_deg, view=view)
    out["s0"], (out["s0_sky"], out["s0_ncc"]) = float(s0), _parts(sc)
    shift = tuple(int(m) for m in scenario.memory.max_shift)
    out["s0_mem"] = pattern_correlation(camera_pattern, terrain.index.pattern(sc.view.image), max_shift=shift)
    out["s0_ms"] = 1e3 * (time.perf_counter() - t0)
    s1, h, p, _ = sc.score(start.x, start.y, h, p, max_heading=2 * sky.step_deg)
    out["s1"], (out["s1_sky"], out["s1_ncc"]) = float(s1), _parts(sc)
    out["s1_mem"] = pattern_correlation(camera_pattern, terrain.index.pattern(sc.view.image), max_shift=(2, 2))
    out["s1_ms"] = 1e3 * (time.perf_counter() - t0)
    th = math.radians(start.heading_deg)
    fwd, side = np.array([math.cos(th), math.sin(th)]), np.array([math.sin(th), -math.cos(th)])
    best = (float(s1), _parts(sc), (start.x, start.y))
    mems = [out["s1_mem"]]
    ticks = np.linspace(-1.0, 1.0, grid)
    for a in ticks:
        for c in ticks:
            if a == 0 and c == 0:
                continue
            x, y = np.array([start.x, start.y]) + a * along * spacing_m * fwd + c * across_m * side
            got = sc.score(float(x), float(y), h, p, max_heading=4 * sky.step_deg)
            mems.append(pattern_correlation(camera_pattern, terrain.index.pattern(sc.view.image), max_shift=(2, 2)))
            if got[0] < best[0]:
                best = (float(got[0]), _parts(sc), (float(x), float(y)))
    out["sp"], (out["sp_sky"], out["sp_ncc"]) = best[0], best[1]
    out["sp_xy"] = list(best[2])
    out["sp_mem"] = float(max(mems))  # the best memory correlation over the pattern's views
    route = view_route(np.asarray(scenario.route, dtype=np.float64), 1)[0]
    out["sp_point"] = int(np.argmin(np.hypot(route[:, 0] - best[2][0], route[:, 1] - best[2][1])))
    out["sp_ms"] = 1e3 * (time.perf_counter() - t0)
    out["renders"] = sc.renders
    return out


def collect(
    split: str,
    profiles: list[str],
    *,
    k: int,
    grid: int,
    along: float,
    across_m: float,
    names: list[str] | None = None,
    kinds: list[str] | None = None,
) -> list[dict[str, Any]]:
    """Per frame: the fused ranking's first ``k`` candidates and their features."""
    from bench.pose_ablation import _scenario, rank_frame
    from models.route_views import first_per_point
    from models.sensor import load_frame_image
    from models.skyline import skyline_from_image

    terrains: dict[str, Terrain] = {}
    records: list[dict[str, Any]] = []
    try:
        for profile in profiles:
            for case in cases(split, kinds=kinds, names=names, errors=profile):
                sc = _scenario(case, None, None)
                if case.terrain not in terrains:
                    terrains[case.terrain] = Terrain(sc)
                ter = terrains[case.terrain]
                t0 = time.perf_counter()
                for fr in case.frames:
                    image = load_frame_image(fr.image, width=sc.camera.width, height=sc.camera.height)
                    t1 = time.perf_counter()
                    r = rank_frame(ter, sc, image)
                    rank_ms = 1e3 * (time.perf_counter() - t1)
                    fused = first_per_point(r["rankings"]["fused"], ter.points)
                    q = skyline_from_image(image, fov_y_deg=sc.camera.fov_y_deg, step_deg=sc.skyline.step_deg)
                    cands = []
                    pattern = ter.index.pattern(image)
                    for vf, f in fused[:k]:
                        feats = candidate_features(
                            image,
                            ter,
                            sc,
                            vf,
                            query_skyline=q,
                            camera_pattern=pattern,
                            spacing_m=case.spacing_m,
                            grid=grid,
                            along=along,
                            across_m=across_m,
                        )
                        cands.append({"F": float(f), **feats})
                    records.append(
                        {
                            "profile": profile,
                            "case": case.name,
                            "terrain": case.terrain,
                            "truth": int(fr.route_index),
                            "rank_ms": rank_ms,
                            "candidates": cands,
                        }
                    )
                print(
                    f"# {profile} {case.name}: {len(case.frames)} frames, {time.perf_counter() - t0:.1f} s",
                    file=sys.stderr,
                    flush=True,
                )
    finally:
        for t in terrains.values():
            t.close()
    return records


# -- analysis ---------------------------------------------------------------------------------


def _score(c: dict[str, Any], feature: str, w: float) -> float:
    """The re-ranking key of a candidate (lower is better): ``F + w * feature`` (``w`` inf: the feature alone)."""
    if feature.endswith("_ncc") or feature.endswith("_mem"):
        val = -float(c[feature])
    else:
        val = float(c[feature])
    return val if math.isinf(w) else float(c["F"]) + w * val


def choose(
    rec: dict[str, Any], feature: str | None, w: float, *, k: int, margin: float = math.inf, answer: str = "point"
) -> int:
    """The route point chosen among the first ``k`` candidates (``feature`` None: the fused first);
    re-ranked only when the fused margin (second's F minus first's) is below ``margin``.
    ``answer``: ``point``, the chosen candidate's route point; ``sp_point``, the route point
    nearest its refined position."""
    cands = rec["candidates"][:k]
    if feature is None or len(cands) < 2 or cands[1]["F"] - cands[0]["F"] >= margin:
        return int(cands[0][answer])
    return int(min(cands, key=lambda c: _score(c, feature, w))[answer])


def evaluate(
    records: list[dict[str, Any]],
    feature: str | None,
    w: float,
    *,
    k: int,
    margin: float = math.inf,
    answer: str = "point",
) -> dict[str, Any]:
    """Top-1 before and after, oracle, fixed and broken frames of one rule."""
    n = len(records)
    before = np.array([r["candidates"][0]["point"] == r["truth"] for r in records])
    oracle = np.array([any(c["point"] == r["truth"] for c in r["candidates"][:k]) for r in records])
    after = np.array([choose(r, feature, w, k=k, margin=margin, answer=answer) == r["truth"] for r in records])
    fixable = ~before & oracle
    reranked = np.array(
        [len(r["candidates"]) > 1 and r["candidates"][1]["F"] - r["candidates"][0]["F"] < margin for r in records]
    )
    return {
        "frames": n,
        "top1_before": float(before.mean()) if n else None,
        "oracle": float(oracle.mean()) if n else None,
        "top1_after": float(after.mean()) if n else None,
        "fixable": int(fixable.sum()),
        "fixed": int((fixable & after).sum()),
        "fixed_share": float((fixable & after).sum() / fixable.sum()) if fixable.sum() else None,
        "right": int(before.sum()),
        "broken": int((before & ~after).sum()),
        "broken_share": float((before & ~after).sum() / before.sum()) if before.sum() else None,
        "reranked_share": float(reranked.mean()) if n else None,
    }


def fit_weight(records: list[dict[str, Any]], feature: str, *, k: int) -> float:
    """``w`` of ``F + w * feature`` maximising the likelihood of the truth among the first ``k``
    candidates (a conditional logit over the frames whose truth is among them; a grid search)."""
    rows = [
        (
            np.array([c["F"] for c in r["candidates"][:k]]),
            np.array([_score(c, feature, math.inf) for c in r["candidates"][:k]]),
            [c["point"] for c in r["candidates"][:k]].index(r["truth"]),
        )
        for r in records
        if any(c["point"] == r["truth"] for c in r["candidates"][:k])
    ]
    best_w, best_ll = 0.0, -math.inf
    for w in np.concatenate([[0.0], np.geomspace(0.05, 200.0, 60)]):
        ll = 0.0
        for f, s, t in rows:
            z = -(f + w * s)
            z -= z.max()
            ll += float(z[t] - math.log(np.exp(z).sum()))
        if ll > best_ll:
            best_w, best_ll = float(w), ll
    return best_w


def _design(records: list[dict[str, Any]], features: tuple[str, ...], *, k: int):
    """Per frame with its truth among the first ``k``: (matrix (k', 1 + len(features)) of F and
    the features as re-ranking keys, the truth's row)."""
    rows = []
    for r in records:
        cands = r["candidates"][:k]
        pts = [c["point"] for c in cands]
        if r["truth"] in pts and len(cands) > 1:
            x = np.array([[c["F"], *(_score(c, f, math.inf) for f in features)] for c in cands])
            rows.append((x, pts.index(r["truth"])))
    return rows


def fit_logit(records: list[dict[str, Any]], features: tuple[str, ...], *, k: int) -> np.ndarray:
    """Coefficients ``(a_F, w_1, ...)`` of the key ``a_F F + sum_i w_i x_i`` (lower: more likely)
    maximising the likelihood of the truth among the first ``k`` candidates (a conditional
    logit, lightly ridge-regularised), over the frames whose truth is among them."""
    from scipy.optimize import minimize

    rows = _design(records, features, k=k)
    if not rows:
        return np.zeros(1 + len(features))

    def nll(theta: np.ndarray) -> tuple[float, np.ndarray]:
        total, grad = 0.0, np.zeros_like(theta)
        for x, t in rows:
            z = -(x @ theta)
            z -= z.max()
            p = np.exp(z)
            p /= p.sum()
            total -= float(np.log(max(p[t], 1e-300)))
            grad += x[t] - p @ x
        return total + 1e-3 * float(theta @ theta), grad + 2e-3 * theta

    theta0 = np.zeros(1 + len(features))
    theta0[0] = 1.0
    return np.asarray(minimize(nll, theta0, jac=True, method="L-BFGS-B").x)


def choose_logit(rec: dict[str, Any], features: tuple[str, ...], theta: np.ndarray, *, k: int, margin: float) -> int:
    """The route point of the lowest key ``theta . (F, features)`` among the first ``k`` (see :func:`choose`)."""
    cands = rec["candidates"][:k]
    if len(cands) < 2 or cands[1]["F"] - cands[0]["F"] >= margin:
        return int(cands[0]["point"])
    keys = [float(np.dot(theta, [c["F"], *(_score(c, f, math.inf) for f in features)])) for c in cands]
    return int(cands[int(np.argmin(keys))]["point"])


def evaluate_logit(
    records: list[dict[str, Any]],
    features: tuple[str, ...],
    *,
    k: int,
    margin: float,
    held_out_terrain: bool,
    pool: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """:func:`evaluate`'s numbers for the fitted logit key; ``held_out_terrain``: each terrain's
    frames chosen with the coefficients fitted on the other terrains' (leave one terrain out) of
    ``pool`` (default ``records``; e.g. every profile's frames)."""
    pool = records if pool is None else pool
    picks: dict[int, int] = {}
    terrains = sorted({r["terrain"] for r in records})
    groups = [[r for r in records if r["terrain"] == t] for t in terrains] if held_out_terrain else [records]
    for g in groups:
        fit_on = [r for r in pool if r["terrain"] != g[0]["terrain"]] if held_out_terrain else pool
        theta = fit_logit(fit_on, features, k=k)
        for r in g:
            picks[id(r)] = choose_logit(r, features, theta, k=k, margin=margin)
    before = np.array([r["candidates"][0]["point"] == r["truth"] for r in records])
    oracle = np.array([any(c["point"] == r["truth"] for c in r["candidates"][:k]) for r in records])
    after = np.array([picks[id(r)] == r["truth"] for r in records])
    fixable = ~before & oracle
    return {
        "frames": len(records),
        "top1_before": float(before.mean()),
        "oracle": float(oracle.mean()),
        "top1_after": float(after.mean()),
        "fixable": int(fixable.sum()),
        "fixed": int((fixable & after).sum()),
        "right": int(before.sum()),
        "broken": int((before & ~after).sum()),
        "reranked_share": float(
            np.mean(
                [
                    len(r["candidates"]) > 1 and r["candidates"][1]["F"] - r["candidates"][0]["F"] < margin
                    for r in records
                ]
            )
        ),
    }


#: feature sets of the fitted logit keys
COMBOS: tuple[tuple[str, ...], ...] = (
    ("s0_mem",),
    ("s1_mem",),
    ("s0_mem", "s1_mem"),
    ("s1_mem", "s1_sky", "s1_ncc"),
    ("s0_mem", "s1_mem", "sp_mem", "s1_sky", "sp_sky"),
    ("s0_mem", "s0_sky", "s0_ncc"),
)

FEATURES = tuple(f"{d}{p}" for d in DEPTHS for p in ("", "_sky", "_ncc", "_mem"))


def analyse(records: list[dict[str, Any]], ks: list[int], margins: list[float]) -> dict[str, Any]:
    """Every rule on every profile: the feature alone, ``F + w * feature`` with the fitted ``w``
    (fitted on all profiles' frames together), at each K and margin."""
    out: dict[str, Any] = {"profiles": {}, "weights": {}}
    profiles = sorted({r["profile"] for r in records})
    kmax = max(len(r["candidates"]) for r in records)
    for k in [k for k in ks if k <= kmax]:
        weights = {f: fit_weight(records, f, k=k) for f in FEATURES}
        out["weights"][str(k)] = weights
        for prof in profiles:
            recs = [r for r in records if r["profile"] == prof]
            per = out["profiles"].setdefault(prof, {}).setdefault(str(k), {})
            per["fused"] = evaluate(recs, None, 0.0, k=k)
            per["fused, refined position"] = evaluate(recs, None, 0.0, k=k, answer="sp_point")
            per["sp alone, refined position"] = evaluate(recs, "sp", math.inf, k=k, answer="sp_point")
            per[f"F+{weights['sp']:.3g}*sp, refined position"] = evaluate(
                recs, "sp", weights["sp"], k=k, answer="sp_point"
            )
            for f in FEATURES:
                per[f"{f} alone"] = evaluate(recs, f, math.inf, k=k)
                for m in margins:
                    tag = f"F+{weights[f]:.3g}*{f}" + ("" if math.isinf(m) else f" |margin<{m:g}")
                    per[tag] = evaluate(recs, f, weights[f], k=k, margin=m)
    for k in [k for k in ks if k <= kmax]:
        for combo in COMBOS:
            theta = fit_logit(records, combo, k=k)
            out["weights"].setdefault(f"{k} logit", {})["+".join(combo)] = theta.tolist()
            for prof in profiles:
                recs = [r for r in records if r["profile"] == prof]
                per = out["profiles"][prof][str(k)]
                for m in margins:
                    tag = "logit " + "+".join(combo) + ("" if math.isinf(m) else f" |margin<{m:g}")
                    chosen = [choose_logit(r, combo, theta, k=k, margin=m) for r in recs]
                    ev = evaluate_logit(recs, combo, k=k, margin=m, held_out_terrain=False)
                    ev["top1_after"] = float(np.mean([c == r["truth"] for c, r in zip(chosen, recs)]))
                    per[tag] = ev
                    per[tag + " (LOTO)"] = evaluate_logit(
                        recs, combo, k=k, margin=m, held_out_terrain=True, pool=records
                    )
    cost = {}
    for d in DEPTHS:
        cost[f"{d}_ms_per_candidate"] = float(np.mean([c[f"{d}_ms"] for r in records for c in r["candidates"]]))
    cost["rank_ms"] = float(np.mean([r["rank_ms"] for r in records]))
    out["cost"] = cost
    return out


def per_terrain(records: list[dict[str, Any]], feature: str, w: float, *, k: int, margin: float) -> dict[str, Any]:
    """One rule's numbers per profile and terrain."""
    out: dict[str, Any] = {}
    for prof in sorted({r["profile"] for r in records}):
        for t in sorted({r["terrain"] for r in records if r["profile"] == prof}):
            recs = [r for r in records if r["profile"] == prof and r["terrain"] == t]
            out.setdefault(prof, {})[t] = evaluate(recs, feature, w, k=k, margin=margin)
    return out


def table(res: dict[str, Any]) -> str:
    lines = []
    for prof, ks in res["profiles"].items():
        for k, rules in ks.items():
            lines.append(f"\n{prof} errors, K = {k}")
            lines.append(
                f"{'rule':34s} {'frames':>6s} {'before':>6s} {'oracle':>6s} {'after':>6s} "
                f"{'fixed':>9s} {'broken':>9s} {'rerank':>6s}"
            )
            for rule, m in rules.items():
                lines.append(
                    f"{rule:34s} {m['frames']:6d} {m['top1_before']:6.3f} {m['oracle']:6.3f} {m['top1_after']:6.3f} "
                    f"{m['fixed']:4d}/{m['fixable']:<4d} {m['broken']:4d}/{m['right']:<4d} {m['reranked_share']:6.2f}"
                )
    c = res["cost"]
    lines.append(
        "\ncost: ranking {:.1f} ms/frame; per candidate s0 {:.1f} ms, s1 {:.1f} ms, sp {:.1f} ms (cumulative)".format(
            c["rank_ms"], c["s0_ms_per_candidate"], c["s1_ms_per_candidate"], c["sp_ms_per_candidate"]
        )
    )
    return "\n".join(lines)


def _single_frame_json(path: Path) -> dict[str, Any]:
    """The JSON document at the start of a ``bench/single_frame.py`` output (the table after it ignored)."""
    text = path.read_text()
    doc, _ = json.JSONDecoder().raw_decode(text.lstrip())
    return doc


def compare(before: dict[str, Any], after: dict[str, Any]) -> dict[str, Any]:
    """Per terrain and overall: frames, top-1 before and after, fixed and broken (see the docstring)."""
    out: dict[str, Any] = {}
    for name, case in before["cases"].items():
        other = after["cases"].get(name)
        if other is None or "correct" not in case or "correct" not in other:
            raise ValueError(f"case {name}: not in both runs, or a run without per-frame results")
        terrain = name.split("/")[0]
        row = out.setdefault(terrain, {"frames": 0, "before": 0, "after": 0, "fixed": 0, "broken": 0})
        for a, b in zip(case["correct"], other["correct"]):
            if a is None or b is None:
                continue
            row["frames"] += 1
            row["before"] += int(a)
            row["after"] += int(b)
            row["fixed"] += int(b and not a)
            row["broken"] += int(a and not b)
    total = {k: sum(r[k] for r in out.values()) for k in ("frames", "before", "after", "fixed", "broken")}
    out["all"] = total
    return out


def compare_table(res: dict[str, Any]) -> str:
    lines = [f"{'terrain':16s} {'frames':>6s} {'before':>6s} {'after':>6s} {'fixed':>9s} {'broken':>9s}"]
    for t, r in res.items():
        n = max(r["frames"], 1)
        lines.append(
            f"{t:16s} {r['frames']:6d} {r['before'] / n:6.3f} {r['after'] / n:6.3f} "
            f"{r['fixed']:4d}/{r['frames'] - r['before']:<4d} {r['broken']:4d}/{r['before']:<4d}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="tuning", choices=("tuning", "heldout"))
    ap.add_argument("--errors", nargs="*", default=["standard", "large"], choices=sorted(ERROR_PROFILES))
    ap.add_argument("--k", type=int, default=5, help="candidates compared (features of the first K)")
    ap.add_argument("--ks", type=json.loads, default=[2, 3, 5], help="K values analysed (<= --k)")
    ap.add_argument("--margins", type=json.loads, default=[1e9, 1.0, 0.5], help="posterior margins (nats)")
    ap.add_argument("--grid", type=int, default=3, help="position pattern grid x grid (sp)")
    ap.add_argument("--along", type=float, default=0.4, help="position pattern: +- this share of the spacing")
    ap.add_argument("--across-m", type=float, default=4.0, help="position pattern: +- metres across")
    ap.add_argument("--names", nargs="*", default=None)
    ap.add_argument("--kinds", nargs="*", default=None)
    ap.add_argument("--features-out", type=Path, default=None)
    ap.add_argument("--features-in", type=Path, default=None)
    ap.add_argument("--compare", nargs=2, type=Path, default=None, metavar=("BEFORE", "AFTER"))
    ap.add_argument("--json-only", action="store_true")
    args = ap.parse_args(argv)
    if args.compare is not None:
        try:
            res = compare(*(_single_frame_json(p) for p in args.compare))
        except (OSError, ValueError, KeyError) as exc:
            print(f"error: --compare {args.compare[0]} {args.compare[1]}: {exc}", file=sys.stderr)
            return 2
        print(json.dumps(res, indent=1))
        if not args.json_only:
            print(f"\n{args.compare[0]} -> {args.compare[1]}")
            print(compare_table(res))
        return 0
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else None
    utc = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())
    t0 = time.time()
    if args.features_in is not None:
        try:
            records = json.loads(args.features_in.read_text())["records"]
        except (OSError, ValueError, KeyError) as exc:
            print(f"error: {args.features_in}: not a features file of bench/rerank.py ({exc})", file=sys.stderr)
            return 2
    else:
        records = collect(
            args.split,
            args.errors,
            k=args.k,
            grid=args.grid,
            along=args.along,
            across_m=args.across_m,
            names=args.names,
            kinds=args.kinds,
        )
        if args.features_out is not None:
            args.features_out.write_text(
                json.dumps(
                    {
                        "records": records,
                        "options": vars(args) | {"features_out": str(args.features_out), "features_in": None},
                    }
                )
            )
    margins = [math.inf if m >= 1e9 else float(m) for m in args.margins]
    res = analyse(records, args.ks, margins)
    res["machine"] = {"load_at_start": load, "utc_start": utc, "wall_s": time.time() - t0}
    print(json.dumps(res, indent=1))
    if not args.json_only:
        print(f"\nsplit {args.split}, load {load}, {utc} UTC")
        print(table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
