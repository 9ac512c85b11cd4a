"""Single-frame benchmark (issue 10): every camera frame of the evaluation set localized alone.

Each case of :mod:`bench.evalset` (held-out by default; ``--split fresh``: the split kept for one
final measurement) runs through the real pipeline,
:func:`knowledge_sources.mission.run_mission` (all agents on the blackboard, in one process), with
the scenario's defaults unless ``--memory``/``--scheduler``/``--skyline``/``--render``/``--refine``/``--verify`` override blocks of it,
and without the tracker (every frame decided alone; ``--track``: with it, as a mission runs by
default, so that ``top1`` is the track's). Per terrain and
over all frames it reports:

* ``top1``: the final answer is the route point nearest the truth (the results' criterion),
* ``rank_top1`` / ``rank_top5``: the ranking the scene analysis starts from (the fusion of every
  ranking source) has the truth first / among its first five,
* ``err_mean`` / ``err_median``: metres between the answer's position and the true one,
* ``frames``, ``fps`` (frames / localization seconds, of the whole run).

Prints JSON, then a table. Columns are entries of :data:`COLUMNS` (name, format, function of a
list of frame records): add one there (e.g. a ranking source's own top-1 once results carry it).

    python bench/single_frame.py [--split heldout|tuning|fresh] [--names h-mesas ...] [--kinds sweep]
        [--memory '{"bank_size": 1}'] [--scheduler '{...}'] [--skyline '{...}'] [--render '{...}']
        [--refine '{"recheck": false}'] [--verify '{"enabled": true}'] [--track] [--errors standard|large]
        [--extraction-rounds 3] [--seed-trim-rounds 0] [--sky-field quadratic] [--json-only]

``--errors large``: the evaluation set's larger pose errors (:data:`bench.evalset.ERROR_PROFILES`).
"""

from __future__ import annotations

import sys
from pathlib import Path

# bench/blackboard.py would shadow the blackboard package: drop this folder, add the repository root
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from bench.evalset import ERROR_PROFILES, SPLITS, cases  # noqa: E402
from bench.horizon import add_sky_model_options, fixed_rounds, sky_model  # noqa: E402
from knowledge_sources.mission import run_mission  # noqa: E402

Frame = dict[str, Any]


def _share(frames: Sequence[Frame], test: Callable[[Frame], bool]) -> float | None:
    judged = [f for f in frames if f.get("truth_viewframe") is not None]
    return (sum(bool(test(f)) for f in judged) / len(judged)) if judged else None


def _errors(frames: Sequence[Frame]) -> list[float]:
    return [f["error_m"] if f.get("error_m") is not None else math.inf for f in frames if f.get("truth")]


def _headings(frames: Sequence[Frame]) -> list[float]:
    """Degrees between each frame's single-frame heading (``frame_only`` when tracking) and its true one."""
    out = []
    for f in frames:
        heading = (f.get("frame_only") or f).get("heading_deg")
        if f.get("truth") is not None and heading is not None:
            out.append(abs((float(heading) - float(f["truth"][2]) + 180.0) % 360.0 - 180.0))
    return out


def _median(values: Sequence[float]) -> float | None:
    return float(np.median(values)) if values else None


def _in_ranking(f: Frame, k: int) -> bool:
    return f["truth_viewframe"] in [int(r[0]) for r in (f.get("ranking") or [])[:k]]


#: (column, format, value of a list of frame records); None prints as "-"
COLUMNS: list[tuple[str, str, Callable[[Sequence[Frame]], float | None]]] = [
    ("frames", "{:d}", len),
    ("top1", "{:.3f}", lambda fr: _share(fr, lambda f: f["correct"])),
    ("rank_top1", "{:.3f}", lambda fr: _share(fr, lambda f: _in_ranking(f, 1))),
    ("rank_top5", "{:.3f}", lambda fr: _share(fr, lambda f: _in_ranking(f, 5))),
    ("err_mean", "{:.1f}", lambda fr: float(np.mean(_errors(fr))) if fr else None),
    ("err_median", "{:.1f}", lambda fr: float(np.median(_errors(fr))) if fr else None),
    # the single-frame decision's heading (the refiner's, when it refined the frame): degrees off the truth
    ("head_mean", "{:.2f}", lambda fr: float(np.mean(_headings(fr))) if _headings(fr) else None),
    ("head_median", "{:.2f}", lambda fr: _median(_headings(fr))),
    ("head_p90", "{:.2f}", lambda fr: float(np.percentile(_headings(fr), 90)) if _headings(fr) else None),
    # the final answer's heading (the track's, turned as the frame was, when tracking): degrees off the truth
    (
        "final_head_median",
        "{:.2f}",
        lambda fr: _median([f["heading_error_deg"] for f in fr if f.get("heading_error_deg") is not None]),
    ),
]


def measure(frames: Sequence[Frame]) -> dict[str, Any]:
    """Every column of :data:`COLUMNS` over ``frames``."""
    return {name: fn(frames) for name, _, fn in COLUMNS}


def run(
    split: str,
    *,
    names: Sequence[str] | None = None,
    kinds: Sequence[str] | None = None,
    blocks: dict[str, Any] | None = None,
    track: bool = False,
    errors: str = "standard",
) -> dict[str, Any]:
    """Run every selected case; returns per-case results, per-terrain and overall measures.
    ``track``: with the tracker (the mission's default); off, every frame is decided alone."""
    per_case, by_terrain, everything = {}, {}, []
    for case in cases(split, names=names, kinds=kinds, errors=errors):
        path = case.write_scenario(**blocks) if blocks else case.scenario_path
        t0 = time.perf_counter()
        res = run_mission(path, track=track)
        wall = time.perf_counter() - t0
        frames = res["frames"]
        for f, truth in zip(frames, case.frames):
            f["case"], f["event"], f["size"] = case.name, truth.event, list(truth.size)
        per_case[case.name] = {
            **measure(frames),
            "fps": res["summary"]["frames_per_s"],
            "wall_s": wall,
            "description": case.description,
            # each frame's final answer right (null: no truth), to compare two runs frame by frame
            "correct": [bool(f["correct"]) if f.get("truth_viewframe") is not None else None for f in frames],
        }
        by_terrain.setdefault(case.terrain, []).extend(frames)
        everything.extend(frames)
    terrains = {t: measure(fr) for t, fr in by_terrain.items()}
    return {
        "split": split,
        "blocks": blocks or {},
        "track": track,
        "errors": errors,
        "cases": per_case,
        "terrains": terrains,
        "all": measure(everything),
    }


def table(result: dict[str, Any]) -> str:
    """The per-terrain table (and the overall row) as text."""
    head = ["terrain"] + [c for c, _, _ in COLUMNS]
    rows = [[t] + [_fmt(m[c], f) for c, f, _ in COLUMNS] for t, m in result["terrains"].items()]
    rows.append(["all"] + [_fmt(result["all"][c], f) for c, f, _ in COLUMNS])
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(len(head))]
    lines = [
        "  ".join(str(c).rjust(w) if i else str(c).ljust(w) for i, (c, w) in enumerate(zip(r, widths)))
        for r in [head, *rows]
    ]
    return "\n".join(lines)


def _fmt(value: Any, fmt: str) -> str:
    if value is None:
        return "-"
    if isinstance(value, float) and math.isinf(value):
        return "inf"
    return fmt.format(value)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=SPLITS, default="heldout")
    parser.add_argument("--names", nargs="*", default=None, help="cases or terrains (default all)")
    parser.add_argument("--kinds", nargs="*", default=None, help="sweep, drive, kidnap (default all)")
    parser.add_argument("--memory", type=json.loads, default=None, help="JSON memory block replacing the default")
    parser.add_argument("--scheduler", type=json.loads, default=None, help="JSON scheduler block")
    parser.add_argument("--track", action="store_true", help="with the tracker (default: every frame decided alone)")
    parser.add_argument("--skyline", type=json.loads, default=None, help="JSON skyline block")
    parser.add_argument("--render", type=json.loads, default=None, help='JSON render block, e.g. {"views_per_leg": 3}')
    parser.add_argument("--errors", choices=sorted(ERROR_PROFILES), default="standard", help="pose-error profile")
    parser.add_argument("--refine", type=json.loads, default=None, help='JSON refine block, e.g. {"recheck": false}')
    parser.add_argument("--verify", type=json.loads, default=None, help='JSON verify block, e.g. {"enabled": true}')
    parser.add_argument(
        "--extraction-rounds",
        type=int,
        default=None,
        help="the horizon extraction's EM runs exactly this many rounds (3: the rule before session 14), "
        "for a before and after in one tree (default: until the boundary settles)",
    )
    add_sky_model_options(parser)
    parser.add_argument("--json-only", action="store_true")
    args = parser.parse_args(argv)
    blocks = {
        k: v
        for k, v in (
            ("memory", args.memory),
            ("scheduler", args.scheduler),
            ("skyline", args.skyline),
            ("render", args.render),
            ("refine", args.refine),
            ("verify", args.verify),
        )
        if v is not None
    }
    t0 = time.time()
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else None
    result: dict[str, Any] = {}
    # every agent runs in this process (run_mission)
    with fixed_rounds(args.extraction_rounds), sky_model(args, result):
        result.update(
            run(args.split, names=args.names, kinds=args.kinds, blocks=blocks, track=args.track, errors=args.errors)
        )
    result["extraction_rounds"] = args.extraction_rounds
    result["machine"] = {
        "python": platform.python_version(),
        "cpus": __import__("os").cpu_count(),
        "load_at_start": load,
        "wall_s": time.time() - t0,
    }
    print(json.dumps(result, indent=1))
    if not args.json_only:
        print()
        print(
            f"split {args.split} ({args.errors} pose errors), blocks {json.dumps(blocks) if blocks else 'scenario defaults'}, "
            f"{'with' if args.track else 'without'} tracking"
        )
        print(table(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
