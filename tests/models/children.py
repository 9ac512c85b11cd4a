"""Child Python processes for the tests that run one piece of code in several processes at once."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def start(script: str, args: Sequence[str], *, env: Mapping[str, str], count: int = 2) -> list[subprocess.Popen]:
    """``count`` processes of ``python -c script *args`` in the checkout, started at once."""
    return [
        subprocess.Popen(
            [sys.executable, "-c", script, *args],
            cwd=ROOT,
            env=dict(env),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(count)
    ]


def outputs(procs: Sequence[subprocess.Popen], *, timeout_s: float = 300) -> list[dict]:
    """Each process's last line of output as JSON, once it has exited 0 (asserted, with its stderr)."""
    outs = []
    for p in procs:
        out, err = p.communicate(timeout=timeout_s)
        assert p.returncode == 0, err
        outs.append(json.loads(out.strip().splitlines()[-1]))
    return outs
