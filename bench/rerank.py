"""Render-and-compare verification of the fused ranking's first K viewframes (issue 10), offline.

For every camera frame of the split (``tuning`` by default: choose there; ``--extra`` adds
bench/tracking.py's extra tuning drives), the frame is ranked as the mission's agents rank it
(:func:`bench.pose_ablation.rank_frame`: the associative memory, the skyline and their fusion at
the scenario's weights), and the fused ranking's first ``K`` viewframes are verified as the
verifier agent verifies them (:func:`models.verify.verify_candidates` with the scenario's memory
and skyline settings and the verification's rolls: each candidate aligned by the memory's shift
search and by the skyline, rendered turned so, and scored by the camera image's memory-pattern
correlation ``c`` with the better-matching view). Per candidate: its fused score ``F`` (nats),
``c``, its route point.

Then, offline: the key ``F + w (max_j c_j - c_k)`` re-ranks the first K (on frames whose fused
margin, the second route point's F minus the first's, is below a threshold), ``w`` from a
conditional logit of the truth's route point among the K candidates over every profile's frames
(the likelihood calibrated on the frames, as the fusion's weights are, ``bench/fusion_sweep.py``;
the default of :class:`models.scenario.VerifySpec`). The table gives, per profile, K and margin,
the fused top-1 before, the oracle ceiling (truth among the K), top-1 after, the frames fixed
(first wrong, re-ranked first right) and broken (first right, re-ranked first wrong), and the
CPU per candidate.

    python bench/rerank.py [--split tuning] [--errors standard large] [--extra] [--k 8]
        [--ks '[3, 5, 8]'] [--margins '[1e9, 2.0, 1.0]'] [--names ...] [--kinds ...]
        [--features-out F.json] [--features-in F.json] [--json-only]

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


def verify_frame(image: np.ndarray, terrain: Terrain, scenario, viewframes: list[int]) -> tuple[list[float], float]:
    """The verifier's correlations of the camera ``image`` (H, W, 3) with each of ``viewframes``
    (:func:`models.verify.verify_candidates` as :class:`knowledge_sources.verifier.Verifier`
    calls it) and the milliseconds it took."""
    from models.skyline import skyline_from_image
    from models.verify import verify_viewframes

    t0 = time.perf_counter()
    q = skyline_from_image(image, fov_y_deg=scenario.camera.fov_y_deg, step_deg=scenario.skyline.step_deg)
    r = verify_viewframes(
        image,
        terrain.emulator,
        [terrain.viewframes[vf] for vf in viewframes],
        scenario,
        pattern=terrain.index.pattern,
        query_skyline=q,
    )
    return list(r.correlations), 1e3 * (time.perf_counter() - t0)


def _cases(split: str, profile: str, *, names, kinds, extra: bool):
    yield from cases(split, kinds=kinds, names=names, errors=profile)
    if extra:
        from bench.tracking import extra_tuning_drives

        for t in extra_tuning_drives():  # a terrain again with its other kinds ("-x": its sweep is the split's own)
            only = [k for k in (kinds or ("sweep", *t.drives)) if k != "sweep" or not t.name.endswith("-x")]
            if only:
                yield from cases(split, kinds=only, names=names, errors=profile, terrains=[t])


def collect(
    split: str,
    profiles: list[str],
    *,
    k: int,
    names: list[str] | None = None,
    kinds: list[str] | None = None,
    extra: bool = False,
) -> list[dict[str, Any]]:
    """Per frame: the fused ranking's first ``k`` viewframes, their F, route point and correlation."""
    from bench.pose_ablation import _scenario, rank_frame
    from models.sensor import load_frame_image

    if extra and split != "tuning":
        raise ValueError("extra: only the tuning split has more cases (bench/tracking.py's extra tuning drives)")
    terrains: dict[str, Terrain] = {}
    records: list[dict[str, Any]] = []
    try:
        for profile in profiles:
            for case in _cases(split, profile, names=names, kinds=kinds, extra=extra):
                sc = _scenario(case, None, None)
                if case.terrain not in terrains:
                    terrains[case.terrain] = Terrain(sc)
                ter = terrains[case.terrain]
                t0 = time.perf_counter()
                for fr in case.frames:
                    image = load_frame_image(
                        fr.image, width=sc.camera.width, height=sc.camera.height, fov_y_deg=sc.camera.fov_y_deg
                    )
                    t1 = time.perf_counter()
                    fused = rank_frame(ter, sc, image)["rankings"]["fused"][:k]
                    rank_ms = 1e3 * (time.perf_counter() - t1)
                    corr, verify_ms = verify_frame(image, ter, sc, [int(vf) for vf, _ in fused])
                    records.append(
                        {
                            "profile": profile,
                            "case": case.name,
                            "terrain": case.terrain,
                            "truth": int(fr.route_index),
                            "rank_ms": rank_ms,
                            "verify_ms": verify_ms,
                            "candidates": [
                                {"viewframe": int(vf), "point": int(ter.points[vf]), "F": float(f), "c": float(c)}
                                for (vf, f), c in zip(fused, corr)
                            ],
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


def _margin(rec: dict[str, Any]) -> float:
    """The fused margin: F of the second route point (its best viewframe) minus the first's."""
    first = rec["candidates"][0]
    other = next((c for c in rec["candidates"] if c["point"] != first["point"]), None)
    return math.inf if other is None else float(other["F"] - first["F"])


def choose(rec: dict[str, Any], w: float | None, *, k: int, margin: float = math.inf) -> int:
    """The route point chosen among the first ``k`` viewframes by ``F + w (max c - c)`` (``w``
    None: the fused first; inf: the correlation alone), re-ranked only when the fused margin is
    below ``margin`` (the scheduler's rule)."""
    cands = rec["candidates"][:k]
    if w is None or len(cands) < 2 or _margin(rec) >= margin:
        return int(cands[0]["point"])
    top = max(c["c"] for c in cands)
    if math.isinf(w):
        return int(max(cands, key=lambda c: c["c"])["point"])
    return int(min(cands, key=lambda c: c["F"] + w * (top - c["c"]))["point"])


def evaluate(records: list[dict[str, Any]], w: float | None, *, k: int, margin: float = math.inf) -> dict[str, Any]:
    """Top-1 before and after, oracle, fixed and broken frames of one rule."""
    n = len(records)
    before = np.array([r["candidates"][0]["point"] == r["truth"] for r in records])
    oracle = np.array([any(c["point"] == r["truth"] for c in r["candidates"][:k]) for r in records])
    after = np.array([choose(r, w, k=k, margin=margin) == r["truth"] for r in records])
    fixable = ~before & oracle
    return {
        "frames": n,
        "top1_before": float(before.mean()) if n else None,
        "oracle": float(oracle.mean()) if n else None,
        "top1_after": float(after.mean()) if n else None,
        "fixable": int(fixable.sum()),
        "fixed": int((fixable & after).sum()),
        "right": int(before.sum()),
        "broken": int((before & ~after).sum()),
        "reranked_share": float(np.mean([_margin(r) < margin for r in records])) if n else None,
    }


def fit_weight(records: list[dict[str, Any]], *, k: int) -> tuple[float, float, float]:
    """The conditional logit of the truth's route point among the first ``k`` viewframes, key
    ``a F - b c`` (lower: more likely; every viewframe of the truth's point counts as the truth):
    ``(a, b, b / a)``, the last the verification's ``weight`` (nats of F per unit of correlation)."""
    from scipy.optimize import minimize

    rows = []
    for r in records:
        cands = r["candidates"][:k]
        ok = np.array([c["point"] == r["truth"] for c in cands])
        if ok.any() and not ok.all():
            rows.append((np.array([[c["F"], -c["c"]] for c in cands]), ok))
    if not rows:
        return 1.0, 0.0, 0.0

    def nll(theta: np.ndarray) -> tuple[float, np.ndarray]:
        total, grad = 0.0, np.zeros_like(theta)
        for x, ok in rows:
            z = -(x @ theta)
            z -= z.max()
            p = np.exp(z)
            p /= p.sum()
            pt = p[ok].sum()
            total -= float(np.log(max(pt, 1e-300)))
            # d(-log sum_ok p)/dtheta = E_ok[x] - E[x]
            grad += (p[ok] / pt) @ x[ok] - p @ x
        return total, grad

    a, b = np.asarray(minimize(nll, np.array([1.0, 10.0]), jac=True, method="L-BFGS-B").x)
    return float(a), float(b), float(b / a) if a > 0 else math.inf


def analyse(records: list[dict[str, Any]], ks: list[int], margins: list[float]) -> dict[str, Any]:
    """Every K and margin on every profile: the fused first, the correlation alone, and the key
    with the weight fitted on all profiles' frames together."""
    out: dict[str, Any] = {"profiles": {}, "weights": {}}
    profiles = sorted({r["profile"] for r in records})
    kmax = max(len(r["candidates"]) for r in records)
    for k in [k for k in ks if k <= kmax]:
        a, b, w = fit_weight(records, k=k)
        out["weights"][str(k)] = {"a_F": a, "b_c": b, "weight": w}
        for prof in profiles:
            recs = [r for r in records if r["profile"] == prof]
            per = out["profiles"].setdefault(prof, {}).setdefault(str(k), {})
            per["fused"] = evaluate(recs, None, k=k)
            per["c alone"] = evaluate(recs, math.inf, k=k)
            for m in margins:
                per[f"F+{w:.3g}*dc" + ("" if math.isinf(m) else f" |margin<{m:g}")] = evaluate(recs, w, k=k, margin=m)
    out["cost"] = {
        "rank_ms": float(np.mean([r["rank_ms"] for r in records])),
        "verify_ms_per_candidate": float(np.mean([r["verify_ms"] / len(r["candidates"]) for r in records])),
    }
    return out


def table(res: dict[str, Any]) -> str:
    lines = []
    for k, wt in res["weights"].items():
        lines.append(f"K = {k}: logit a_F {wt['a_F']:.3f}, b_c {wt['b_c']:.2f}: weight {wt['weight']:.2f}")
    for prof, ks in res["profiles"].items():
        for k, rules in ks.items():
            lines.append(f"\n{prof} errors, K = {k}")
            lines.append(
                f"{'rule':28s} {'frames':>6s} {'before':>6s} {'oracle':>6s} {'after':>6s} "
                f"{'fixed':>9s} {'broken':>9s} {'rerank':>6s}"
            )
            for rule, m in rules.items():
                lines.append(
                    f"{rule:28s} {m['frames']:6d} {m['top1_before']:6.3f} {m['oracle']:6.3f} {m['top1_after']:6.3f} "
                    f"{m['fixed']:4d}/{m['fixable']:<4d} {m['broken']:4d}/{m['right']:<4d} {m['reranked_share']:6.2f}"
                )
    c = res["cost"]
    lines.append(
        f"\ncost: ranking {c['rank_ms']:.1f} ms/frame; verification {c['verify_ms_per_candidate']:.1f} ms/candidate"
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
    ap.add_argument("--extra", action="store_true", help="with bench/tracking.py's extra tuning drives")
    ap.add_argument("--k", type=int, default=8, help="viewframes verified (the first K of the fused ranking)")
    ap.add_argument("--ks", type=json.loads, default=[3, 5, 8], help="K values analysed (<= --k)")
    ap.add_argument("--margins", type=json.loads, default=[1e9, 2.0, 1.0], help="posterior margins (nats)")
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
            names=args.names,
            kinds=args.kinds,
            extra=args.extra,
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
