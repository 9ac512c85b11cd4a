"""Scale benchmark: where the memory of a route's viewframes goes, and what the viewframe cache
saves, on generated routes (the ``bench/end_to_end.py`` scenario generator).

Per route length it measures, in this process:

* the world: resident memory (RSS) added by the environment model, by the camera emulator
  (pyrender's offscreen context and buffers) and by rendering the viewframes, and the viewframes'
  own array bytes (image, depth, mask, any other array field);
* the ``viewframe`` messages: encoded bytes per viewframe (what the node store keeps once per
  viewframe and what each subscribing agent receives and decodes);
* the memory banks of a :class:`~models.index.ViewframeIndex` with the scenario's memory settings
  (bytes allocated, traced with ``tracemalloc``);
* the viewframe cache: the entry's bytes on disk and the time to read it back;

and, in child processes (one process per run, every agent in it), the whole mission with a trace:
peak RSS (``ru_maxrss``), map and setup time, frames/s and the trace file's size, once with the
cache off (cold) and once with a filled cache (warm).

Prints JSON, then a table.

Or, with ``--banks-only``, the memory banks alone (random patterns, N=128, bank_size 2, spectrum
in complex128 and complex64), in fresh child processes.

    python bench/scale.py [--sizes 1000 2000] [--frames 20] [--no-mission] [--banks-only] [--json-only]
"""

from __future__ import annotations

import sys
from pathlib import Path

# bench/blackboard.py would shadow the blackboard package: drop this folder from the path
HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]
sys.path.insert(0, str(HERE.parent))

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import gc  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import platform  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402

import numpy as np  # noqa: E402

MB = 1024.0 * 1024.0


def rss_mb() -> float:
    """Current resident set size of this process (MB), from /proc."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / MB


def _make_scenario(n: int, folder: Path, frames: int) -> Path:
    import importlib.util

    spec = importlib.util.spec_from_file_location("end_to_end", HERE / "end_to_end.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.make_scenario(n, folder, frames=frames)


def components(path: Path, cache_dir: Path) -> dict:
    """The in-process breakdown of one route (see the module docstring)."""
    from blackboard.codec import encode
    from knowledge_sources import levels
    from models.index import ViewframeIndex
    from models.viewframe_cache import ViewframeCache
    from models.world import World

    out: dict = {}
    gc.collect()
    r0 = rss_mb()
    world = World.from_scenario(path, cache=None)
    t0 = time.perf_counter()
    _ = world.environment
    r1 = rss_mb()
    _ = world.emulator
    r2 = rss_mb()
    viewframes = world.viewframes
    _ = world.priors
    render_s = time.perf_counter() - t0
    r3 = rss_mb()
    n = len(viewframes)
    arrays = {  # optional arrays (a background only where a landmark is in view) count where present
        f.name: sum(a.nbytes for vf in viewframes if isinstance(a := getattr(vf, f.name), np.ndarray)) / n
        for f in dataclasses.fields(viewframes[0])
        if any(isinstance(getattr(vf, f.name), np.ndarray) for vf in viewframes)
    }
    out["viewframes"] = n
    out["render_workers"] = world.scenario.render.worker_count(n)
    out["render_s"] = render_s
    out["rss_environment_mb"] = r1 - r0
    out["rss_emulator_mb"] = r2 - r1
    out["rss_viewframes_mb"] = r3 - r2
    out["rss_per_viewframe_kb"] = (r3 - r2) * 1024 / n
    out["array_bytes_per_viewframe"] = arrays
    world.close()
    gc.collect()
    out["rss_after_closing_emulator_mb"] = rss_mb() - r0

    sizes = []
    for vf in viewframes[: min(n, 200)]:
        msg = levels.Viewframe.of(vf)
        sizes.append(len(encode(msg.to_body())))
    out["message_bytes_per_viewframe"] = float(np.mean(sizes))

    scenario = world.scenario
    tracemalloc.start()
    index = ViewframeIndex(scenario.memory)
    t0 = time.perf_counter()
    index.add((vf.image for vf in viewframes), (vf.index for vf in viewframes))
    index_s = time.perf_counter() - t0
    current, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    out["index_s"] = index_s
    out["bank_bytes_per_viewframe"] = current / n
    out["index_peak_mb"] = peak / MB
    out["memory_size"] = scenario.memory.size
    del index

    cache = ViewframeCache(cache_dir)
    from models.viewframe_cache import cache_key

    key = cache_key(scenario, world.environment.terrain, lod={})
    t0 = time.perf_counter()
    cache.store(key, viewframes)
    out["cache_store_s"] = time.perf_counter() - t0
    out["cache_bytes_per_viewframe"] = sum(f.stat().st_size for f in cache.path(key).iterdir()) / n
    del viewframes
    gc.collect()
    t0 = time.perf_counter()
    back = World.from_scenario(path, cache=cache).viewframes
    out["cache_load_s"] = time.perf_counter() - t0
    assert len(back) == n and cache.hits == 1
    return out


_BANKS = """
import json, os, sys, tracemalloc
import numpy as np
from models import associative
associative.SPECTRUM_DTYPE = np.dtype(sys.argv[2]).type
def rss():
    return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
rng = np.random.default_rng(0)
n, count = 128, int(sys.argv[1])
pats = [rng.standard_normal((n, n)).astype(np.float32) for _ in range(count)]
r0 = rss(); tracemalloc.start()
mem = associative.BankedMemory(n, bank_size=2, seed=0, key_method="phase", max_shift=(2, 16))
mem.write_many(pats, range(count))
written = tracemalloc.get_traced_memory()[0]
mem.rank(pats[3])
ranked = tracemalloc.get_traced_memory()[0]
tracemalloc.stop()
print(json.dumps({"traced_kb_per_vf_written": written / count / 1024, "traced_kb_per_vf_ranked": ranked / count / 1024,
                  "rss_kb_per_vf": (rss() - r0) / count / 1024}))
"""


def banks(count: int) -> dict:
    """Memory of a BankedMemory of ``count`` random patterns (N=128, bank_size 2), per viewframe,
    with the spectrum in complex128 and in complex64: one fresh child process each."""
    out = {}
    for dtype in ("complex128", "complex64"):
        done = subprocess.run(
            [sys.executable, "-c", _BANKS, str(count), dtype],
            cwd=HERE.parent,
            capture_output=True,
            text=True,
            timeout=1800,
        )
        if done.returncode != 0:
            raise RuntimeError(f"bank measurement failed: {done.stderr[-2000:]}")
        out[dtype] = json.loads(done.stdout.strip().splitlines()[-1])
    return out


_CHILD = """
import json, resource, sys, time
from knowledge_sources.mission import run_mission
t0 = time.perf_counter()
res = run_mission(sys.argv[1], trace_path=sys.argv[2])
wall = time.perf_counter() - t0
s = res["summary"]
print(json.dumps({"peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "wall_s": wall,
                  "setup_s": wall - (s["localization_s"] or 0.0), "frames": s["frames"], "top1": s["top1"],
                  "frames_per_s": s["frames_per_s"], "latency_ms_p50": s["latency_ms_p50"]}))
"""


def mission(path: Path, cache: str, trace: Path) -> dict:
    env = {**os.environ, "MAPINTERP_CACHE": cache, "PYOPENGL_PLATFORM": "egl"}
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, str(path), str(trace)],
        cwd=HERE.parent,
        env=env,
        capture_output=True,
        text=True,
        timeout=3600,
    )
    if done.returncode != 0:
        raise RuntimeError(f"mission run failed: {done.stderr[-2000:]}")
    out = json.loads(done.stdout.strip().splitlines()[-1])
    out["trace_mb"] = trace.stat().st_size / MB
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="*", default=[1000], help="route lengths (default 1000)")
    parser.add_argument("--frames", type=int, default=20, help="simulated camera frames per route")
    parser.add_argument("--no-mission", action="store_true", help="skip the whole-mission child runs")
    parser.add_argument(
        "--banks-only",
        action="store_true",
        help="only the memory banks' bytes per viewframe (random patterns, no rendering)",
    )
    parser.add_argument("--json-only", action="store_true")
    args = parser.parse_args(argv)
    results: dict = {
        "machine": {
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "load_avg_start": os.getloadavg(),
        },
        "routes": {},
    }
    if args.banks_only:
        results["banks"] = {str(n): banks(n) for n in args.sizes}
        results["machine"]["load_avg_end"] = os.getloadavg()
        print(json.dumps(results, indent=1))
        if not args.json_only:
            print(f"\n{'viewframes':>10} {'spectrum':>10} {'traced KB/vf':>13} {'+ ranking':>10} {'RSS KB/vf':>10}")
            for n, r in results["banks"].items():
                for dtype, x in r.items():
                    print(
                        f"{n:>10} {dtype:>10} {x['traced_kb_per_vf_written']:>13.0f} "
                        f"{x['traced_kb_per_vf_ranked']:>10.0f} {x['rss_kb_per_vf']:>10.0f}"
                    )
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for n in args.sizes:
            path = _make_scenario(n, tmp, args.frames)
            cache_dir = tmp / f"cache{n}"
            r = {"components": components(path, cache_dir)}
            if not args.no_mission:
                r["mission_cold"] = mission(path, "off", tmp / f"cold{n}.trace")
                r["mission_warm"] = mission(path, str(cache_dir), tmp / f"warm{n}.trace")
            results["routes"][str(n)] = r
    results["machine"]["load_avg_end"] = os.getloadavg()
    results["machine"]["peak_rss_bench_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps(results, indent=1))
    if not args.json_only:
        print()
        for n, r in results["routes"].items():
            c = r["components"]
            print(f"route of {n} viewframes (memory size {c['memory_size']})")
            rows = [
                ("environment model (RSS)", f"{c['rss_environment_mb']:.1f} MB", ""),
                ("camera emulator, pyrender (RSS)", f"{c['rss_emulator_mb']:.1f} MB", ""),
                (
                    "rendered viewframes (RSS)",
                    f"{c['rss_viewframes_mb']:.1f} MB",
                    f"{c['rss_per_viewframe_kb']:.0f} KB/vf",
                ),
            ]
            rows += [
                (f"  array {k}", f"{v * int(n) / MB:.1f} MB", f"{v / 1024:.0f} KB/vf")
                for k, v in c["array_bytes_per_viewframe"].items()
            ]
            rows += [
                (
                    "viewframe message (encoded)",
                    f"{c['message_bytes_per_viewframe'] * int(n) / MB:.1f} MB",
                    f"{c['message_bytes_per_viewframe'] / 1024:.0f} KB/vf",
                ),
                (
                    "memory banks",
                    f"{c['bank_bytes_per_viewframe'] * int(n) / MB:.1f} MB",
                    f"{c['bank_bytes_per_viewframe'] / 1024:.0f} KB/vf",
                ),
                (
                    "cache entry on disk",
                    f"{c['cache_bytes_per_viewframe'] * int(n) / MB:.1f} MB",
                    f"{c['cache_bytes_per_viewframe'] / 1024:.0f} KB/vf",
                ),
                ("render + describe", f"{c['render_s']:.1f} s", ""),
                ("index (preprocess + store)", f"{c['index_s']:.1f} s", ""),
                ("cache store / load", f"{c['cache_store_s']:.2f} s / {c['cache_load_s']:.2f} s", ""),
            ]
            for run in ("mission_cold", "mission_warm"):
                if run in r:
                    m = r[run]
                    rows.append(
                        (
                            f"{run}: peak RSS / setup / wall",
                            f"{m['peak_rss_mb']:.0f} MB",
                            f"{m['setup_s']:.1f} s / {m['wall_s']:.1f} s, trace {m['trace_mb']:.1f} MB, "
                            f"top-1 {m['top1']}",
                        )
                    )
            for a, b, cc in rows:
                print(f"  {a:<38} {b:>14}  {cc}")
        print(f"load average {results['machine']['load_avg_start']} -> {results['machine']['load_avg_end']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
