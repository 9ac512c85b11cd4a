"""Every command-line benchmark starts: ``python bench/NAME.py --help`` from a clean process.

The benchmarks are run by hand, so an import that breaks one (a module loaded by file before the
repository root is on the path, say) would otherwise go unseen until someone needs its numbers.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

#: the scripts with a command line (argparse); bench/tuning's pickle-driven sweeps of the first
#: session (prep.py, oracle.py, ...) run in the order of bench/tuning/README.md and take no options
SCRIPTS = sorted(
    str(p.relative_to(ROOT))
    for p in [*ROOT.glob("bench/*.py"), *ROOT.glob("bench/tuning/*.py")]
    if "argparse" in p.read_text(encoding="utf-8")
)


def test_the_scripts_are_found() -> None:
    assert {"bench/single_frame.py", "bench/detectors.py", "bench/tuning/calibrate_detectors.py"} <= set(SCRIPTS)


@pytest.mark.parametrize("script", SCRIPTS)
def test_a_benchmark_answers_help(script: str, tmp_path: Path) -> None:
    # from another folder, as a user runs it from wherever: the script must find the repository itself
    env = {**os.environ, "PYTHONPATH": ""}
    done = subprocess.run(
        [sys.executable, str(ROOT / script), "--help"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, f"{script} --help failed:\n{done.stderr[-2000:]}"
    assert "usage" in done.stdout.lower()


@pytest.mark.parametrize("script", ["bench/single_frame.py", "bench/tracking.py", "bench/pose_ablation.py"])
@pytest.mark.parametrize("split, code", [("fresh", 0), ("heldout", 0), ("nosuch", 2)])
def test_the_evaluation_benchmarks_take_every_split(script: str, split: str, code: int) -> None:
    # argparse checks --split's choice before it reaches --help: 0 if the split is accepted, 2 if not
    done = subprocess.run(
        [sys.executable, str(ROOT / script), "--split", split, "--help"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == code, done.stderr[-2000:]


def test_single_frame_runs_the_fresh_split_s_cases(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """bench/single_frame.py's run over the fresh split, the pipeline replaced by a stub that
    localizes nothing (the split is kept for one final measurement: no test may look at one)."""
    import importlib.util

    from bench.evalset import cases as real_cases

    spec = importlib.util.spec_from_file_location("single_frame_under_test", ROOT / "bench" / "single_frame.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    seen: list[str] = []

    def few_cases(split, **kw):
        return real_cases(split, out_dir=tmp_path, max_frames=2, **kw)

    def no_mission(path, track):
        seen.append(str(path))
        truths = [f["truth"] for f in load_yaml(path)["sensor"]["frames"]]
        # every frame unanswered (no position, no ranking): what a mission that found nothing reports
        frames = [
            {"truth": [t["x"], t["y"], t["heading_deg"]], "truth_viewframe": None, "error_m": None} for t in truths
        ]
        return {"frames": frames, "summary": {"frames_per_s": 0.0}}

    monkeypatch.setattr(module, "cases", few_cases)
    monkeypatch.setattr(module, "run_mission", no_mission)
    result = module.run("fresh", names=["f-volcano-contours"], errors="large")
    assert result["split"] == "fresh" and result["errors"] == "large"
    assert list(result["cases"]) == ["f-volcano-contours/sweep"] and len(seen) == 1
    assert "fresh-large" in seen[0]


def load_yaml(path):
    import yaml

    return yaml.safe_load(Path(path).read_text())
