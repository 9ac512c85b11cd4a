"""Behaviour check: the per-frame results of every bundled scenario, against a saved reference.

For every ``scenarios/*.yaml`` with a ``sensor`` block it runs ``mapinterp run SCENARIO --out``
(the real command, in a subprocess, everything on loopback) and keeps, per camera frame, what
the system decided: the chosen ``viewframe``, the detector ``queries``, the ``backtracks`` and
the first five viewframes of the associative ranking. With ``--table`` it also keeps each row of
``mapinterp table SCENARIO --json`` (the best viewframe, compared exactly, and the error
variances, compared within a relative 1e-2 and reported as their largest relative difference).
The software renderer is not bit-exact between two renders of the same pose (a pixel or two of
a few jacksboro views differ, also in the code before the refactor), so the variances differ a
little from run to run. Rarely a decision differs too: a detector score near a threshold
moves with those pixels (jacksboro frame 5 took 2 queries in one run of the code before the
refactor and 3 with a backtrack in the next, the same viewframe both times); rerun a scenario
that differs before concluding.

    python bench/compare_results.py --write bench/reference/results_before.json
    python bench/compare_results.py --compare bench/reference/results_before.json

``--repo DIR`` runs the commands of another checkout (its packages first on ``PYTHONPATH``),
which is how the reference was produced from the code before a refactor. Prints one JSON
document (the results, and with ``--compare`` the differences), then a table on stderr; the
exit status is 1 when ``--compare`` finds a difference.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parent.parent
#: relative tolerance of the table's error variances (see :func:`_close`)
VARIANCE_RTOL = 1e-2


def scenarios_with_sensor(folder: Path) -> list[Path]:
    """The scenario files of ``folder`` that have camera frames (``sensor``), sorted by name."""
    out = []
    for path in sorted(folder.glob("*.yaml")):
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
        if isinstance(data, dict) and data.get("sensor"):
            out.append(path)
    return out


def _command(repo: Path, args: list[str]) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(repo), PYOPENGL_PLATFORM=os.environ.get("PYOPENGL_PLATFORM", "egl"))
    cmd = [sys.executable, "-m", "knowledge_sources.cli", *args]
    proc = subprocess.run(cmd, cwd=repo, env=env, capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return proc


def run_frames(repo: Path, scenario: Path) -> tuple[list[dict[str, Any]], float]:
    """Per-frame decisions of ``mapinterp run`` on ``scenario``, and the wall time in seconds."""
    with tempfile.TemporaryDirectory(prefix="mapinterp-compare-") as tmp:
        out = Path(tmp) / "results.json"
        t0 = time.perf_counter()
        _command(repo, ["run", str(scenario), "--out", str(out), "--no-progress"])
        wall = time.perf_counter() - t0
        results = json.loads(out.read_text())
    frames = [
        {
            "frame": f["frame"],
            "viewframe": f["viewframe"],
            "queries": f["queries"],
            "backtracks": f["backtracks"],
            "ranking": [int(k) for k, _ in f["ranking"]],
        }
        for f in results["frames"]
    ]
    return frames, wall


def table_rows(repo: Path, scenario: Path) -> list[dict[str, Any]]:
    """Rows of ``mapinterp table --json``: best viewframe and variances (rounded)."""
    doc = json.loads(_command(repo, ["table", str(scenario), "--json"]).stdout)
    return [
        {"frame": r["frame"], "best": r["best"], "variances": [round(v, 12) for v in r["variances"]]}
        for r in doc["rows"]
    ]


def collect(repo: Path, scenarios: list[Path], *, table: bool) -> dict[str, Any]:
    doc: dict[str, Any] = {"repo": str(repo), "scenarios": {}}
    for path in scenarios:
        frames, wall = run_frames(repo, path)
        entry: dict[str, Any] = {"frames": frames, "wall_s": round(wall, 1)}
        if table:
            entry["table"] = table_rows(repo, path)
        doc["scenarios"][path.stem] = entry
        print(f"{path.stem}: {len(frames)} frames in {wall:.0f} s", file=sys.stderr)
    return doc


def compare(reference: dict[str, Any], current: dict[str, Any]) -> list[str]:
    """Every difference between two collected documents, one sentence each."""
    diffs: list[str] = []
    for name in sorted(set(reference["scenarios"]) | set(current["scenarios"])):
        ref, cur = reference["scenarios"].get(name), current["scenarios"].get(name)
        if ref is None or cur is None:
            diffs.append(f"{name}: only in the {'current run' if ref is None else 'reference'}")
            continue
        for part in ("frames", "table"):
            if part not in ref or part not in cur:
                continue
            a, b = ref[part], cur[part]
            if len(a) != len(b):
                diffs.append(f"{name} {part}: {len(a)} entries in the reference, {len(b)} now")
            for x, y in zip(a, b):
                for key in x:
                    if key == "variances" and _close(x[key], y.get(key)):
                        continue
                    if x[key] != y.get(key):
                        diffs.append(f"{name} {part} frame {x['frame']}: {key} {x[key]} -> {y.get(key)}")
    return diffs


def _close(a: list[float], b: list[float] | None, *, rtol: float = VARIANCE_RTOL) -> bool:
    """Equal within ``rtol``: the variances differ slightly between two runs of the same code
    (the software renderer, float32 reductions), so table variances are compared with a
    tolerance; every decision (viewframe, queries, backtracks, ranking order, best) must be equal."""
    return b is not None and len(a) == len(b) and all(abs(x - y) <= rtol * max(abs(x), abs(y)) for x, y in zip(a, b))


def max_variance_difference(reference: dict[str, Any], current: dict[str, Any]) -> dict[str, float]:
    """Per scenario, the largest relative difference of a table variance (0 without tables)."""
    out = {}
    for name, cur in current["scenarios"].items():
        ref = reference["scenarios"].get(name, {})
        worst = 0.0
        for a, b in zip(ref.get("table", []), cur.get("table", [])):
            for x, y in zip(a["variances"], b["variances"]):
                worst = max(worst, abs(x - y) / max(abs(x), abs(y), 1e-300))
        out[name] = worst
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", type=Path, help="write the collected results here (the reference)")
    mode.add_argument("--compare", type=Path, help="compare the current results with this reference")
    parser.add_argument("--repo", type=Path, default=ROOT, help="checkout whose code runs (default: this one)")
    parser.add_argument("--scenarios", type=Path, default=None, help="scenario folder (default: REPO/scenarios)")
    parser.add_argument("--table", action="store_true", help="also compare 'mapinterp table --json'")
    args = parser.parse_args(argv)
    repo = args.repo.resolve()
    scenarios = scenarios_with_sensor(args.scenarios or repo / "scenarios")
    if args.compare is not None:
        reference = json.loads(args.compare.read_text())
        table = args.table or any("table" in s for s in reference["scenarios"].values())
    else:
        table = args.table
    current = collect(repo, scenarios, table=table)
    if args.write is not None:
        args.write.parent.mkdir(parents=True, exist_ok=True)
        args.write.write_text(json.dumps(current, indent=1) + "\n")
        print(json.dumps(current, indent=1))
        return 0
    diffs = compare(reference, current)
    spread = max_variance_difference(reference, current)
    print(
        json.dumps(
            {
                "reference": str(args.compare),
                "current": current,
                "differences": diffs,
                "table_max_relative_variance_difference": spread,
            },
            indent=1,
        )
    )
    print(
        f"{'scenario':<12}{'frames':>8}{'same viewframe':>16}{'same queries':>14}{'table var. rel. diff':>22}",
        file=sys.stderr,
    )
    for name, cur in current["scenarios"].items():
        ref = reference["scenarios"].get(name, {"frames": []})
        pairs = list(zip(ref["frames"], cur["frames"]))
        same_vf = sum(a["viewframe"] == b["viewframe"] for a, b in pairs)
        same_q = sum(a["queries"] == b["queries"] for a, b in pairs)
        print(f"{name:<12}{len(cur['frames']):>8}{same_vf:>16}{same_q:>14}{spread[name]:>22.1e}", file=sys.stderr)
    print(f"{len(diffs)} difference(s)" + "".join(f"\n  {d}" for d in diffs[:40]), file=sys.stderr)
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
