"""Do missions give the same rankings and answers? Compares mission traces (and their results).

Every ``ranking`` hypothesis posted in a trace (by source, frame and shard: the associative
indexers' and the skyline ranker's) against the first trace's: the same viewframes in the same
order, and the largest relative difference of the variances (two runs of the same code differ by
about 1e-7: numpy's SIMD sums depend on where the arrays lie in memory). With results files
(``--results``, ``mapinterp run --out`` / ``bench/scale.py --keep``), also each frame's answer:
the chosen viewframe, the track's state, correctness, the frame-only viewframe, the fused
ranking's first five and the number of questions. Prints JSON, then a table; exit status 1
when an order or an answer differs::

    python bench/trace_rankings.py A.trace B.trace [C.trace ...] [--results A.json B.json ...]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]  # bench/blackboard.py would hide the package

import numpy as np  # noqa: E402


def rankings(path: Path) -> dict[tuple[str, int, int], tuple[list[int], np.ndarray]]:
    """``{(source, frame, shard): (viewframes, variances)}`` of the rankings posted in a trace."""
    from blackboard.trace import read_trace

    out = {}
    for r in read_trace(path):
        if r.get("level") == "ranking" and r.get("kind") == "post":
            b = r["body"]
            var = np.asarray(b.get("variances") or [], dtype=np.float64)
            out[(str(b["source"]), int(b["frame"]), int(b["shard"]))] = ([int(v) for v in b["viewframes"]], var)
    return out


def compare_traces(ref: dict, got: dict) -> dict[str, Any]:
    keys = sorted(set(ref) & set(got))
    order = [k for k in keys if ref[k][0] != got[k][0]]
    rel = 0.0
    for k in keys:
        a, b = ref[k][1], got[k][1]
        if ref[k][0] == got[k][0] and a.size and a.shape == b.shape:
            rel = max(rel, float(np.max(np.abs(a - b) / np.maximum(np.abs(a), 1e-300))))
    return {
        "rankings": len(keys),
        "by_source": {s: sum(k[0] == s for k in keys) for s in sorted({k[0] for k in keys})},
        "only_in_one": len(set(ref) ^ set(got)),
        "order_differs": [list(k) for k in order],
        "max_rel_variance_diff": rel,
    }


def _answer(frame: dict) -> tuple:
    head = [r[0] if isinstance(r, list) else r for r in (frame.get("ranking") or [])[:5]]
    only = (frame.get("frame_only") or {}).get("viewframe")
    return (frame["viewframe"], frame.get("state"), frame.get("correct"), only, head, frame.get("queries"))


def compare_results(ref: list[dict], got: list[dict]) -> list[dict]:
    """The frames whose answer differs: ``[{frame, ref, got}]``."""
    diffs = [
        {"frame": a["frame"], "ref": list(_answer(a)), "got": list(_answer(b))}
        for a, b in zip(ref, got)
        if _answer(a) != _answer(b)
    ]
    if len(ref) != len(got):
        diffs.append({"frame": None, "ref": len(ref), "got": len(got)})
    return diffs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("traces", type=Path, nargs="+", help="mission traces; the first is the reference")
    parser.add_argument("--results", type=Path, nargs="*", default=[], help="results files; the first the reference")
    args = parser.parse_args(argv)
    for p in [*args.traces, *args.results]:
        if not p.is_file():
            parser.error(f"{p}: no such file")
    ref = rankings(args.traces[0])
    out: dict[str, Any] = {"reference": str(args.traces[0]), "traces": {}, "results": {}}
    for p in args.traces[1:]:
        out["traces"][str(p)] = compare_traces(ref, rankings(p))
    if args.results:
        frames = [json.loads(p.read_text())["frames"] for p in args.results]
        out["results_reference"] = str(args.results[0])
        for p, fr in zip(args.results[1:], frames[1:]):
            out["results"][str(p)] = compare_results(frames[0], fr)
    print(json.dumps(out, indent=1))
    print(f"\nagainst {args.traces[0].name}:")
    for p, r in out["traces"].items():
        print(
            f"  {Path(p).name}: {r['rankings']} rankings {r['by_source']}, only in one {r['only_in_one']}, "
            f"order differs in {len(r['order_differs'])}, variances within {r['max_rel_variance_diff']:.1e}"
        )
    for p, d in out["results"].items():
        print(f"  {Path(p).name}: {len(d)} frames answered otherwise" + (f" (first: {d[0]})" if d else ""))
    bad = any(r["order_differs"] or r["only_in_one"] for r in out["traces"].values()) or any(out["results"].values())
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
