"""The skyline ranker's per-frame cost: the horizon extraction (:func:`models.skyline.skyline_from_image`)
and the whole ranking of a frame (extraction + :func:`models.skyline_coarse.ranked_references`,
the scenario's ``skyline`` settings), this checkout's code against a baseline's, in one run.

The baseline is ``models/skyline.py`` and ``models/skyline_coarse.py`` of the git revision
``--baseline`` (default: main before they were made faster), loaded from ``git show`` as modules
of their own (the baseline's coarse stage is given the baseline's full match,
``match_skylines``). Frames, alternating which code goes first from one frame to
the next so that load changes hit both:

* ``route``: ``--frames`` viewframe images of a long route's viewframe cache entry (``--entry``,
  read-only; 160 x 120, the ``bench/end_to_end.py`` camera, 45 degrees), evenly spaced, degraded
  like camera images (:func:`models.sensor.degrade`, seeded: haze, noise, gain, blur), ranked
  against all the entry's skylines (the coarse stage, then the full match of its best);
* ``evalset``: the evaluation set's camera frames (``--evalset``, its drives' jpg frames,
  240 x 320; extraction only: the references are not on their grid), the first ``--frames``.

CPU ms per frame (``time.process_time``; BLAS on one thread), median and mean per code, their
ratio (baseline / ours); every frame's profile and ranking are compared between the two codes
(``identical``: the same bits).

    nice -n 5 python bench/skyline_speed.py --frames 60

Prints JSON, then a table.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
# bench/blackboard.py would shadow the blackboard package: drop this folder from the path
HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]
sys.path.insert(0, str(HERE.parent))

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402
import types  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from models import skyline as ours  # noqa: E402
from models import skyline_coarse as ours_coarse  # noqa: E402
from models.scenario import SimulateSpec, SkylineSpec  # noqa: E402
from models.sensor import degrade  # noqa: E402

#: main at session 11, before the faster extraction
DEFAULT_BASELINE = "868cdb3"
DEFAULT_ENTRY = "/work/cache/full10k-10k"
FOV_Y_DEG = 45.0  # bench/end_to_end.py's camera


def _baseline(rev: str, path: str) -> types.ModuleType:
    """``path`` (e.g. ``models/skyline.py``) of git revision ``rev`` as a module of its own."""
    try:
        src = subprocess.run(
            ["git", "-C", str(HERE.parent), "show", f"{rev}:{path}"], capture_output=True, text=True, check=True
        ).stdout
    except subprocess.CalledProcessError as err:
        raise SystemExit(f"--baseline {rev}: git show {path} failed: {err.stderr.strip()}") from None
    name = "baseline_" + Path(path).stem
    spec = importlib.util.spec_from_loader(name, loader=None)
    assert spec is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # dataclasses look their module up
    exec(compile(src, f"{rev}:{path}", "exec"), mod.__dict__)
    return mod


def _entry_folder(path: Path) -> Path:
    """A cache entry folder: ``path`` itself (with meta.json) or its only entry."""
    if (path / "meta.json").is_file():
        return path
    entries = sorted(p for p in path.iterdir() if (p / "meta.json").is_file()) if path.is_dir() else []
    if len(entries) != 1:
        raise SystemExit(f"--entry {path}: not a viewframe cache entry, nor a cache holding exactly one")
    return entries[0]


def _route_frames(entry: Path, count: int) -> tuple[list[np.ndarray], np.ndarray]:
    images = np.load(entry / "image.npy", mmap_mode="r")
    refs = np.array(np.load(entry / "skyline.npy", mmap_mode="r"), dtype=np.float32)
    rows = np.linspace(0, len(images) - 1, count).round().astype(int)
    spec = SimulateSpec(haze=0.3, noise=6.0, gain=0.2, gamma=0.2, blur=0.8)
    return [degrade(np.array(images[k]), spec=spec, rng=i) for i, k in enumerate(rows)], refs


def _evalset_frames(folder: Path, count: int) -> list[np.ndarray]:
    files = sorted(folder.glob("*/*/*/frames/*.jpg"))[:count]
    if not files:
        raise SystemExit(f"--evalset {folder}: no */*/*/frames/*.jpg")
    out = []
    for f in files:
        img = cv2.imread(str(f))
        if img is None:
            raise SystemExit(f"--evalset: cannot read {f}")
        out.append(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
    return out


def _stats(ms: list[float]) -> dict[str, float]:
    return {"median_ms": float(np.median(ms)), "mean_ms": float(np.mean(ms))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", default=DEFAULT_BASELINE, help="git revision of the baseline models/skyline.py")
    ap.add_argument("--entry", type=Path, default=Path(DEFAULT_ENTRY), help="viewframe cache (entry) of a route")
    ap.add_argument(
        "--evalset", type=Path, default=Path(os.environ.get("MAPINTERP_EVALSET_DIR", "/work/cache/evalset"))
    )
    ap.add_argument("--frames", type=int, default=60, help="frames per set")
    ap.add_argument("--sets", nargs="+", default=["route", "evalset"], choices=["route", "evalset"])
    args = ap.parse_args()
    if args.frames < 1:
        raise SystemExit("--frames must be >= 1")
    codes = {"baseline": _baseline(args.baseline, "models/skyline.py"), "ours": ours}
    rankers = {"baseline": _baseline(args.baseline, "models/skyline_coarse.py"), "ours": ours_coarse}
    # the baseline's coarse stage imported this checkout's full match: give it the baseline's
    rankers["baseline"].match_skylines = codes["baseline"].match_skylines  # type: ignore[attr-defined]
    rankers["baseline"].SkylineMatch = codes["baseline"].SkylineMatch  # type: ignore[attr-defined]
    sky = SkylineSpec()
    match = {k: v for k, v in sky.match_options().items() if k != "roll_candidates"}
    out: dict[str, object] = {
        "utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "load_avg": list(os.getloadavg()),
        "host": platform.node(),
        "baseline": args.baseline,
        "ours": subprocess.run(
            ["git", "-C", str(HERE.parent), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
        ).stdout.strip(),
        "frames": args.frames,
        "sets": {},
    }
    for name in args.sets:
        if name == "route":
            frames, refs = _route_frames(_entry_folder(args.entry), args.frames)
            coarse = {c: m.CoarseSkylines.prepare(refs) for c, m in rankers.items()}
        else:
            frames, refs, coarse = _evalset_frames(args.evalset, args.frames), None, {}
        ms: dict[str, dict[str, list[float]]] = {c: {"extract": [], "rank": []} for c in codes}
        identical = True
        for i, img in enumerate(frames):
            order = ["baseline", "ours"] if i % 2 == 0 else ["ours", "baseline"]
            got = {}
            for c in order:
                t0 = time.process_time()
                q = codes[c].skyline_from_image(img, fov_y_deg=FOV_Y_DEG, step_deg=sky.step_deg)
                t1 = time.process_time()
                ranked = None
                if refs is not None:
                    if q.size != refs.shape[1]:
                        raise SystemExit(f"--entry: skylines of {refs.shape[1]} bins, the frames' {q.size}")
                    ranked = rankers[c].ranked_references(
                        q,
                        refs,
                        coarse[c],
                        candidates=sky.coarse_candidates,
                        roll_candidates=sky.roll_candidates,
                        **match,
                    )
                    ms[c]["rank"].append((time.process_time() - t0) * 1e3)
                ms[c]["extract"].append((t1 - t0) * 1e3)
                got[c] = (q, ranked)
            (qa, ra), (qb, rb) = got["baseline"], got["ours"]
            same = np.array_equal(qa, qb, equal_nan=True)
            if ra is not None and rb is not None:
                same = same and np.array_equal(ra[0], rb[0])
                for f in ("error", "heading_deg", "pitch_deg", "overlap", "roll_deg"):
                    same = same and np.array_equal(getattr(ra[1], f), getattr(rb[1], f))
            identical = identical and bool(same)
        res: dict[str, object] = {"frames": len(frames), "shape": list(frames[0].shape), "identical": identical}
        for part in ("extract", "rank"):
            if ms["ours"][part]:
                b, o = _stats(ms["baseline"][part]), _stats(ms["ours"][part])
                res[part] = {"baseline": b, "ours": o, "ratio_median": b["median_ms"] / o["median_ms"]}
        out["sets"][name] = res  # type: ignore[index]
    out["load_avg_end"] = list(os.getloadavg())
    print(json.dumps(out, indent=1))
    print()
    print(
        f"skyline ranker per frame, CPU ms (baseline {args.baseline} vs ours {out['ours']}), {out['utc']}, load {out['load_avg']}"
    )
    print(
        f"{'set':8s} {'part':8s} {'frames':>6s} {'base med':>9s} {'ours med':>9s} {'base mean':>9s} {'ours mean':>9s} {'ratio':>6s} same"
    )
    for name, res in out["sets"].items():  # type: ignore[attr-defined]
        for part in ("extract", "rank"):
            if part in res:
                r = res[part]
                print(
                    f"{name:8s} {part:8s} {res['frames']:6d} {r['baseline']['median_ms']:9.2f} {r['ours']['median_ms']:9.2f} "
                    f"{r['baseline']['mean_ms']:9.2f} {r['ours']['mean_ms']:9.2f} {r['ratio_median']:6.2f} {res['identical']}"
                )


if __name__ == "__main__":
    main()
