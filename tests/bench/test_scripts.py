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
