"""Setup benchmark: where the time of a route's setup goes per viewframe, before and after the
renderer's per-draw overhead was cut, measured in one run.

On a generated route (the ``bench/end_to_end.py`` scenario generator) it times, per viewframe,
every stage of the map's setup in this process:

* ``render``: the camera emulator's colour and segmentation passes (image, depth, mask);
* ``background``: the colour pass without landmarks (for the detectors), where a landmark is in view;
* ``describe``: the symbolic description (:func:`models.symbolic.describe`);
* ``skyline``: the skyline from the depth buffer (:func:`models.skyline.skyline_from_depth`);
* ``message``: the ``viewframe`` message built (:meth:`knowledge_sources.levels.Viewframe.of`),
  encoded and decoded (what the blackboard does with it);
* ``index``: the viewframe's memory pattern made and stored (:class:`models.index.ViewframeIndex`).

Two camera emulators of the same environment render every pose in turn, so both see the same
load: ``before`` with pyrender's own shader programs, renderer and scene pose lookup (what the
emulator did before: a uniform's location asked of GL and its value set at every draw, shader
defines rebuilt at every draw, node poses composed at every draw), ``after`` with the emulator
as it is. Their images, depth maps, masks and backgrounds are compared bit for bit. The speed-up
is before / after in this one run. With ``--workers K`` it also renders the whole route with
:func:`models.viewframes.render_viewframes` serially and in ``K`` worker processes (one EGL
context each), one after the other, and checks that both give the same viewframes.

Prints JSON, then a table.

    python bench/setup.py [--size 200] [--workers 2] [--json-only]
"""

from __future__ import annotations

import sys
from pathlib import Path

# bench/blackboard.py would shadow the blackboard package: drop this folder from the path
HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]
sys.path.insert(0, str(HERE.parent))

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import platform  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import pyrender  # noqa: E402
from pyrender.shader_program import ShaderProgramCache  # noqa: E402

STAGES = ("render", "background", "describe", "skyline", "message", "index")


def _make_scenario(n: int, folder: Path, frames: int) -> Path:
    spec = importlib.util.spec_from_file_location("end_to_end", HERE / "end_to_end.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.make_scenario(n, folder, frames=frames)


def _stock(emulator) -> None:
    """Turn an emulator back into what it was before the per-draw caches: pyrender's shader
    programs and renderer class, and pyrender's own scene pose lookup."""
    from models import camera_emulator

    inner = emulator._renderer._renderer
    inner.__class__ = pyrender.renderer.Renderer
    inner._program_cache = ShaderProgramCache(shader_dir=camera_emulator._lambert_shader_dir())

    class _StockPoses(camera_emulator._ActiveScene):
        def get_pose(self, node):
            return pyrender.Scene.get_pose(self, node)

    emulator.scene.__class__ = _StockPoses


def stages(path: Path) -> dict:
    """Per-stage seconds per viewframe, before and after, and whether their outputs agree."""
    from blackboard.codec import decode, encode
    from knowledge_sources import levels
    from models.camera_emulator import CameraEmulator
    from models.index import ViewframeIndex
    from models.skyline import skyline_from_depth
    from models.symbolic import describe
    from models.viewframes import Viewframe
    from models.world import World

    world = World.from_scenario(path, cache=None)
    scenario, env, poses = world.scenario, world.environment, world.poses
    fov, step = float(scenario.camera.fov_y_deg), scenario.skyline.step_deg
    emulators = {"before": CameraEmulator(env, scenario.camera), "after": CameraEmulator(env, scenario.camera)}
    _stock(emulators["before"])
    t = {name: {s: 0.0 for s in STAGES} for name in emulators}
    same = {"image": True, "depth": True, "mask": True, "background": True}
    for cam in emulators.values():  # warm-up: every tile mesh at every level the route needs uploaded
        for pose in poses[:: max(1, len(poses) // 20)]:
            cam.render(pose)
    viewframes: list[Viewframe] = []
    backgrounds = 0
    for pose in poses:
        views = {}
        for name, cam in emulators.items():
            t0 = time.perf_counter()
            view = cam.render(pose)
            t1 = time.perf_counter()
            bg = cam.render_background(pose) if (view.mask >= 0).any() else None
            t2 = time.perf_counter()
            t[name]["render"] += t1 - t0
            t[name]["background"] += t2 - t1
            views[name] = (view, bg)
        (vb, bb), (va, ba) = views["before"], views["after"]
        same["image"] &= bool(np.array_equal(vb.image, va.image))
        same["depth"] &= bool(np.array_equal(vb.depth, va.depth))
        same["mask"] &= bool(np.array_equal(vb.mask, va.mask))
        same["background"] &= (bb is None) == (ba is None) and (bb is None or bool(np.array_equal(bb, ba)))
        backgrounds += ba is not None
        t0 = time.perf_counter()
        desc = describe(va.mask, va.depth, env.landmarks, pose=pose, emulator=emulators["after"])
        t1 = time.perf_counter()
        sky = skyline_from_depth(va.depth, fov_y_deg=fov, step_deg=step)
        t2 = time.perf_counter()
        vf = Viewframe(len(viewframes), pose, va.image, va.depth, va.mask, desc, sky, ba)
        decode(encode(levels.Viewframe.of(vf).to_body()))
        t3 = time.perf_counter()
        for name in emulators:
            t[name]["describe"] += t1 - t0
            t[name]["skyline"] += t2 - t1
            t[name]["message"] += t3 - t2
        viewframes.append(vf)
    index = ViewframeIndex(scenario.memory)
    t0 = time.perf_counter()
    index.add((vf.image for vf in viewframes), (vf.index for vf in viewframes))
    index_s = time.perf_counter() - t0
    for name, cam in emulators.items():
        t[name]["index"] = index_s
        cam.close()
    world.close()
    n = len(poses)
    per_vf = {name: {s: v / n for s, v in stages_.items()} for name, stages_ in t.items()}
    for name in per_vf:
        per_vf[name]["total"] = sum(per_vf[name][s] for s in STAGES)
    return {"viewframes": n, "with_background": backgrounds, "s_per_viewframe": per_vf, "identical": same}


def parallel(path: Path, workers: int) -> dict:
    """The whole route rendered serially and in ``workers`` processes: seconds and equality."""
    from models.viewframes import render_viewframes, render_viewframes_parallel
    from models.world import World

    out: dict = {"workers": workers}
    results = {}
    world = World.from_scenario(path, cache=None)
    scenario, env, poses = world.scenario, world.environment, world.poses
    step = scenario.skyline.step_deg
    t0 = time.perf_counter()
    results["serial"] = render_viewframes(world.emulator, poses, skyline_step_deg=step)
    out["serial_s"] = time.perf_counter() - t0
    world.close()
    t0 = time.perf_counter()
    results["parallel"] = render_viewframes_parallel(
        env, scenario.camera, poses, workers=workers, skyline_step_deg=step
    )
    out["parallel_s"] = time.perf_counter() - t0
    a, b = results["serial"], results["parallel"]
    out["identical"] = len(a) == len(b) and all(
        x.index == y.index
        and x.pose == y.pose
        and np.array_equal(x.image, y.image)
        and np.array_equal(x.depth, y.depth)
        and np.array_equal(x.mask, y.mask)
        and np.array_equal(x.skyline, y.skyline, equal_nan=True)
        and x.description == y.description
        and ((x.background is None and y.background is None) or np.array_equal(x.background, y.background))
        for x, y in zip(a, b)
    )
    out["speedup"] = out["serial_s"] / out["parallel_s"]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=200, help="route points (viewframes), default 200")
    parser.add_argument("--workers", type=int, default=0, help="also time rendering in this many processes")
    parser.add_argument("--json-only", action="store_true")
    args = parser.parse_args(argv)
    results: dict = {
        "machine": {
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "load_avg_start": os.getloadavg(),
        },
        "size": args.size,
    }
    with tempfile.TemporaryDirectory() as tmp:
        path = _make_scenario(args.size, Path(tmp), 20)
        results["stages"] = stages(path)
        results["machine"]["load_avg_after_stages"] = os.getloadavg()
        if args.workers > 1:
            results["parallel"] = parallel(path, args.workers)
    results["machine"]["load_avg_end"] = os.getloadavg()
    print(json.dumps(results, indent=1))
    if not args.json_only:
        s = results["stages"]
        b, a = s["s_per_viewframe"]["before"], s["s_per_viewframe"]["after"]
        print(f"\n{s['viewframes']} viewframes ({s['with_background']} with a background), ms per viewframe")
        print(f"{'stage':<12} {'before':>8} {'after':>8} {'speed-up':>9}")
        for stage in (*STAGES, "total"):
            ratio = b[stage] / a[stage] if a[stage] > 0 else float("nan")
            print(f"{stage:<12} {b[stage] * 1e3:>8.1f} {a[stage] * 1e3:>8.1f} {ratio:>8.2f}x")
        print("identical: " + ", ".join(f"{k} {v}" for k, v in s["identical"].items()))
        if "parallel" in results:
            p = results["parallel"]
            print(
                f"whole route: serial {p['serial_s']:.1f} s, {p['workers']} workers {p['parallel_s']:.1f} s, "
                f"speed-up {p['speedup']:.2f}x, identical {p['identical']}"
            )
        m = results["machine"]
        print(f"load average {m['load_avg_start']} -> {m['load_avg_end']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
