"""``mapinterp run`` end to end on input cases users plausibly hand over, for one or more code trees.

It writes the cases into ``--out`` (each a scenario file with its data):

* camera frames on file of other sizes than the 160 x 120 camera, same lens: 1280 x 720 (16:9)
  and 720 x 960 (portrait), 10 frames near the route points of ``hills``
  (:func:`bench.frame_sizes.write_scenario`);
* the lon/lat GeoTIFF of ``jacksboro_geo`` as bundled, with a block of -32768 beside the route
  and no nodata value named, with the same block as NaN (nodata NaN), and in feet with the
  band's unit ``ft``;
* the contour lines of ``contours`` as bundled, with their height attribute named ``ELEV``, and
  as 3-D lines without an attribute;

then runs ``mapinterp run`` on each with every ``--code NAME=ROOT`` (a source tree whose
``knowledge_sources`` and ``models`` are imported, e.g. ``old=/tmp/old`` extracted with
``git archive <commit> | tar -x -C /tmp/old`` and ``new=.``), alternating per case, in this
virtual environment, and prints JSON and a table (exit status, top-1, top-1 of the single
frame alone, mean error, median heading error).

    python bench/input_cases.py --out /tmp/cases --code old=/tmp/old new=.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import yaml  # noqa: E402


def write_cases(out: Path) -> list[tuple[str, Path]]:
    import rasterio

    from bench.frame_sizes import write_scenario

    out.mkdir(parents=True, exist_ok=True)
    cases = []
    hills = str(ROOT / "scenarios" / "hills.yaml")
    for label, size, name in (
        ("16:9 frames 1280x720 (hills)", (1280, 720), "wide"),
        ("portrait frames 720x960 (hills)", (720, 960), "portrait"),
    ):
        path = write_scenario(hills, out / name, size, frames=10, seed=1005, jitter_m=1.0, jitter_deg=2.0)
        cases.append((label, path))

    geo = yaml.safe_load((ROOT / "scenarios" / "jacksboro_geo.yaml").read_text())
    tif = ROOT / "scenarios" / "data" / "jacksboro.tif"
    with rasterio.open(tif) as src:
        h, profile = src.read(1), src.profile
        r, c = src.index(-84.2335, 36.6060)  # beside the route's middle
    block = (slice(r - 6, r + 6), slice(c + 3, c + 12))
    holes = h.copy()
    holes[block] = -32768
    with rasterio.open(out / "untagged.tif", "w", **profile) as ds:
        ds.write(holes, 1)
    nan = h.astype(np.float32)
    nan[block] = np.nan
    with rasterio.open(out / "nan.tif", "w", **{**profile, "dtype": "float32", "nodata": float("nan")}) as ds:
        ds.write(nan, 1)
    with rasterio.open(out / "feet.tif", "w", **{**profile, "dtype": "float32"}) as ds:
        ds.write((h / 0.3048).astype(np.float32), 1)
        ds.units = ("ft",)
    for label, dem, name in (
        ("lon/lat DEM, as bundled", tif, "orig"),
        ("lon/lat DEM, -32768 holes, no nodata tag", out / "untagged.tif", "untagged"),
        ("lon/lat DEM, NaN holes, nodata NaN", out / "nan.tif", "nan"),
        ("lon/lat DEM in feet, band unit ft", out / "feet.tif", "feet"),
    ):
        doc = {**geo, "name": f"geo-{name}", "terrain": {"dem": str(dem)}, "sensor": {"simulate": {"stride": 3}}}
        doc.pop("expect", None)
        (out / f"geo_{name}.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
        cases.append((label, out / f"geo_{name}.yaml"))

    contours = yaml.safe_load((ROOT / "scenarios" / "contours.yaml").read_text())
    lines = json.loads((ROOT / "scenarios" / "data" / "contours.geojson").read_text())
    elev = json.loads(json.dumps(lines))
    for f in elev["features"]:
        f["properties"] = {"ELEV": f["properties"]["elevation"]}
    flat = json.loads(json.dumps(lines))
    for f in flat["features"]:
        z, g = f["properties"].pop("elevation"), f["geometry"]
        if g["type"] == "LineString":
            g["coordinates"] = [[x, y, z] for x, y, *_ in g["coordinates"]]
        else:
            g["coordinates"] = [[[x, y, z] for x, y, *_ in part] for part in g["coordinates"]]
    (out / "contours_ELEV.geojson").write_text(json.dumps(elev))
    (out / "contours_3d.geojson").write_text(json.dumps(flat))
    for label, file, name in (
        ("contours, as bundled", ROOT / "scenarios" / "data" / "contours.geojson", "orig"),
        ("contours, attribute ELEV", out / "contours_ELEV.geojson", "ELEV"),
        ("contours, 3-D lines, no attribute", out / "contours_3d.geojson", "3d"),
    ):
        terrain = {**contours["terrain"], "contours": str(file)}
        doc = {**contours, "name": f"contours-{name}", "terrain": terrain, "sensor": {"simulate": {"stride": 2}}}
        doc.pop("expect", None)
        (out / f"contours_{name}.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
        cases.append((label, out / f"contours_{name}.yaml"))
    return cases


def run_case(path: Path, code: Path, out: Path, cache: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(code), MAPINTERP_CACHE=cache)
    main = "import sys; from knowledge_sources.cli import console_main; sys.exit(console_main())"
    t0 = time.time()
    p = subprocess.run(
        [sys.executable, "-c", main, "run", str(path), "--out", str(out), "--no-progress"],
        cwd=code,
        env=env,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    row: dict = {"exit": p.returncode, "s": round(time.time() - t0, 1), "load": round(os.getloadavg()[0], 2)}
    if p.returncode in (0, 1) and out.exists():
        s = json.loads(out.read_text())["summary"]
        row.update(
            frames=s["frames"],
            top1=s["top1"],
            top1_frame_only=s["top1_frame_only"],
            mean_error_m=round(s["mean_error_m"], 1),
            median_heading_error_deg=s.get("median_heading_error_deg"),
        )
    else:
        lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
        row["error"] = lines[-1][:300] if lines else ""
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="folder for the cases and the results")
    ap.add_argument("--code", nargs="+", default=["new=."], help="NAME=ROOT source trees to run")
    ap.add_argument("--cache", default=os.environ.get("MAPINTERP_CACHE", "off"), help="viewframe cache folder")
    args = ap.parse_args()
    codes = [(n, Path(r).resolve()) for n, r in (c.split("=", 1) for c in args.code)]
    cases = write_cases(args.out)
    started, load = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), os.getloadavg()
    rows = []
    for label, path in cases:
        for name, root in codes:
            row = {
                "case": label,
                "code": name,
                **run_case(path, root, args.out / f"{path.stem}_{name}.json", args.cache),
            }
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    print(json.dumps({"utc": started, "load": load, "rows": rows}, indent=1))
    print(f"\n{started}, load {load[0]:.2f} at the start, {os.getloadavg()[0]:.2f} at the end")
    print("| case | code | exit | top-1 | top-1 frame only | mean error m | median heading error deg |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        if "top1" in r:
            print(
                f"| {r['case']} | {r['code']} | {r['exit']} | {r['top1']:.2f} | {r['top1_frame_only']:.2f} |"
                f" {r['mean_error_m']} | {r['median_heading_error_deg']:.2f} |"
            )
        else:
            print(f"| {r['case']} | {r['code']} | {r['exit']} | {r['error']} | | | |")


if __name__ == "__main__":
    main()
