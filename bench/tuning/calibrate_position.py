"""Fit the position evidence's spreads (models.scenario.SchedulerSpec.position_spread) on the tuning split.

The sweeps of the evaluation set's *tuning* split only (bench/evalset; camera frames from another
renderer than the viewframes', pose errors up to ±30% of the route spacing along, ±4 m across,
±5° heading, ±2° pitch and roll), the questions the scheduler would ask about them, labelled by
the truth (bench/detector_pairs.py). For every question whose landmark is truly there (label 1)
and that the calibrated detector answers with ``llr > 0`` (the answers that give position
evidence, knowledge_sources/scene_analysis.py), the place the detector found
(``Detection.where`` as a placement, models.placement) is compared with the prediction of the
frame's *true* viewframe (its nearest route point) for the same landmark, carried into the
camera frame by the skyline's turn and tilt against that viewframe (models.skyline, as the
scheduler does with the skyline agent's ``shifts``). The spreads are the robust scales
``1.4826 * median |residual|`` (about zero: a bias counts against the model) of the elevation,
azimuth and log size ratio. Prints JSON, then a table; the spreads go into models/scenario.py.

    python bench/tuning/calibrate_position.py
"""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("detector_pairs", ROOT / "bench" / "detector_pairs.py")
dp = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(dp)

sys.path.append(str(ROOT))
from bench.evalset import cases  # noqa: E402
from models.detectors import CandidateView, align_pixels, default_registry  # noqa: E402
from models.placement import found_placement, placement  # noqa: E402
from models.scenario import load_scenario  # noqa: E402
from models.skyline import match_skylines, skyline_from_image  # noqa: E402


def residuals(case) -> list[dict]:
    """The residuals of one tuning case (module docstring)."""
    sc = load_scenario(case.scenario_path)
    s = sc.scheduler
    fov = sc.camera.fov_y_deg
    align = align_pixels(height=sc.camera.height, fov_y_deg=fov, tolerance_deg=s.align_deg)
    reg = default_registry(
        threshold=s.detector_threshold, absent_threshold=s.absent_threshold, calibration=s.calibration, align_px=align
    )
    data = dp.case_questions(case, align_px=align, min_pixels=s.min_pixels, candidates=s.candidates)
    vfs = data["viewframes"]
    skylines = np.stack([v.skyline for v in vfs])
    match = sc.skyline.match_options()
    turns: dict[int, tuple[float, float]] = {}
    out = []
    for q in data["questions"]:
        if q["label"] != 1:
            continue
        fi, li = q["frame"], q["index"]
        truth = data["truth"][fi]
        mt = vfs[truth].mask == li
        if int(mt.sum()) < s.min_pixels:
            continue  # the true viewframe does not show it: no prediction to compare with
        image = data["frames"][fi]["image"]
        vf = vfs[q["viewframe"]]
        view = CandidateView.from_mask(vf.image, vf.mask, li, background=vf.background)
        d = reg.for_kind(q["kind"]).detect(image, view=view)
        if d.where is None or d.llr is None or d.llr <= 0:
            continue
        if fi not in turns:  # the camera's turn and tilt against the frame's true viewframe
            m = match_skylines(
                skyline_from_image(image, fov_y_deg=fov, step_deg=match["step_deg"]), skylines[[truth]], **match
            )
            turns[fi] = (float(m.heading_deg[0]), float(m.pitch_deg[0]))
        heading, pitch = turns[fi]
        obs = found_placement(d.where, pixels=int(view.silhouette.sum()), shape=image.shape, fov_y_deg=fov)
        rows, cols = np.nonzero(mt)
        pred = placement(rows.mean(), cols.mean(), len(rows), shape=mt.shape, fov_y_deg=fov)
        out.append(
            {
                "case": case.name,
                "kind": q["kind"],
                "elevation": obs[0] - (pred[0] - pitch),
                "azimuth": obs[1] - (pred[1] + heading),
                "log_size": math.log(obs[2] / pred[2]),
                "azimuth_without_turn": obs[1] - pred[1],
            }
        )
    return out


def main() -> int:
    rows: list[dict] = []
    names = []
    for case in cases("tuning", kinds=["sweep"]):
        rows += residuals(case)
        names.append(case.name)
    keys = ("elevation", "azimuth", "log_size", "azimuth_without_turn")
    spread = {k: float(1.4826 * np.median(np.abs([r[k] for r in rows]))) for k in keys}
    median = {k: float(np.median([r[k] for r in rows])) for k in keys}
    result = {"split": "tuning", "cases": names, "answers": len(rows), "spread": spread, "median": median}
    print(json.dumps(result, indent=1))
    print(f"\n{len(rows)} present answers (llr > 0) on the tuning split: {', '.join(names)}\n")
    print("| residual | robust spread (1.4826 median abs) | median |")
    print("|---|---|---|")
    for k in keys:
        print(f"| {k} | {spread[k]:.3f} | {median[k]:+.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
