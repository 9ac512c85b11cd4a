"""Does verification pay? python bench/verification.py [--split heldout] [--names ...] [--kinds ...]

The goal of issue 10: of the frames where the ranking's first is wrong but the truth is among the
scheduler's candidates, the scheduler fixes at least half, and it breaks fewer than 2% of the
frames the ranking had right. The evaluation set's held-out cases (bench/evalset: camera frames
from another renderer, other sizes, pose errors up to ±5° of heading, ±2° of pitch and roll),
the real associative
ranking, the real detectors (calibrated) and the real scene-analysis rule
(knowledge_sources/scene_analysis.py), for each rule side by side on the same frames and the
same detector answers: the seed paper's (``hard`` backtracking, questions by P(L|A)), and
``soft`` backtracking with questions by information gain or by P(L|A), each with the position
evidence (the default: where the detector found the landmark against where each candidate puts
it, knowledge_sources/scene_analysis.py) and without it (presence only); and, as ceilings, the
default rule answered by a perfect detector (reading the truth labels of
bench/detector_pairs.py, for evaluation only; with position evidence, the landmark's place
in the mask rendered at the frame's true pose). The camera's turn against each viewframe
comes from the skyline's alignment (models.skyline.match_skylines, the skyline agent's
``shifts``), as in a mission. A frame is
right when the decided viewframe is the route point nearest the true position (the results'
criterion). Prints JSON, then a table.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "bench" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


dp = _load("detector_pairs")
bench_detectors = _load("detectors")

from bench.evalset import one_view_a_point  # noqa: E402
from knowledge_sources.scene_analysis import SceneAnalysis  # noqa: E402
from models.detectors import CandidateView  # noqa: E402
from models.placement import found_placement, placement  # noqa: E402
from models.scenario import load_scenario  # noqa: E402
from models.skyline import match_skylines, skyline_from_image  # noqa: E402

DEFAULT = "soft, information gain, position (default)"
RULES = {
    "seed (hard, P(L|A))": {"backtracking": "hard", "questions": "probability"},
    "soft, information gain, presence only": {
        "backtracking": "soft",
        "questions": "information",
        "position_evidence": False,
    },
    DEFAULT: {"backtracking": "soft", "questions": "information", "position_evidence": True},
    "soft, P(L|A), presence only": {"backtracking": "soft", "questions": "probability", "position_evidence": False},
    "soft, P(L|A), position": {"backtracking": "soft", "questions": "probability", "position_evidence": True},
}
#: the ceilings: the default rule with a detector that reads the truth labels (evaluation only),
#: without and with the landmark's true place in the frame
ORACLE = "perfect detector, presence only (ceiling)"
ORACLE_POSITION = "perfect detector, position (ceiling)"


def _placements(data: dict, fov_y_deg: float, min_pixels: int) -> dict[int, dict[str, tuple[float, float, float]]]:
    """Where each viewframe shows each landmark of at least ``min_pixels`` (models.placement)."""
    lms = data["landmarks"]
    out: dict[int, dict[str, tuple[float, float, float]]] = {}
    for vf in data["viewframes"]:
        here = {}
        for li in np.unique(vf.mask[vf.mask >= 0]):
            rows, cols = np.nonzero(vf.mask == li)
            if len(rows) >= min_pixels:
                here[lms[int(li)].id] = placement(
                    rows.mean(), cols.mean(), len(rows), shape=vf.mask.shape, fov_y_deg=fov_y_deg
                )
        out[vf.index] = here
    return out


def _analysis(ranking, visible, s, rule: dict, **extra) -> SceneAnalysis:
    """The scene analysis of one frame under ``rule``, with the scheduler settings ``s``."""
    return SceneAnalysis(
        ranking,
        visible,
        strategy="associative",
        candidates=s.candidates,
        accept=s.accept,
        reliability=s.reliability,
        beta=s.beta,
        floor=s.floor,
        max_llr=s.max_llr,
        neighbour_visibility=s.neighbour_visibility,
        position_spread=s.position_spread,
        position_dof=s.position_dof,
        max_position_llr=s.max_position_llr,
        **rule,
        **extra,
    )


def run_rules(data: dict, scenario, registry) -> list[dict]:
    """Each frame's outcome under every rule of :data:`RULES`."""
    s = scenario.scheduler
    lms = data["landmarks"]
    visible = {}
    for vf in data["viewframes"]:
        counts = np.bincount(vf.mask[vf.mask >= 0].ravel(), minlength=len(lms))
        visible[vf.index] = frozenset(lms[i].id for i in np.nonzero(counts >= s.min_pixels)[0])
    index = {lm.id: i for i, lm in enumerate(lms)}
    labels = {(q["frame"], q["landmark"], q["viewframe"]): q["label"] for q in data["questions"]}
    fov = scenario.camera.fov_y_deg
    placements = _placements(data, fov, s.min_pixels)
    skylines = np.stack([vf.skyline for vf in data["viewframes"]])
    match = scenario.skyline.match_options()
    cache: dict[tuple[int, str, int], tuple] = {}
    out = []
    for fi, rk in enumerate(data["rankings"]):
        ranking = [(int(k), float(v)) for k, v in zip(rk.viewframes, rk.variances)]
        truth = data["truth"][fi]
        image = data["frames"][fi]["image"]
        cand = [k for k, _ in ranking[: s.candidates]]
        m = match_skylines(
            skyline_from_image(image, fov_y_deg=fov, step_deg=match["step_deg"]), skylines[cand], **match
        )
        turns = {k: (float(m.heading_deg[i]), float(m.pitch_deg[i])) for i, k in enumerate(cand)}
        rec = {
            "frame": fi,
            "truth": truth,
            "ranking_first": ranking[0][0],
            "in_candidates": truth in cand,
            "landmarks_differ": visible[ranking[0][0]] != visible[truth],
            "truth_no_landmark": not visible[truth],
            "share_landmark": bool(visible[ranking[0][0]] & visible[truth]),
        }
        extra = {"placements": placements, "turns": turns}
        for name, rule in RULES.items():
            sa = _analysis(ranking, visible, s, rule, **extra)
            while (q := sa.next_question()) is not None:
                key = (fi, q.landmark, q.viewframe)
                if key not in cache:
                    vf = data["viewframes"][q.viewframe]
                    view = CandidateView.from_mask(vf.image, vf.mask, index[q.landmark], background=vf.background)
                    det = registry.for_kind(lms[index[q.landmark]].kind)
                    d = det.detect(image, view=view)
                    where = None
                    if d.where is not None:
                        px = int(view.silhouette.sum())
                        where = found_placement(d.where, pixels=px, shape=image.shape, fov_y_deg=fov)
                    cache[key] = (d, where)
                d, where = cache[key]
                sa.answer(q, d.present, score=d.score, llr=d.llr, where=where)
            rec[name] = {"viewframe": sa.decision.viewframe, "queries": sa.decision.queries}
        for name, position in ((ORACLE, False), (ORACLE_POSITION, True)):
            sa = _analysis(ranking, visible, s, {**RULES[DEFAULT], "position_evidence": position}, **extra)
            while (q := sa.next_question()) is not None:
                label = labels.get((fi, q.landmark, q.viewframe))
                where = None
                if label:
                    rows, cols = np.nonzero(data["frames"][fi]["mask"] == index[q.landmark])
                    if len(rows):
                        where = placement(rows.mean(), cols.mean(), len(rows), shape=image.shape, fov_y_deg=fov)
                sa.answer(
                    q,
                    None if label is None else bool(label),
                    llr=None if label is None else (s.max_llr if label else -s.max_llr),
                    where=where,
                )
            rec[name] = {"viewframe": sa.decision.viewframe, "queries": sa.decision.queries}
        out.append(rec)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="heldout", choices=["heldout", "tuning"])
    ap.add_argument("--names", nargs="*", help="cases or terrains of the split (default: all)")
    ap.add_argument("--kinds", nargs="*", default=["sweep"], help="case kinds (default: sweep)")
    args = ap.parse_args(argv)
    started = time.perf_counter()
    frames = []
    for case in bench_detectors.cases(args.split, names=args.names, kinds=args.kinds):
        sc = one_view_a_point(load_scenario(case.scenario_path))
        reg, align = bench_detectors.registry_for(sc)
        data = dp.case_questions(
            case, align_px=align, min_pixels=sc.scheduler.min_pixels, candidates=sc.scheduler.candidates
        )
        frames += [{**r, "scenario": case.name} for r in run_rules(data, sc, reg)]
    ranking_right = [f for f in frames if f["ranking_first"] == f["truth"]]
    fixable = [f for f in frames if f["ranking_first"] != f["truth"] and f["in_candidates"]]
    result = {
        "split": args.split,
        "scenarios": sorted({f["scenario"] for f in frames}),
        "frames": len(frames),
        "ranking_top1": len(ranking_right) / len(frames),
        "ranking_right": len(ranking_right),
        "fixable": len(fixable),
        "fixable_landmarks_differ": sum(f["landmarks_differ"] for f in fixable),
        "fixable_truth_no_landmark": sum(f["truth_no_landmark"] for f in fixable),
        "fixable_share_landmark": sum(f["share_landmark"] for f in fixable),
        "elapsed_s": round(time.perf_counter() - started, 1),
        "rules": {},
    }
    for name in [*RULES, ORACLE, ORACLE_POSITION]:
        fixed = sum(f[name]["viewframe"] == f["truth"] for f in fixable)
        broken = sum(f[name]["viewframe"] != f["truth"] for f in ranking_right)
        result["rules"][name] = {
            "top1": sum(f[name]["viewframe"] == f["truth"] for f in frames) / len(frames),
            "fixed": fixed,
            "fixed_fraction": fixed / len(fixable) if fixable else None,
            "broken": broken,
            "broken_fraction": broken / len(ranking_right) if ranking_right else None,
            "queries_per_frame": float(np.mean([f[name]["queries"] for f in frames])),
            "by_scenario": {
                s: sum(f[name]["viewframe"] == f["truth"] for f in frames if f["scenario"] == s)
                / max(1, sum(f["scenario"] == s for f in frames))
                for s in result["scenarios"]
            },
        }
    print(json.dumps(result, indent=1))
    print(
        f"\n{len(frames)} frames ({args.split} split); ranking top-1 {result['ranking_top1']:.3f}; "
        f"{len(fixable)} frames with the ranking's first wrong and the truth among the candidates; "
        f"{len(ranking_right)} with the ranking right. Goal: fix >= 50%, break < 2%. In "
        f"{result['fixable_landmarks_differ']} of the {len(fixable)} the ranking's first and the truth differ in "
        f"their landmarks (of at least min_pixels); in {result['fixable_share_landmark']} they share one (the "
        f"position evidence's frames); in {result['fixable_truth_no_landmark']} the truth shows none.\n"
    )
    print("| rule | top-1 | fixed | broken | queries/frame | goal |")
    print("|---|---|---|---|---|---|")
    for name, v in result["rules"].items():
        ff = v["fixed_fraction"] or 0.0
        bf = v["broken_fraction"] or 0.0
        ok = ff >= 0.5 and bf < 0.02
        print(
            f"| {name} | {v['top1']:.3f} | {v['fixed']}/{len(fixable)} ({ff:.0%}) | "
            f"{v['broken']}/{len(ranking_right)} ({bf:.1%}) | {v['queries_per_frame']:.2f} | "
            f"{'met' if ok else 'missed'} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
