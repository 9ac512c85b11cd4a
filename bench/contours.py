"""Contour lines to DEM: how close the interpolated DEM is to the true one, and to its skyline.

Each terrain (the tuning split's contour terrain, the tuning ridged terrain, and procedural
terrains of this script's own seeds; never a held-out terrain) is turned into contour lines
every ``--interval`` metres by :func:`models.contours.dem_to_contours`, and back into a DEM by
each method (``tin``: :func:`models.contours.contours_to_tin`, the former interpolation;
``thin-plate``: :func:`models.contours.contours_to_dem`, today's). Against the true DEM:

* ``rms_m`` / ``max_m``: height error over the map (a 3-cell border left out),
* ``ridge_m`` / ``valley_m``: mean error (signed, interpolated minus true) on ridge cells / valley
  cells (the 10 % of cells most above / below their 3-cell Gaussian neighbourhood),
* ``sky_deg``: mean absolute difference of the skyline (elevation angle of the horizon, per
  azimuth bin of 1 degree over the viewframes' +-29 degrees) seen 2 m above the ground from every
  route point in 8 headings, the interpolated DEM's (eye on its ground) against the true one's;
  ``sky_px``: the same in pixels of the 160x120 viewframes (f = 144.9 px), ``sky_gt1px``: the
  share of bins more than one pixel off,
* ``seconds``: time of the interpolation.

``--localize CASE ...`` instead runs evaluation cases (e.g. ``h-contours-ridged``) through
:func:`bench.single_frame.run` twice in this one process, the scenario's terrain built by each
method (``models.terrain_sources.contours_to_dem`` replaced for the first): single-frame
top-1 and the rest of :data:`bench.single_frame.COLUMNS`, side by side.

Prints JSON, then a table.

``--report-heldout`` adds the held-out contour terrain, to report on after the choice (never
to choose by). ``--jitter`` moves every contour vertex by Gaussian noise (a digitised map's error).

    python bench/contours.py [--interval 10] [--terrains t-contours-fbm own-ridged-1 ...]
        [--methods tin thin-plate:stiffness=0.01 ...] [--jitter 3] [--report-heldout] [--json-only]
    python bench/contours.py --localize h-contours-ridged [--split heldout]
"""

from __future__ import annotations

import sys
from pathlib import Path

_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import os  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import replace  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from scipy.ndimage import gaussian_filter, map_coordinates  # noqa: E402

from bench.evalset.cases import TERRAINS, _heights, _route, _route_headings  # noqa: E402
from models.contours import ContourLine, contours_to_dem, contours_to_tin, dem_to_contours  # noqa: E402
from models.terrain import Terrain  # noqa: E402

#: focal length in pixels of the viewframes (160x120, fov_y 45 degrees)
F_PX = 60.0 / math.tan(math.radians(22.5))
HALF_FOV_X = 29.0
EYE = 2.0


def _terrains(heldout: bool = False) -> dict[str, tuple[np.ndarray, float, list[tuple[float, float]]]]:
    """name -> (true heights, cell metres, route); tuning entries and this script's own seeds;
    ``heldout`` adds the held-out contour terrain (to report on, never to choose by)."""
    base = {t.name: t for t in TERRAINS if t.split == "tuning"}
    # this script's own terrains: (name, seed, source, changes to the t-contours-fbm case)
    specs = [
        ("own-ridged-1", 9101, {"family": "ridged", "size": 200, "relief": 120.0}, {}),
        ("own-ridged-2", 9102, {"family": "ridged", "size": 200, "relief": 160.0}, {}),
        ("own-fbm-0.5", 9103, {"family": "fbm", "size": 200, "relief": 150.0, "hurst": 0.5}, {}),
        ("own-mesas", 9105, {"family": "mesas", "size": 200, "relief": 90.0}, {"cell": 12.0}),
        ("own-valleys", 9104, {"family": "valleys", "size": 200, "relief": 90.0}, {"cell": 10.0}),
    ]
    own = {
        name: replace(base["t-contours-fbm"], name=name, seed=seed, source=source, **more)
        for name, seed, source, more in specs
    }
    out = {}
    extra = [t for t in TERRAINS if heldout and t.split == "heldout" and t.contours > 0]
    for t in [base["t-contours-fbm"], base["t-ridged"], *own.values(), *extra]:
        h = _heights(t)
        out[t.name] = (h, t.cell, _route(t, h))
    return out


def horizon(heights: np.ndarray, cell: float, x: float, y: float, heading_deg: float) -> np.ndarray:
    """Elevation angle (degrees) of the skyline per 1-degree azimuth bin over +-HALF_FOV_X, seen
    EYE metres above the ground at world (x, y) looking along ``heading_deg`` (ccw from +x);
    NaN where the ray meets no terrain. Heights bilinear, nothing beyond the map."""
    rows, cols = heights.shape
    az = np.radians(heading_deg + np.arange(-HALF_FOV_X, HALF_FOV_X + 1.0))
    far = math.hypot(rows, cols) * cell
    d = np.arange(max(5.0, cell / 2), far, cell / 2)
    px = x + np.cos(az)[:, None] * d[None, :]
    py = y + np.sin(az)[:, None] * d[None, :]
    u, v = px / cell, py / cell
    inside = (u >= 0) & (u <= cols - 1) & (v >= 0) & (v <= rows - 1)
    z = map_coordinates(heights, [v.ravel(), u.ravel()], order=1, mode="nearest").reshape(u.shape)
    z0 = float(map_coordinates(heights, [[y / cell], [x / cell]], order=1, mode="nearest")[0]) + EYE
    ang = np.where(inside, np.degrees(np.arctan2(z - z0, d[None, :])), -np.inf)
    best = ang.max(axis=1)
    return np.where(np.isfinite(best), best, np.nan)


def measure(truth: np.ndarray, dem: np.ndarray, cell: float, route: list[tuple[float, float]]) -> dict[str, float]:
    inner = np.s_[3:-3, 3:-3]
    err = (dem - truth)[inner]
    relief = (truth - gaussian_filter(truth, 3.0, mode="nearest"))[inner]
    ridge, valley = relief >= np.quantile(relief, 0.9), relief <= np.quantile(relief, 0.1)
    pts = np.asarray(route)
    heads = _route_headings(pts)
    diffs = []
    for (x, y), h in zip(pts, heads):
        for turn in range(0, 360, 45):
            a = horizon(truth, cell, x, y, h + turn)
            b = horizon(dem, cell, x, y, h + turn)
            ok = np.isfinite(a) & np.isfinite(b)
            diffs.append(np.abs(a - b)[ok])
    sky = np.concatenate(diffs)
    px = np.radians(sky) * F_PX
    return {
        "rms_m": float(np.sqrt(np.mean(err**2))),
        "max_m": float(np.abs(err).max()),
        "ridge_m": float(err[ridge].mean()),
        "valley_m": float(err[valley].mean()),
        "sky_deg": float(sky.mean()),
        "sky_px": float(px.mean()),
        "sky_gt1px": float(np.mean(px > 1.0)),
    }


def _value(text: str) -> Any:
    try:
        return float(text)
    except ValueError:
        return text


METHODS: dict[str, Callable[..., Terrain]] = {"tin": contours_to_tin, "thin-plate": contours_to_dem}


def run(
    names: list[str] | None, interval: float, methods: list[str], jitter: float = 0.0, heldout: bool = False
) -> list[dict[str, Any]]:
    rows = []
    rng = np.random.default_rng(9100)
    for name, (truth, cell, route) in _terrains(heldout).items():
        if names and name not in names:
            continue
        lines: list[ContourLine] = dem_to_contours(Terrain(heights=truth, cell_size=cell), interval=interval)
        if jitter > 0:  # digitising error: every vertex moved by a Gaussian of jitter metres, kept on the map
            hi = (np.array(truth.shape[::-1]) - 1) * cell
            lines = [(np.clip(p + rng.normal(0.0, jitter, p.shape), 0.0, hi), e) for p, e in lines]
        for m in methods:
            t0 = time.perf_counter()
            name_, _, opts = m.partition(":")
            kw = {k: _value(v) for k, v in (o.split("=") for o in opts.split(",") if o)}
            dem = METHODS[name_](lines, cell_size=cell, shape=truth.shape, **kw).heights
            secs = time.perf_counter() - t0
            rows.append(
                {
                    "terrain": name,
                    "method": m,
                    "cells": int(truth.size),
                    "seconds": secs,
                    **measure(truth, dem, cell, route),
                }
            )
            print(f"# {name} {m} {secs:.1f}s", file=sys.stderr)
    return rows


def localize(names: list[str], split: str) -> list[dict[str, Any]]:
    """Single-frame measures of the cases ``names`` with the DEM from the TIN, then from today's method."""
    import models.terrain_sources as sources
    from bench import single_frame

    out = []
    for label, fn in (("tin", contours_to_tin), ("thin-plate", contours_to_dem)):
        sources.contours_to_dem = fn  # type: ignore[assignment]
        t0 = time.perf_counter()
        res = single_frame.run(split, names=names)
        out.append({"method": label, "seconds": time.perf_counter() - t0, **res["all"]})
        print(f"# localize {label} {time.perf_counter() - t0:.0f}s", file=sys.stderr)
    sources.contours_to_dem = contours_to_dem
    return out


COLS = ["rms_m", "max_m", "ridge_m", "valley_m", "sky_deg", "sky_px", "sky_gt1px", "seconds"]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--interval", type=float, default=10.0)
    ap.add_argument("--terrains", nargs="*")
    ap.add_argument(
        "--methods",
        nargs="*",
        default=list(METHODS),
        help="METHOD[:key=value,...], METHOD one of " + ", ".join(METHODS),
    )
    ap.add_argument("--jitter", type=float, default=0.0, help="metres of Gaussian noise on every contour vertex")
    ap.add_argument("--localize", nargs="*", help="evaluation cases to localize with each method")
    ap.add_argument("--split", default="heldout")
    ap.add_argument("--report-heldout", action="store_true", help="also the held-out contour terrain (report only)")
    ap.add_argument("--json-only", action="store_true")
    args = ap.parse_args(argv)
    started = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    load = [round(v, 2) for v in os.getloadavg()]
    if args.localize:
        res = localize(args.localize, args.split)
        print(
            json.dumps(
                {
                    "started": started,
                    "host": platform.node(),
                    "load_start": load,
                    "cases": args.localize,
                    "load_end": [round(v, 2) for v in os.getloadavg()],
                    "rows": res,
                },
                indent=1,
            )
        )
        if not args.json_only:
            keys = [k for k in res[0] if k not in ("method",)]
            print("| method | " + " | ".join(keys) + " |")
            print("|---|" + "---|" * len(keys))
            for r in res:
                print(
                    f"| {r['method']} | "
                    + " | ".join(
                        "-" if r[k] is None else f"{r[k]:.3f}" if isinstance(r[k], float) else str(r[k]) for k in keys
                    )
                    + " |"
                )
        return
    rows = run(args.terrains, args.interval, args.methods, args.jitter, args.report_heldout)
    print(
        json.dumps(
            {
                "started": started,
                "host": platform.node(),
                "load": load,
                "interval": args.interval,
                "jitter": args.jitter,
                "rows": rows,
            },
            indent=1,
        )
    )
    if args.json_only:
        return
    print("| terrain | method | " + " | ".join(COLS) + " |")
    print("|---|---|" + "---|" * len(COLS))
    for r in rows:
        print(
            f"| {r['terrain']} | {r['method']} | "
            + " | ".join(f"{r[c]:.3f}" if c == "sky_gt1px" else f"{r[c]:.2f}" for c in COLS)
            + " |"
        )


if __name__ == "__main__":
    main()
