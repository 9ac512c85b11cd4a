"""Camera frames of other sizes and aspect ratios against the scenario camera's viewframes.

For each frame size it renders, at a jittered pose near every route point of a scenario (the
same lens: the camera's vertical field of view on a sensor of that size), a camera frame with
the scenario camera emulator, degrades it as :func:`models.sensor.degrade` does, and maps it
onto the scenario camera three ways:

* ``squeeze``: resized to the camera's width x height (what ``load_frame_image`` did before:
  the aspect ratio is not kept);
* ``fit``: :func:`models.sensor.fit_to_camera` (scaled by the focal lengths' ratio, cropped,
  border pixels replicated where the frame is narrower), the skyline from every column;
* ``fit_columns``: the same image, the skyline only from the columns the frame sees (what the
  camera posts as ``sensor_frame.columns`` and the skyline ranker honours);

and reports each way's top-1 (the frame's own route point ranked first) of the associative
memory (:class:`models.index.ViewframeIndex`) and of the skyline
(:func:`models.skyline.match_skylines`), and the mean absolute difference (gray levels) between
the mapped noise-free render and the same pose rendered at the camera's own size (inside the
columns the frame sees). No blackboard, no landmark verification.

    python bench/frame_sizes.py --scenario scenarios/hills.yaml --sizes 1280x720 720x960
    python bench/frame_sizes.py --write-scenario out/wide --size 1280x720 --frames 10

With ``--write-scenario DIR`` it writes instead a copy of the scenario whose ``sensor.frames``
are such frames as PNG files (with their truth), for ``mapinterp run DIR/scenario.yaml``.

Prints JSON, then a table.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

from models.camera_emulator import CameraEmulator  # noqa: E402
from models.index import ViewframeIndex  # noqa: E402
from models.scenario import SimulateSpec, load_scenario  # noqa: E402
from models.sensor import degrade, fit_to_camera  # noqa: E402
from models.skyline import match_skylines, skyline_from_image  # noqa: E402
from models.world import World  # noqa: E402

DEFAULT_SIZES = ["1280x720", "1920x1080", "641x479", "96x72", "720x960", "900x1000", "120x160"]


def _size(text: str) -> tuple[int, int]:
    w, h = text.lower().split("x")
    return int(w), int(h)


def _frames(world: World, size: tuple[int, int], *, seed: int, jitter_m: float, jitter_deg: float, every: int = 1):
    """(route point k, pose, degraded image, clean image) at a jittered pose near every ``every``-th point."""
    cam = world.scenario.camera
    spec = cam.model_copy(update={"width": size[0], "height": size[1]})
    rng = np.random.default_rng(seed)
    out = []
    with CameraEmulator(world.environment, spec) as em:
        for k, vf in enumerate(world.viewframes):
            if k % every:
                continue
            p = vf.pose
            x, y = p.x + rng.normal(0, jitter_m), p.y + rng.normal(0, jitter_m)
            pose = em.pose_at(x, y, p.heading_deg + rng.normal(0, jitter_deg))
            view = em.render(pose)
            image = degrade(view.image, depth=view.depth, spec=SimulateSpec(), rng=seed * 1000 + k)
            out.append((k, pose, image, view.image))
    return out


def measure(scenario_path: str, sizes: list[tuple[int, int]], *, seed: int, jitter_m: float, jitter_deg: float):
    with World.from_scenario(scenario_path) as world:
        cam = world.scenario.camera
        vfs = world.viewframes
        index = ViewframeIndex(world.scenario.memory)
        index.add([vf.image for vf in vfs], [vf.index for vf in vfs])
        skylines = np.stack([vf.skyline for vf in vfs])
        step = world.scenario.skyline.step_deg
        rows = []
        for size in sizes:
            t0 = time.perf_counter()
            frames = _frames(world, size, seed=seed, jitter_m=jitter_m, jitter_deg=jitter_deg)
            hits = {w: {"memory": 0, "skyline": 0} for w in ("squeeze", "fit", "fit_columns")}
            mad = {"squeeze": [], "fit": []}
            coverage = None
            with CameraEmulator(world.environment, cam) as own:
                for k, pose, image, clean in frames:
                    shrink = image.shape[0] > cam.height
                    squeezed = cv2.resize(
                        image, (cam.width, cam.height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
                    )
                    fitted, fit = fit_to_camera(image, width=cam.width, height=cam.height, fov_y_deg=cam.fov_y_deg)
                    coverage = fit.coverage
                    columns = fit.columns  # as the camera agent has them (models.sensor.frames_from_files)
                    for way, img, cols in (
                        ("squeeze", squeezed, None),
                        ("fit", fitted, None),
                        ("fit_columns", fitted, columns),
                    ):
                        if way != "fit_columns":
                            hits[way]["memory"] += index.rank(img).top(1)[0][0] == k
                        q = skyline_from_image(img, fov_y_deg=cam.fov_y_deg, step_deg=step, columns=cols)
                        err = match_skylines(q, skylines, step_deg=step).error
                        hits[way]["skyline"] += int(np.argmin(err)) == k
                    hits["fit_columns"]["memory"] = hits["fit"]["memory"]
                    want = own.render(pose).image
                    a, b = fit.valid_cols
                    mapped_clean, _ = fit_to_camera(clean, width=cam.width, height=cam.height, fov_y_deg=cam.fov_y_deg)
                    squeezed_clean = cv2.resize(clean, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
                    mad["fit"].append(float(np.abs(mapped_clean[:, a:b].astype(int) - want[:, a:b]).mean()))
                    mad["squeeze"].append(float(np.abs(squeezed_clean.astype(int) - want).mean()))
            n = len(frames)
            rows.append(
                {
                    "size": f"{size[0]}x{size[1]}",
                    "frames": n,
                    "coverage_rows_cols": list(coverage) if coverage else None,
                    "top1": {w: {s: v / n for s, v in h.items()} for w, h in hits.items()},
                    "mad_gray": {w: float(np.mean(v)) for w, v in mad.items()},
                    "seconds": round(time.perf_counter() - t0, 1),
                }
            )
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    return rows


def write_scenario(scenario_path: str, out: Path, size: tuple[int, int], *, frames: int, seed: int, **jitter) -> Path:
    """A copy of the scenario whose sensor.frames are ``frames`` PNG files of ``size``, with truth."""
    src = Path(scenario_path)
    data = yaml.safe_load(src.read_text())
    sc = load_scenario(src)
    for key in ("dem", "contours"):
        if key in data["terrain"]:
            data["terrain"][key] = str(getattr(sc.terrain, key))
    out.mkdir(parents=True, exist_ok=True)
    with World.from_scenario(src) as world:
        every = max(1, len(world.poses) // frames)
        shots = _frames(world, size, seed=seed, every=every, **jitter)[:frames]
    specs = []
    for k, pose, image, _ in shots:
        name = f"frame_{k:03d}.png"
        cv2.imwrite(str(out / name), np.ascontiguousarray(image[..., ::-1]))
        specs.append(
            {
                "image": name,
                "truth": {"x": round(pose.x, 2), "y": round(pose.y, 2), "heading_deg": round(pose.heading_deg, 2)},
            }
        )
    data["name"] = f"{data['name']}-{size[0]}x{size[1]}"
    data["sensor"] = {"frames": specs}
    data.pop("expect", None)
    path = out / "scenario.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="scenarios/hills.yaml")
    ap.add_argument("--sizes", nargs="+", default=DEFAULT_SIZES, help="frame sizes WxH")
    ap.add_argument("--seed", type=int, default=1005)
    ap.add_argument("--jitter-m", type=float, default=1.0)
    ap.add_argument("--jitter-deg", type=float, default=2.0)
    ap.add_argument("--write-scenario", type=Path, help="write a scenario with frames of --size instead")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--frames", type=int, default=10)
    args = ap.parse_args()
    jitter = {"jitter_m": args.jitter_m, "jitter_deg": args.jitter_deg}
    if args.write_scenario:
        path = write_scenario(
            args.scenario, args.write_scenario, _size(args.size), frames=args.frames, seed=args.seed, **jitter
        )
        print(path)
        return
    started = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    load = os.getloadavg()
    rows = measure(args.scenario, [_size(s) for s in args.sizes], seed=args.seed, **jitter)
    print(
        json.dumps({"scenario": args.scenario, "utc": started, "load": load, "seed": args.seed, "rows": rows}, indent=1)
    )
    print(f"\n{args.scenario}, seed {args.seed}, {started}, load {load[0]:.2f}")
    print(
        f"{'size':>10} {'cover':>11} {'n':>3} | memory top-1 squeeze fit | skyline top-1 squeeze fit fit+cols | MAD squeeze fit"
    )
    for r in rows:
        t, c = r["top1"], r["coverage_rows_cols"]
        print(
            f"{r['size']:>10} {c[0]:.2f}x{c[1]:.2f} {r['frames']:>3} | {t['squeeze']['memory']:>20.2f} {t['fit']['memory']:.2f} |"
            f" {t['squeeze']['skyline']:>21.2f} {t['fit']['skyline']:.2f} {t['fit_columns']['skyline']:8.2f} |"
            f" {r['mad_gray']['squeeze']:11.2f} {r['mad_gray']['fit']:.2f}"
        )


if __name__ == "__main__":
    main()
