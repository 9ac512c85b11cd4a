"""Fit the detectors' calibration (models.scenario.DETECTOR_CALIBRATION) on the tuning split.

The sweeps of the evaluation set's *tuning* split (bench/evalset: terrains and seeds disjoint
from the held-out split; camera frames from another renderer than the viewframes', at other
sizes, with pose errors up to ±5° of heading and ±2° of pitch and roll); the questions the
scheduler would ask about them, labelled by the truth (bench/detector_pairs.py). A logistic
regression of the label on the detector's evidence (:data:`LR_FEATURES`), once over every kind
(``any``, the schema's default) and once per detector family; the training set's prior log-odds
are taken out of the bias so that the result is a log-likelihood ratio. With ``--cv`` it also
prints the per-kind ROC AUC of each grouping (``any``, ``family``, ``kind``) fitted with one
tuning case left out at a time and scored on it (the choice between groupings). Prints JSON,
then a table; the coefficients go into models/scenario.py.

    python bench/tuning/calibrate_detectors.py [--cv]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("detector_pairs", ROOT / "bench" / "detector_pairs.py")
dp = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(dp)

sys.path.append(str(ROOT))
from bench.evalset import cases  # noqa: E402
from models.detectors import ANY_KIND, KIND_FAMILY, LR_FEATURES, align_pixels, default_registry  # noqa: E402
from models.scenario import SchedulerSpec, load_scenario  # noqa: E402


def fit_logistic(x: np.ndarray, y: np.ndarray, *, l2: float = 1e-2) -> np.ndarray:
    """Logistic regression ``P(y=1) = sigmoid(b + w.x)``, a small ridge on ``w``; returns [b, w...]."""
    design = np.c_[np.ones(len(x)), x]

    def loss(w):
        z = design @ w
        return float(np.sum(np.logaddexp(0.0, z) - y * z) + l2 * np.sum(w[1:] ** 2))

    def grad(w):
        z = design @ w
        g = design.T @ (1.0 / (1.0 + np.exp(-z)) - y)
        g[1:] += 2 * l2 * w[1:]
        return g

    return minimize(loss, np.zeros(design.shape[1]), jac=grad, method="BFGS").x


GROUPINGS = {
    "any": lambda r: ANY_KIND,
    "family": lambda r: r["family"],
    "kind": lambda r: r["kind"],
}


def cross_validated(rows: list[dict]) -> dict:
    """Per grouping, the per-kind AUC of the llr fitted without the case it is scored on."""
    cases = sorted({r["case"] for r in rows})
    out = {}
    for name, key in GROUPINGS.items():
        llr = np.zeros(len(rows))
        for hold in cases:
            for group in {key(r) for r in rows}:
                train = [r for r in rows if r["case"] != hold and key(r) == group]
                test = [i for i, r in enumerate(rows) if r["case"] == hold and key(r) == group]
                if not test or len({r["label"] for r in train}) < 2:
                    continue
                w = fit_logistic(
                    np.array([[r[f] for f in LR_FEATURES] for r in train]), np.array([r["label"] for r in train], float)
                )
                llr[test] = np.c_[np.ones(len(test)), np.array([[rows[i][f] for f in LR_FEATURES] for i in test])] @ w
        out[name] = {
            k: dp.roc_auc(
                [v for v, r in zip(llr, rows) if r["kind"] == k], [r["label"] for r in rows if r["kind"] == k]
            )
            for k in sorted({r["kind"] for r in rows})
        }
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cv", action="store_true", help="also the leave-one-case-out AUC of each grouping")
    args = ap.parse_args(argv)
    spec = SchedulerSpec()
    rows, names = [], []
    for case in cases("tuning", kinds=["sweep"]):
        sc = load_scenario(case.scenario_path)
        ap = align_pixels(height=sc.camera.height, fov_y_deg=sc.camera.fov_y_deg, tolerance_deg=spec.align_deg)
        # no calibration: evidence() needs none
        reg = default_registry(
            threshold=spec.detector_threshold,
            absent_threshold=spec.absent_threshold,
            align_px=ap,
            scales=spec.detector_scales,
        )
        data = dp.case_questions(case, align_px=ap, min_pixels=spec.min_pixels, candidates=spec.candidates)
        for r in dp.evidence(data, reg):
            rows.append({**r, "case": case.name, "family": KIND_FAMILY.get(r["kind"], "outline")})
        names.append(case.name)
        print(
            f"{case.name}: {len(data['questions'])} questions, {data['ambiguous']} ambiguous",
            file=sys.stderr,
            flush=True,
        )
    out: dict = {"cases": names, "features": LR_FEATURES, "families": {}}
    for family in [ANY_KIND, *sorted({r["family"] for r in rows})]:
        rr = [r for r in rows if family in (ANY_KIND, r["family"])]
        x = np.array([[r[f] for f in LR_FEATURES] for r in rr])
        y = np.array([r["label"] for r in rr], float)
        w = fit_logistic(x, y)
        base = float(y.mean())
        w[0] -= math.log(base / (1.0 - base))  # a likelihood ratio, not the training posterior
        llr = np.c_[np.ones(len(x)), x] @ w
        out["families"][family] = {
            "calibration": [round(float(v), 4) for v in w],
            "questions": len(rr),
            "positives": int(y.sum()),
            "auc": dp.roc_auc(llr, y),
            "auc_by_kind": {
                k: dp.roc_auc(
                    [v for v, r in zip(llr, rr) if r["kind"] == k], [r["label"] for r in rr if r["kind"] == k]
                )
                for k in sorted({r["kind"] for r in rr})
            },
        }
    if args.cv:
        out["cross_validated_auc"] = cross_validated(rows)
    print(json.dumps(out, indent=1))
    print(
        "\n| family | questions | positives | bias | "
        + " | ".join(f"w_{f}" for f in LR_FEATURES)
        + " | AUC (training) |"
    )
    print("|---|---|---|---|" + "---|" * len(LR_FEATURES) + "---|")
    for fam, v in out["families"].items():
        print(
            f"| {fam} | {v['questions']} | {v['positives']} | "
            + " | ".join(str(c) for c in v["calibration"])
            + f" | {v['auc']:.3f} |"
        )
    if args.cv:
        kinds = sorted({r["kind"] for r in rows})
        print("\n| grouping (left-one-case-out) | " + " | ".join(kinds) + " |")
        print("|---|" + "---|" * len(kinds))
        for name, by_kind in out["cross_validated_auc"].items():
            print(f"| {name} | " + " | ".join(f"{by_kind[k]:.3f}" for k in kinds) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
