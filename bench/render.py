"""Benchmark of the camera emulator: viewframes rendered per second at 160 x 120.

Run::

    /tmp/venv/bin/python bench/render.py              # every bundled scenario, 3 passes over the route
    /tmp/venv/bin/python bench/render.py --repeat 1 scenarios/hills.yaml

For each scenario, in one process and one run, two configurations render the viewframes of the
whole route (after one warm-up pass that builds and uploads the tile meshes it needs):

* ``lod`` - ours: 64-cell tiles, distance-chosen level of detail, frustum culling (defaults of
  :class:`models.environment.EnvironmentModel`);
* ``full`` - the baseline: the same tiles, culling and shader but every tile at full DEM
  resolution (``levels=1``).

A viewframe here is what :func:`models.viewframes.render_viewframes` makes (the loop below is
that function's, timed, with the triangle count): the colour pass, the segmentation pass (mask
and depth) and the symbolic description. The environment, emulator and route poses come from a
:class:`models.world.World` of the scenario. Reported per configuration:
``vf_per_s`` (viewframes per second over the timed passes), ``ms_per_vf``, ``triangles`` (mean
terrain triangles drawn per view), ``warmup_s`` (first pass, building meshes), and for ``lod``
the fidelity against ``full``: ``depth_err_m`` (median over views of the median |depth
difference| on ground pixels), ``depth_rel_p99`` (median over views of the 99th percentile of
the relative depth difference on ground pixels), ``mask_iou`` (landmark pixels, mean over views that have any)
and ``same_visible`` (fraction of views whose visible landmark set is identical). The ratio
``speedup`` = full ms / lod ms is measured in the same run.

Output: one JSON document on stdout and a table on stderr.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import sys
import time
from pathlib import Path

_HERE = Path(__file__).resolve().parent
sys.path[:] = [str(_HERE.parent)] + [p for p in sys.path if Path(p or ".").resolve() != _HERE] + [str(_HERE)]

import numpy as np  # noqa: E402

from models.camera_emulator import CameraEmulator  # noqa: E402
from models.scenario import load_scenario  # noqa: E402
from models.symbolic import describe  # noqa: E402
from models.terrain_sources import load_terrain  # noqa: E402
from models.world import World  # noqa: E402

log = logging.getLogger("bench.render")

BUNDLED = ["hills", "jacksboro", "contours"]


def _pass(cam: CameraEmulator, poses) -> tuple[float, list, int]:
    env = cam.environment
    views, tris = [], 0
    t0 = time.perf_counter()
    for p in poses:
        v = cam.render(p)
        d = describe(v.mask, v.depth, env.landmarks, pose=p, emulator=cam)
        views.append((v, d))
        tris += cam.triangles_last
    return time.perf_counter() - t0, views, tris // max(1, len(poses))


def bench_scenario(path: Path, repeat: int) -> dict:
    scenario = load_scenario(path)
    terrain = load_terrain(scenario.terrain, base_dir=scenario.base_dir, seed=scenario.seed)
    poses = None
    out: dict = {
        "scenario": scenario.name,
        "dem": list(terrain.shape),
        "size": f"{scenario.camera.width}x{scenario.camera.height}",
    }
    views: dict = {}
    for name, lod in (("lod", {}), ("full", {"levels": 1})):
        with World(scenario, terrain=terrain, **lod) as world:
            env, cam, poses = world.environment, world.emulator, world.poses
            warm, _, _ = _pass(cam, poses)
            total, tri = 0.0, 0
            for _ in range(repeat):
                dt, vs, tri = _pass(cam, poses)
                total += dt
            n = len(poses) * repeat
            out[name] = {
                "vf_per_s": round(n / total, 1),
                "ms_per_vf": round(1000 * total / n, 2),
                "triangles": tri,
                "warmup_s": round(warm, 2),
                "views": len(poses),
            }
            views[name] = vs
        out["full_dem_triangles"] = env.full_triangles
    errs, p99s, ious, same = [], [], [], []
    for (a, da), (b, db) in zip(views["lod"], views["full"]):
        ground = (a.mask < 0) & (b.mask < 0) & (a.depth > 0) & (b.depth > 0)
        if ground.any():
            rel = np.abs(a.depth[ground] - b.depth[ground]) / b.depth[ground]
            errs.append(float(np.median(np.abs(a.depth[ground] - b.depth[ground]))))
            p99s.append(float(np.percentile(rel, 99)))
        la, lb = a.mask >= 0, b.mask >= 0
        if (la | lb).any():
            ious.append(float(((a.mask == b.mask) & la).sum() / (la | lb).sum()))
        same.append(da.visible == db.visible)
    out["lod"].update(
        depth_err_m=round(float(np.median(errs)), 3),
        depth_rel_p99=round(float(np.median(p99s)), 4),
        mask_iou=round(float(np.mean(ious)), 3) if ious else None,
        same_visible=round(float(np.mean(same)), 3),
    )
    out["speedup"] = round(out["full"]["ms_per_vf"] / out["lod"]["ms_per_vf"], 2)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenarios", nargs="*", type=Path, help="scenario files (default: the bundled ones)")
    parser.add_argument("--repeat", type=int, default=3, help="timed passes over each route (default 3)")
    args = parser.parse_args(argv)
    paths = args.scenarios or [_HERE.parent / "scenarios" / f"{n}.yaml" for n in BUNDLED]
    results = [bench_scenario(p, args.repeat) for p in paths]
    doc = {
        "benchmark": "render",
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "gl": os.environ.get("PYOPENGL_PLATFORM"),
        },
        "goal_vf_per_s": 30,
        "results": results,
    }
    print(json.dumps(doc, indent=1))
    _table(results)
    return 0


def _table(results: list[dict]) -> None:
    cols = [
        "scenario",
        "dem",
        "config",
        "vf/s",
        "ms/vf",
        "triangles",
        "warmup_s",
        "depth_err_m",
        "depth_rel_p99",
        "mask_iou",
        "same_visible",
        "speedup",
    ]
    rows = []
    for r in results:
        for cfg in ("lod", "full"):
            c = r[cfg]
            rows.append(
                [
                    r["scenario"],
                    "x".join(map(str, r["dem"])),
                    cfg,
                    str(c["vf_per_s"]),
                    str(c["ms_per_vf"]),
                    str(c["triangles"]),
                    str(c["warmup_s"]),
                    str(c.get("depth_err_m", "")),
                    str(c.get("depth_rel_p99", "")),
                    str(c.get("mask_iou", "")),
                    str(c.get("same_visible", "")),
                    str(r["speedup"]) if cfg == "lod" else "",
                ]
            )
    try:
        from rich.console import Console
        from rich.table import Table
    except ImportError:  # pragma: no cover
        print("\t".join(cols), file=sys.stderr)
        for row in rows:
            print("\t".join(row), file=sys.stderr)
        return
    t = Table(title="viewframes rendered per second, 160x120, Mesa llvmpipe (EGL)")
    for c in cols:
        t.add_column(c, justify="right")
    for row in rows:
        t.add_row(*row)
    Console(stderr=True, width=160).print(t)


if __name__ == "__main__":
    sys.exit(main())
