"""Where the larger pose errors' loss comes from: each ranking source under each pose-error profile.

For every profile named (default: ``standard``, ``large`` and each component of ``large`` alone,
``large-along`` ... ``large-roll``: :data:`bench.evalset.ERROR_PROFILES`), every case of the split
(``tuning`` by default: choose there) is read, its scenario's own viewframes (``render.views_per_leg``,
as a mission renders them) are rendered once per terrain (:class:`models.world.World`, through the
viewframe cache), and every camera frame is ranked as the mission's agents rank it: the
associative memory (:class:`models.index.ViewframeIndex` with the scenario's memory settings, the
indexer's call, after the camera agent's resize), the skyline (``skyline_from_image`` and
``match_skylines`` with the scenario's skyline settings, the skyline ranker's calls) and their
fusion (:func:`knowledge_sources.fusion.fuse_rankings` at the scenario's weights, the
scheduler's). A viewframe's route point is where it ranks (the first viewframe of each point,
the scene analysis's candidates). Reports top-1 / top-5 per source and profile, per terrain and
overall, the frames per second of the ranking, and, per profile, top-1 of each source in bins
of each pose-error component's size (which component the misses go with).

    python bench/pose_ablation.py [--split tuning|heldout|fresh] [--profiles standard large large-roll ...]
        [--kinds sweep drive kidnap] [--memory '{"max_shift": [8, 24]}'] [--skyline '{...}']
        [--derotate '{...}'] [--rolls '[-3, 0, 3]'] [--extra] [--json-only]

``--memory`` / ``--skyline`` override fields of the scenario's blocks (as ``bench/single_frame.py``
does), so that an alternative is compared on the same frames; ``--rolls`` is the memory's
``roll_search_deg`` (``[0]``: the match without the roll search, as before it); ``--derotate``
levels each camera image by its skyline match first (:func:`models.derotate.level_image`);
``--extra`` (tuning) adds bench/tracking.py's extra tuning drives (640 frames in all). Prints JSON, then a table.
"""

from __future__ import annotations

import sys
from pathlib import Path

_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402

from bench.evalset import ERROR_PROFILES, cases  # noqa: E402

#: the profiles compared by default: the two of the evaluation set and each component alone
DEFAULT_PROFILES = ("standard", "large", *(p for p in ERROR_PROFILES if p.startswith("large-")))
SOURCES = ("associative", "skyline", "fused")
#: (frame field, bin edges of its absolute value) for the per-component breakdown
COMPONENT_BINS: dict[str, tuple[float, ...]] = {
    "along_frac": (0.0, 0.2, 0.3, 0.4),
    "lateral_m": (0.0, 2.0, 4.0, 8.0),
    "heading_error_deg": (0.0, 2.5, 5.0, 10.0),
    "pitch_deg": (0.0, 1.0, 2.0, 3.0),
    "roll_deg": (0.0, 1.0, 2.0, 3.0),
}


def _scenario(case, memory: dict[str, Any] | None, skyline: dict[str, Any] | None):
    from models.scenario import load_scenario

    sc = load_scenario(case.scenario_path)
    update = {}
    if memory:
        update["memory"] = sc.memory.model_copy(update=memory)
    if skyline:
        update["skyline"] = sc.skyline.model_copy(update=skyline)
    return sc.model_copy(update=update) if update else sc


class Terrain:
    """One terrain's viewframes (rendered once), index and skyline references."""

    def __init__(self, scenario) -> None:
        from models.index import ViewframeIndex
        from models.route_views import route_points_of
        from models.world import World

        with World(scenario) as world:
            vfs = world.viewframes
            self.index = ViewframeIndex(scenario.memory, seed=0)
            self.index.add((v.image for v in vfs), [v.index for v in vfs])
            self.refs = np.stack([v.skyline for v in vfs]).astype(np.float32)
            self.images = [v.image for v in vfs]
        on = route_points_of(scenario)
        self.points = np.arange(len(vfs)) if on is None else np.asarray(on, dtype=np.int64)


def rank_frame(
    terrain: Terrain,
    scenario,
    image: np.ndarray,
    derotate: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The three sources' rankings of one camera image ``image`` (H, W, 3) at the camera's size:
    ``{source: [(viewframe, score), ...] best first}``, and the seconds each source took."""
    from knowledge_sources.fusion import fuse_rankings
    from models.skyline import match_skylines, skyline_from_image

    cam, sky, mem = scenario.camera, scenario.skyline, scenario.memory
    labels = list(range(len(terrain.refs)))
    t0 = time.perf_counter()
    query = skyline_from_image(image, fov_y_deg=cam.fov_y_deg, step_deg=sky.step_deg)
    m = match_skylines(query, terrain.refs, **sky.match_options())
    t1 = time.perf_counter()
    if derotate is not None:
        from models.derotate import level_image

        image = level_image(image, m, fov_y_deg=cam.fov_y_deg, **derotate)
    rk = terrain.index.rank(image)
    t2 = time.perf_counter()
    per = {
        "associative": (rk.viewframes.tolist(), rk.variances.tolist()),
        "skyline": (labels, m.error.tolist()),
    }
    out = {
        "associative": fuse_rankings({"associative": per["associative"]}),
        "skyline": fuse_rankings({"skyline": per["skyline"]}),
        "fused": fuse_rankings(per, weights={"associative": mem.weight, "skyline": sky.weight}),
    }
    return {"rankings": out, "skyline_s": t1 - t0, "associative_s": t2 - t1}


def place(ranking: list[tuple[int, float]], points: np.ndarray, truth: int) -> int:
    """Where the true route point ``truth`` ranks (0: first) when each point ranks where its best viewframe does."""
    from models.route_views import first_per_point

    best = first_per_point(ranking, points)
    return next((j for j, (k, _) in enumerate(best) if int(points[k]) == truth), len(best))


def offset(ranking: list[tuple[int, float]], points: np.ndarray, truth: int) -> int:
    """The first route point of ``ranking`` minus the true one (0: right; -1: the point behind)."""
    return int(points[int(ranking[0][0])]) - int(truth) if ranking else 0


def run(
    split: str,
    profiles: list[str],
    *,
    kinds: list[str] | None = None,
    names: list[str] | None = None,
    memory: dict[str, Any] | None = None,
    skyline: dict[str, Any] | None = None,
    derotate: dict[str, Any] | None = None,
    rolls: list[float] | None = None,
    extra: bool = False,
) -> dict[str, Any]:
    """Every frame of every case of ``split`` under each profile: the truth's place per source;
    ``extra``: with bench/tracking.py's extra tuning drives (more frames of the tuning terrains,
    and of the same families at other seeds)."""
    from models.sensor import load_frame_image

    if rolls is not None:  # the memory's roll search (MemorySpec.roll_search_deg)
        memory = {**(memory or {}), "roll_search_deg": tuple(float(a) for a in rolls)}
    terrains: dict[str, Terrain] = {}
    records: list[dict[str, Any]] = []
    extra_cases: list[Any] = []
    if extra:
        from bench.tracking import extra_tuning_drives

        if split != "tuning":
            raise ValueError("extra: only the tuning split has more cases (bench/tracking.py's extra tuning drives)")
        extra_cases = extra_tuning_drives()
    for profile in profiles:
        more: list[Any] = []
        for t in extra_cases:  # a terrain again with its other drive kinds ("-x": its sweep is the split's own)
            only = [k for k in (kinds or ("sweep", *t.drives)) if k != "sweep" or not t.name.endswith("-x")]
            more.extend(cases(split, kinds=only, names=names, errors=profile, terrains=[t]) if only else [])
        for case in (*cases(split, kinds=kinds, names=names, errors=profile), *more):
            sc = _scenario(case, memory, skyline)
            if case.terrain not in terrains:
                terrains[case.terrain] = Terrain(sc)
            ter = terrains[case.terrain]
            t0 = time.perf_counter()
            for fr in case.frames:
                image = load_frame_image(fr.image, width=sc.camera.width, height=sc.camera.height)
                r = rank_frame(ter, sc, image, derotate)
                rec = {
                    "profile": profile,
                    "case": case.name,
                    "terrain": case.terrain,
                    **{s: place(r["rankings"][s], ter.points, int(fr.route_index)) for s in SOURCES},
                    **{f"{s}_offset": offset(r["rankings"][s], ter.points, int(fr.route_index)) for s in SOURCES},
                    "skyline_s": r["skyline_s"],
                    "associative_s": r["associative_s"],
                }
                for c in COMPONENT_BINS:
                    v = getattr(fr, c)
                    rec[c] = None if v is None else abs(float(v))
                records.append(rec)
            print(
                f"# {profile} {case.name}: {len(case.frames)} frames, {time.perf_counter() - t0:.1f} s",
                file=sys.stderr,
                flush=True,
            )
    return {"split": split, "profiles": profiles, "records": records, "summary": summarise(records, profiles)}


def _rates(recs: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {"frames": len(recs)}
    for s in SOURCES:
        p = np.array([r[s] for r in recs])
        d = np.array([r[f"{s}_offset"] for r in recs])
        out[s] = {
            "top1": float(np.mean(p < 1)) if p.size else None,
            "top5": float(np.mean(p < 5)) if p.size else None,
            # where the first route point is when it is wrong: the point behind, ahead, further
            "behind": int(np.sum(d == -1)),
            "ahead": int(np.sum(d == 1)),
            "further": int(np.sum(np.abs(d) > 1)),
        }
    return out


def summarise(records: list[dict[str, Any]], profiles: list[str]) -> dict[str, Any]:
    """Per profile: overall, per terrain, per component bin; and the ranking's seconds per frame."""
    out: dict[str, Any] = {}
    for prof in profiles:
        recs = [r for r in records if r["profile"] == prof]
        terr = sorted({r["terrain"] for r in recs})
        bins: dict[str, Any] = {}
        for c, edges in COMPONENT_BINS.items():
            have = [r for r in recs if r[c] is not None]
            bins[c] = {}
            for lo, hi in zip(edges[:-1], (*edges[1:-1], float("inf"))):
                sel = [r for r in have if lo <= r[c] < hi]
                bins[c][f"{lo:g}-{hi:g}"] = _rates(sel)
        out[prof] = {
            "all": _rates(recs),
            "terrains": {t: _rates([r for r in recs if r["terrain"] == t]) for t in terr},
            "bins": bins,
            "skyline_ms": 1000 * float(np.mean([r["skyline_s"] for r in recs])) if recs else None,
            "associative_ms": 1000 * float(np.mean([r["associative_s"] for r in recs])) if recs else None,
        }
    return out


def tables(summary: dict[str, Any]) -> str:
    """The overall and per-terrain tables, then the component bins of each profile, as text."""
    lines = []
    profiles = list(summary)
    terrains = list(next(iter(summary.values()))["terrains"]) if summary else []
    head = f"{'profile':16s} {'frames':>6s} " + " ".join(f"{s:>13s}" for s in SOURCES) + "  ms assoc/sky"
    lines.append("top-1/top-5 by route point, all frames")
    lines.append(head)
    for p in profiles:
        a = summary[p]["all"]
        lines.append(
            f"{p:16s} {a['frames']:6d} "
            + " ".join(f"{a[s]['top1']:.3f}/{a[s]['top5']:.3f}".rjust(13) for s in SOURCES)
            + f"  {summary[p]['associative_ms']:.1f}/{summary[p]['skyline_ms']:.1f}"
        )
    lines.append("\nwrong first route points: behind (-1) / ahead (+1) / further")
    lines.append(f"{'profile':16s} " + " ".join(f"{s:>13s}" for s in SOURCES))
    for p in profiles:
        a = summary[p]["all"]
        lines.append(
            f"{p:16s} " + " ".join(f"{a[s]['behind']}/{a[s]['ahead']}/{a[s]['further']}".rjust(13) for s in SOURCES)
        )
    for t in terrains:
        lines.append(f"\n{t}: top-1/top-5")
        for p in profiles:
            a = summary[p]["terrains"].get(t)
            if a:
                lines.append(
                    f"{p:16s} {a['frames']:6d} "
                    + " ".join(f"{a[s]['top1']:.3f}/{a[s]['top5']:.3f}".rjust(13) for s in SOURCES)
                )
    for p in profiles:
        lines.append(f"\n{p}: top-1 {'/'.join(SOURCES)} (frames) by |component|")
        for c, bins in summary[p]["bins"].items():
            cells = [
                f"{b}: "
                + "/".join("-" if v[s]["top1"] is None else f"{v[s]['top1']:.2f}" for s in SOURCES)
                + f" ({v['frames']})"
                for b, v in bins.items()
            ]
            lines.append(f"  {c:18s} " + "  ".join(cells))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="tuning", choices=("tuning", "heldout", "fresh"))
    ap.add_argument("--profiles", nargs="*", default=list(DEFAULT_PROFILES), choices=sorted(ERROR_PROFILES))
    ap.add_argument("--kinds", nargs="*", default=None, help="sweep, drive, kidnap (default all)")
    ap.add_argument("--names", nargs="*", default=None, help="cases or terrains (default all)")
    ap.add_argument("--memory", type=json.loads, default=None, help="JSON fields replacing the scenario's memory's")
    ap.add_argument("--skyline", type=json.loads, default=None, help="JSON fields replacing the scenario's skyline's")
    ap.add_argument("--derotate", type=json.loads, default=None, help="JSON options of models.derotate.level_image")
    ap.add_argument(
        "--rolls", type=json.loads, default=None, help="JSON list: the memory's roll_search_deg ([0]: the plain match)"
    )
    ap.add_argument("--extra", action="store_true", help="tuning: with bench/tracking.py's extra tuning drives")
    ap.add_argument("--json-only", action="store_true")
    args = ap.parse_args(argv)
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else None
    t0 = time.time()
    res = run(
        args.split,
        args.profiles,
        kinds=args.kinds,
        names=args.names,
        memory=args.memory,
        skyline=args.skyline,
        derotate=args.derotate,
        rolls=args.rolls,
        extra=args.extra,
    )
    res["options"] = {
        "memory": args.memory,
        "skyline": args.skyline,
        "derotate": args.derotate,
        "rolls": args.rolls,
        "kinds": args.kinds,
        "extra": args.extra,
    }
    res["machine"] = {
        "load_at_start": load,
        "utc_start": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(t0)),
        "wall_s": time.time() - t0,
    }
    summary = res["summary"]
    print(json.dumps(res if args.json_only else {k: v for k, v in res.items() if k != "records"}, indent=1))
    if not args.json_only:
        print()
        print(
            f"split {args.split}, options {json.dumps(res['options'])}, load {load}, {res['machine']['utc_start']} UTC"
        )
        print(tables(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
