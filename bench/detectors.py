"""Landmark detector ROC on held-out frames: python bench/detectors.py [--split heldout|fresh|confirm|...] [--names ...]

The sweeps of the evaluation set's held-out split (bench/evalset: terrains and seeds never used
to choose a parameter; the calibration was fitted on the tuning split), camera frames from
another renderer than the viewframes', at other sizes, with pose errors up to ±5° of heading and
±2° of pitch and roll; the questions the scheduler would ask (the landmarks of its candidate
viewframes), labelled by the truth (bench/detector_pairs.py). For each landmark
kind: the area under the ROC curve of the calibrated log-likelihood ratio (``llr``), of the edge
score alone (``score``, what the first version thresholded) and of the with/without colour
statistic alone, plus how well calibrated the ratio is (mean predicted vs observed positive
rate by llr bin). Prints JSON, then a table.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("detector_pairs", ROOT / "bench" / "detector_pairs.py")
dp = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(dp)

sys.path.append(str(ROOT))
from bench.evalset import SPLITS, cases, one_view_a_point  # noqa: E402
from models.detectors import CandidateView, align_pixels, default_registry  # noqa: E402
from models.scenario import load_scenario  # noqa: E402

GOAL = 0.97


def registry_for(scenario):
    s = scenario.scheduler
    ap = align_pixels(height=scenario.camera.height, fov_y_deg=scenario.camera.fov_y_deg, tolerance_deg=s.align_deg)
    return default_registry(
        threshold=s.detector_threshold, absent_threshold=s.absent_threshold, calibration=s.calibration, align_px=ap
    ), ap


def answers(data: dict, registry) -> list[dict]:
    """Every question of ``data`` answered by the calibrated detector."""
    out = []
    for q in data["questions"]:
        vf = data["viewframes"][q["viewframe"]]
        view = CandidateView.from_mask(vf.image, vf.mask, q["index"], background=vf.background)
        d = registry.for_kind(q["kind"]).detect(data["frames"][q["frame"]]["image"], view=view)
        if d.llr is None:
            continue
        out.append({**q, "llr": d.llr, "score": d.score, "statistic": d.statistic, "present": d.present})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="heldout", choices=SPLITS)
    ap.add_argument("--names", nargs="*", help="cases or terrains of the split (default: all)")
    ap.add_argument("--kinds", nargs="*", default=["sweep"], help="case kinds (default: sweep)")
    args = ap.parse_args(argv)
    rows, ambiguous, started, names = [], 0, time.perf_counter(), []
    for case in cases(args.split, names=args.names, kinds=args.kinds):
        sc = one_view_a_point(load_scenario(case.scenario_path))
        reg, align = registry_for(sc)
        data = dp.case_questions(
            case, align_px=align, min_pixels=sc.scheduler.min_pixels, candidates=sc.scheduler.candidates
        )
        ambiguous += data["ambiguous"]
        rows += [{**r, "case": case.name} for r in answers(data, reg)]
        names.append(case.name)
    kinds = sorted({r["kind"] for r in rows})
    result = {
        "split": args.split,
        "cases": names,
        "goal_auc": GOAL,
        "ambiguous_left_out": ambiguous,
        "elapsed_s": round(time.perf_counter() - started, 1),
        "kinds": {},
    }
    for kind in kinds:
        rr = [r for r in rows if r["kind"] == kind]
        y = [r["label"] for r in rr]
        llr = np.array([r["llr"] for r in rr])
        # calibration check: with a 50/50 prior, P = sigmoid(llr); compare to the observed rate
        # after reweighting the classes to 50/50
        pos, neg = max(1, sum(y)), max(1, len(y) - sum(y))
        bins = []
        for lo, hi in ((-99, -2), (-2, 0), (0, 2), (2, 99)):
            sel = [(v, t) for v, t in zip(llr, y) if lo <= v < hi]
            if sel:
                wp = sum(1 / pos for _, t in sel if t == 1)
                wn = sum(1 / neg for _, t in sel if t == 0)
                bins.append(
                    {
                        "llr": [lo, hi],
                        "n": len(sel),
                        "predicted": round(float(np.mean([1 / (1 + math.exp(-v)) for v, _ in sel])), 3),
                        "observed": round(wp / (wp + wn), 3),
                    }
                )
        result["kinds"][kind] = {
            "questions": len(rr),
            "positives": int(sum(y)),
            "auc_llr": dp.roc_auc(llr, y),
            "auc_score": dp.roc_auc([r["score"] for r in rr], y),
            "auc_statistic": dp.roc_auc([r["statistic"] for r in rr], y),
            "hard_answers": {
                "present_right": sum(1 for r in rr if r["present"] is True and r["label"] == 1),
                "present_wrong": sum(1 for r in rr if r["present"] is True and r["label"] == 0),
                "absent_right": sum(1 for r in rr if r["present"] is False and r["label"] == 0),
                "absent_wrong": sum(1 for r in rr if r["present"] is False and r["label"] == 1),
                "undecided": sum(1 for r in rr if r["present"] is None),
            },
            "calibration_bins": bins,
        }
    print(json.dumps(result, indent=1))
    print(f"\n{args.split} split: {', '.join(names)}; {ambiguous} ambiguous questions left out; goal AUC >= {GOAL}\n")
    print("| kind | questions | positives | AUC llr | AUC edge score | AUC colour statistic | goal |")
    print("|---|---|---|---|---|---|---|")
    for kind, v in result["kinds"].items():
        f = lambda a: "-" if a is None else f"{a:.3f}"  # noqa: E731
        ok = v["auc_llr"] is not None and v["auc_llr"] >= GOAL
        print(
            f"| {kind} | {v['questions']} | {v['positives']} | {f(v['auc_llr'])} | {f(v['auc_score'])} | "
            f"{f(v['auc_statistic'])} | {'met' if ok else 'missed'} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
