"""Behaviour fingerprint of the bundled scenarios, to check a refactor changed no decision.

Runs every scenario (both strategies) through the blackboard and prints, as JSON then a table,
per frame: the chosen viewframe, the queries and backtracks, the questions asked (landmark,
viewframe, answer) in order, the first 5 of the ranking, the position and heading. With
``--compare OLD.json`` it compares against an earlier fingerprint and exits 1 on any difference.

    python bench/same_results.py --out /tmp/before.json            # on the old code
    python bench/same_results.py --compare /tmp/before.json        # on the new code

Latency, timestamps and hypothesis ids are left out (they change from run to run). BLAS runs
single-threaded here so that two runs of the same code give the same fingerprint.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
# one BLAS thread: a threaded float32 matrix product sums in a load-dependent order, and the last
# bits of the variances then differ from run to run (enough to flip a near-tie decision)
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parent.parent
if sys.path and Path(sys.path[0]).resolve() == ROOT / "bench":
    sys.path[0] = str(ROOT)  # bench/blackboard.py would shadow the blackboard package
SCENARIOS = sorted((ROOT / "scenarios").glob("*.yaml"))


def fingerprint(scenario: Path, strategy: str) -> list[dict[str, Any]]:
    from knowledge_sources.mission import run_mission

    results = run_mission(scenario, strategy=strategy)
    out = []
    for f in results["frames"]:
        out.append({
            "frame": f["frame"],
            "viewframe": f["viewframe"],
            "queries": f["queries"],
            "backtracks": f["backtracks"],
            "questions": [[s.get("landmark"), s.get("viewframe"), s.get("present")] for s in f.get("steps", [])
                          if "landmark" in s],
            "ranking": [[k, round(v, 12)] for k, v in f["ranking"]],
            "position": f["position"],
            "heading_deg": f["heading_deg"],
            "correct": f["correct"],
            "reason": f["reason"],
        })
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", help="write the fingerprint here")
    parser.add_argument("--compare", help="compare with this earlier fingerprint")
    parser.add_argument("--only", nargs="*", default=None, help="scenario names (default: all bundled)")
    args = parser.parse_args(argv)
    chosen = [s for s in SCENARIOS if args.only is None or s.stem in args.only]
    prints = {f"{s.stem}/{strategy}": fingerprint(s, strategy) for s in chosen for strategy in ("associative", "prior")}
    print(json.dumps(prints))
    if args.out:
        Path(args.out).write_text(json.dumps(prints, indent=1) + "\n")
    old = json.loads(Path(args.compare).read_text()) if args.compare else None
    print(f"{'scenario/strategy':28} {'frames':>6} {'queries':>7} {'same':>5}")
    differ = 0
    for name, frames in prints.items():
        same = "-" if old is None else ("yes" if old.get(name) == frames else "NO")
        differ += same == "NO"
        print(f"{name:28} {len(frames):6d} {sum(f['queries'] for f in frames):7d} {same:>5}")
        if same == "NO":
            for a, b in zip(old[name], frames):
                if a != b:
                    print(f"  frame {a['frame']}: before {a}\n  frame {b['frame']}: after  {b}")
                    break
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
