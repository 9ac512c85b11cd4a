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

and, in child processes (one process per run, every agent in it), the whole mission with a trace.
By default (``--mission drive``) the camera frames are a *drive* (:func:`drive_scenario`):
``--frames`` consecutive frames along the start of the route, each posted once the previous
frame's track is out (the camera paced on answers, :class:`knowledge_sources.camera.Camera`), so
that the tracker and the track window apply as with a real camera; the cache (``--cache-dir``)
is filled by the first run, and frames/s and latency count from the first frame, i.e. from when
the map is up. Per run: frames/s, latency p50/p95, top-1 of the track and of the single-frame
decisions, each agent's CPU seconds per frame in its activations on the localization levels,
how many rankings were windowed; ``--variant block.field=value`` adds runs with other scenario
settings (a change turned off, for a ratio in one run); ``--profile DIR`` writes a cProfile per
agent; every drive mission also reports when the map was posted (``map_s``) and when the last
shard's index was (``indexed_s``: the map is up), and its peak RSS. ``--baseline DIR`` runs every
drive mission with that checkout's code too (e.g. a worktree of main), alternating with this one
``--repeat`` times, for a before and after in one run; ``--setup-only`` stops each mission once
the map is up (setup time and peak RSS of the setup alone). With ``--mission burst`` (the first version of this benchmark), frames at every
(route / frames)-th route point are posted at once, cold and warm: peak RSS (``ru_maxrss``), map
and setup time, frames/s and the trace file's size, once with the cache off (cold) and once with
a filled cache (warm).

Prints JSON, then a table.

With ``--holders``, who holds what in a whole mission (one child process, every agent in it, the
cache filled first): at the map, once indexed, and after the first and last position, the
numpy and bytes payload reachable from the node store and from each agent (its knowledge
source, its agenda), RSS split into anonymous / file-backed / shared memory, and the peak RSS;
``--baseline DIR`` runs the same child in another checkout too (e.g. main's), for a before and
after in one run. With ``--holders``, ``--cache-dir DIR`` keeps the viewframe cache there between runs (default: a
temporary folder), so a rerun skips rendering.

Or, with ``--banks-only``, the memory banks alone (random patterns, N=128, bank_size 2, spectrum
in complex128 and complex64), in fresh child processes.

    python bench/scale.py [--sizes 1000 2000] [--frames 20] [--no-mission] [--banks-only] [--json-only]
        [--mission drive|burst] [--no-components] [--cache-dir DIR] [--variant a.b=v ...] [--profile DIR]
        [--baseline DIR [--repeat N]] [--setup-only] [--holders [--baseline /work/main]]
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
import re  # noqa: E402
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
    out["cache_bytes_per_viewframe"] = sum(f.stat().st_size for f in cache.path(key).iterdir() if f.is_file()) / n
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


def _child(
    script: str,
    args: list[str],
    *,
    what: str,
    cwd: Path,
    timeout: float,
    env: dict | None = None,
    log: Path | None = None,
) -> dict:
    """Run ``script`` in a fresh Python (``-c``) and return the JSON of its last stdout line; its
    stderr goes to ``log`` when given; a failure raises naming ``what`` (and the log)."""
    done = subprocess.run(
        [sys.executable, "-c", script, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )
    if log is not None:
        log.write_text(done.stderr)
    if done.returncode != 0:
        where = f" ({log})" if log is not None else ""
        raise RuntimeError(f"{what} failed{where}: {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def banks(count: int) -> dict:
    """Memory of a BankedMemory of ``count`` random patterns (N=128, bank_size 2), per viewframe,
    with the spectrum in complex128 and in complex64: one fresh child process each."""
    out = {}
    for dtype in ("complex128", "complex64"):
        out[dtype] = _child(_BANKS, [str(count), dtype], what="bank measurement", cwd=HERE.parent, timeout=1800)
    return out


_CHILD = """
import cProfile, json, os, resource, sys, time
import knowledge_sources  # before numpy, as the command line imports it (a checkout's BLAS default applies)
import numpy as np
from knowledge_sources.mission import run_mission
opts = json.loads(sys.argv[3])
profiles = {}  # agent -> cProfile of its activations on the localization levels (not the map's)
busy = {}  # agent -> [wall seconds of those activations (profiled: with cProfile's overhead), count, CPU seconds]
from blackboard.agent import AgentRunner
plain = AgentRunner._run_one
def timed(self):
    level = self._agenda[0][2].hypothesis.level if self._agenda else None
    if level in ("viewframe", "map", "scenario", "index", None):
        return plain(self)
    prof = profiles.setdefault(self.name, cProfile.Profile()) if opts.get("profile") else None
    t, c = time.perf_counter(), time.thread_time()
    if prof is not None:
        prof.enable()
    try:
        return plain(self)
    finally:
        if prof is not None:
            prof.disable()
        b = busy.setdefault(self.name, [0.0, 0, 0.0])
        b[0] += time.perf_counter() - t
        b[1] += 1
        b[2] += time.thread_time() - c
AgentRunner._run_one = timed
t0 = time.perf_counter()
ranked = {}  # (source, shard) -> [viewframes ranked per ranking]
marks = {}  # "map_s": the map posted, "indexed_s": the last shard's index posted (s from t0)
indexed = set()
def peak_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
def seen(level, body, stamp):
    if level == "ranking":
        ranked.setdefault((body.get("source", "associative"), body["shard"]), []).append(len(body["viewframes"]))
    elif level == "viewframe" and "by_reference" not in marks:  # pixels in the message or in the cache entry
        marks["by_reference"] = body.get("entry") is not None
    elif level == "map":
        marks["map_s"] = time.perf_counter() - t0
        marks["viewframes"] = body["viewframes"]
        marks["shards"] = -(-body["viewframes"] // body["memory"]["shard_size"])
    elif level == "index":
        indexed.add(body["shard"])
        if len(indexed) == marks.get("shards"):
            marks["indexed_s"] = time.perf_counter() - t0
            if opts.get("setup_only"):  # the map is up: report and stop here (the trace ends here too)
                print(json.dumps({"peak_rss_mb": peak_mb(), "setup_s": marks["indexed_s"],
                                  "wall_s": marks["indexed_s"], **marks}), flush=True)
                os._exit(0)
res = run_mission(sys.argv[1], trace_path=sys.argv[2], paced=opts["paced"], on_hypothesis=seen)
if opts.get("results"):  # the mission's results file, frame by frame (as mapinterp run --out writes it)
    from knowledge_sources.results import write_results
    write_results(opts["results"], res)
if profiles:
    os.makedirs(opts["profile"], exist_ok=True)
    for name, prof in profiles.items():
        prof.dump_stats(os.path.join(opts["profile"], name + ".prof"))
wall = time.perf_counter() - t0
s = res["summary"]
lat = [f["latency_ms"] for f in res["frames"] if f["latency_ms"] is not None]
windows = [f for f in res["frames"] if f.get("state") == "tracking"]
print(json.dumps({"peak_rss_mb": peak_mb(), "wall_s": wall, **marks,
                  "setup_s": wall - (s["localization_s"] or 0.0), "frames": s["frames"], "top1": s["top1"],
                  "top1_frame_only": s["top1_frame_only"], "mean_error_m": s["mean_error_m"],
                  "tracking_frames": s["tracking"], "localization_s": s["localization_s"],
                  "frames_per_s": s["frames_per_s"], "latency_ms_p50": s["latency_ms_p50"],
                  "latency_ms_p95": float(np.percentile(lat, 95)) if lat else None,
                  "degraded": res["degraded"][:5],
                  "ranked_mean": {src: float(np.mean([x for (s, _), v in ranked.items() if s == src for x in v]))
                                  for src in {s for s, _ in ranked}},
                  # rankings of fewer viewframes than their shard's fullest (a track window)
                  "ranked_windowed": {src: int(sum(x < max(v) for (s, _), v in ranked.items() if s == src for x in v))
                                      for src in {s for s, _ in ranked}},
                  "agent_busy_s": {k: {"s": v[0], "activations": v[1], "cpu_s": v[2]} for k, v in sorted(busy.items())}}))
"""


def drive_scenario(path: Path, *, frames: int, overrides: dict[str, object] | None = None) -> Path:
    """A copy of the generated scenario ``path`` whose camera frames are a *drive*
    (:class:`models.scenario.DriveSpec`): ``frames`` consecutive frames from the start of the route,
    2 s apart at 8-20 m/s (16-40 m, about one route point of 25 m per frame), with the drive's
    lateral and heading errors; the same drive (seeded) at every route length, so routes that
    share their first rows (the generator's serpentine rows hold 160 points) share the frames'
    poses. ``overrides``: ``{"block.field": value}`` set in the copy (e.g. ``memory.window_route_points``)."""
    import yaml

    data = yaml.safe_load(path.read_text())
    data["sensor"] = {"simulate": {"drive": {"frames": frames, "start": 0.0}}}
    for dotted, value in (overrides or {}).items():
        block, _, name = dotted.partition(".")
        data.setdefault(block, {})[name] = value
    tag = "".join(f"-{k}={v}" for k, v in sorted((overrides or {}).items())).replace("/", "_")
    out = path.with_name(f"{path.stem}-drive{tag}.yaml")
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return out


def mission(
    path: Path,
    cache: str,
    trace: Path,
    *,
    paced: bool = False,
    profile: Path | None = None,
    setup_only: bool = False,
    checkout: Path | None = None,
) -> dict:
    """One whole mission in a child process (every agent in it); ``paced``: the camera posts
    each frame once the previous frame's track (tracking on) is posted, else all at once (burst);
    ``profile``: a folder for one cProfile per agent of its activations on the localization levels
    (camera frames onwards; each agent's own thread), and each agent's busy seconds in them;
    ``setup_only``: the child stops once every shard's index is posted (the map is up), reporting
    the setup time and the peak RSS until then; ``checkout``: run another checkout's code (e.g.
    main's, for a before and after; default this one). Besides ``setup_s`` (until the first
    frame) the result has ``map_s`` (the map posted) and ``indexed_s`` (the last index posted)."""
    cwd = (checkout or HERE.parent).resolve()
    env = {**os.environ, "MAPINTERP_CACHE": cache, "PYOPENGL_PLATFORM": "egl", "PYTHONPATH": str(cwd)}
    opts = {
        "paced": paced,
        "profile": None if profile is None else str(profile),
        "results": str(trace.with_suffix(".json")),
        "setup_only": setup_only,
    }
    out = _child(
        _CHILD,
        [str(path), str(trace), json.dumps(opts)],
        what=f"mission run ({cwd})",
        cwd=cwd,
        env=env,
        timeout=3600,
        log=trace.with_suffix(".log"),
    )
    out["trace_mb"] = trace.stat().st_size / MB
    out["load_avg"] = os.getloadavg()
    return out


def _override(text: str) -> tuple[str, object]:
    import yaml

    key, sep, value = text.partition("=")
    if not sep or "." not in key:
        raise argparse.ArgumentTypeError(f"{text!r}: expected block.field=value (YAML value)")
    return key, yaml.safe_load(value)


def _print_drives(n: str, r: dict) -> None:
    drives = {k: v for k, v in r.items() if k.startswith("mission drive")}
    if not drives:
        return
    if all("frames" not in m for m in drives.values()):  # --setup-only
        print(f"route of {n} viewframes, setup of drive missions (cache filled), until the map is up")
        head = ("run", "map s", "indexed s", "peak RSS MB", "by ref", "load")
        print(f"  {head[0]:<44}" + "".join(f"{h:>12}" for h in head[1:]))
        for label, m in drives.items():
            cells = (
                f"{m['map_s']:.1f}",
                f"{m['indexed_s']:.1f}",
                f"{m['peak_rss_mb']:.0f}",
                m.get("by_reference"),
                f"{m['load_avg'][0]:.1f}",
            )
            print(f"  {label[len('mission ') :]:<44}" + "".join(f"{c!s:>12}" for c in cells))
        return
    print(f"route of {n} viewframes, drive missions (paced on the track, cache filled)")
    head = ("run", "frames", "frames/s", "p50 ms", "p95 ms", "top-1", "frame-only", "tracking", "map s", "indexed s")
    head += ("setup s", "peak MB", "load")
    print(f"  {head[0]:<44}" + "".join(f"{h:>11}" for h in head[1:]))
    for label, m in drives.items():
        cells = (
            m["frames"],
            f"{m['frames_per_s']:.2f}" if m["frames_per_s"] else "-",
            f"{m['latency_ms_p50']:.0f}",
            f"{m['latency_ms_p95']:.0f}" if m["latency_ms_p95"] is not None else "-",
            f"{m['top1']:.1%}" if m["top1"] is not None else "-",
            f"{m['top1_frame_only']:.1%}" if m["top1_frame_only"] is not None else "-",
            m["tracking_frames"],
            f"{m['map_s']:.1f}" if "map_s" in m else "-",
            f"{m['indexed_s']:.1f}" if "indexed_s" in m else "-",
            f"{m['setup_s']:.0f}",
            f"{m['peak_rss_mb']:.0f}",
            f"{m['load_avg'][0]:.1f}",
        )
        print(f"  {label[len('mission ') :]:<44}" + "".join(f"{c!s:>11}" for c in cells))
    agents = sorted({a for m in drives.values() for a in m.get("agent_busy_s", {})})
    print("  CPU ms per frame of each agent's activations on the localization levels (run order as above):")
    for a in agents:
        per = [m["agent_busy_s"].get(a) for m in drives.values()]
        cells = [f"{x['cpu_s'] / mm['frames'] * 1000:.1f}" if x else "-" for x, mm in zip(per, drives.values())]
        print(f"    {a:<20}" + "".join(f"{c:>11}" for c in cells))
    for label, m in drives.items():
        print(
            f"  {label[len('mission ') :]}: viewframes ranked per ranking (mean) {m.get('ranked_mean')}, rankings windowed {m.get('ranked_windowed')}"
        )


_HOLDERS = """
import json, os, resource, sys, time
from collections import Counter
import numpy as np
import blackboard.runtime as rtm
from knowledge_sources.mission import run_mission

def status():
    out = {}
    for line in open("/proc/self/status"):
        if line.startswith(("VmRSS", "RssAnon", "RssFile", "RssShmem")):
            k, v = line.split(":")
            out[k] = round(int(v.split()[0]) / 1024, 1)
    return out

cap = {}
enter = rtm.Runtime.__enter__
def capture(self):
    cap["rt"] = self
    return enter(self)
rtm.Runtime.__enter__ = capture

def payload(obj, seen, depth=0):
    # bytes of numpy arrays (owning their data) and bytes objects reachable from obj, each once
    if depth > 12 or id(obj) in seen or isinstance(obj, (int, float, str, bool, type(None))):
        return 0
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return obj.nbytes if obj.flags.owndata else payload(obj.base, seen, depth + 1)
    if isinstance(obj, (bytes, bytearray)):
        return len(obj)
    if isinstance(obj, dict):
        return sum(payload(v, seen, depth + 1) for v in list(obj.values()))
    if isinstance(obj, (list, tuple, set, frozenset)):
        return sum(payload(v, seen, depth + 1) for v in list(obj))
    if type(obj).__module__.startswith(("zenoh", "threading", "queue", "logging", "_thread", "mmap")):
        return 0
    total = payload(getattr(obj, "__dict__", None), seen, depth + 1)
    for name in getattr(type(obj), "__slots__", ()):
        total += payload(getattr(obj, name, None), seen, depth + 1)
    return total

rows = []
def census(tag):
    rt, seen = cap["rt"], set()
    row = {"at": tag, **status(), "node store": payload(rt.node._store._entries, seen) / 2**20}
    for name, runner in sorted(rt._runners.items()):
        row[name] = (payload(runner.source, seen) + payload(runner._agenda, seen)) / 2**20
    rows.append(row)

counts = Counter()
frames = int(sys.argv[2])
def on_hypothesis(level, body, ts):
    counts[level] += 1
    c = counts[level]
    if level == "map" or (level == "index" and c == int(sys.argv[3])) or (level == "position" and c in (1, frames)):
        census(f"{level} {c}")

t0 = time.perf_counter()
res = run_mission(sys.argv[1], on_hypothesis=on_hypothesis)
print(json.dumps({"peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "wall_s": time.perf_counter() - t0, "top1": res["summary"]["top1"], "census": rows,
                  "frames": [[r.get("frame"), r.get("viewframe"), r.get("correct")] for r in res["frames"]]}))
"""


def holders(path: Path, cache: str, *, cwd: Path, frames: int) -> dict:
    """Who holds what in a whole mission of ``path`` (see the module docstring), run by the code
    of checkout ``cwd`` (its viewframe cache entry is filled by a first run if missing)."""
    import math

    from models.scenario import load_scenario

    scenario = load_scenario(path)
    shards = max(1, math.ceil(len(scenario.route) / scenario.memory.shard_size))
    env = {**os.environ, "MAPINTERP_CACHE": cache, "PYOPENGL_PLATFORM": "egl", "PYTHONPATH": str(cwd)}
    out: dict = {}
    for run in ("fill", "measured"):  # the first run fills the cache for this checkout's renderer
        out[run] = _child(
            _HOLDERS, [str(path), str(frames), str(shards)], what=f"holders run ({cwd})", cwd=cwd, env=env, timeout=7200
        )
    return out


def _print_holders(n: str, label: str, h: dict) -> None:
    m = h["measured"]
    print(
        f"route of {n} viewframes, {label}: peak RSS {m['peak_rss_mb']:.0f} MB (first run, filling the cache: "
        f"{h['fill']['peak_rss_mb']:.0f} MB), wall {m['wall_s']:.0f} s, top-1 {m['top1']}"
    )
    names = [k for k in m["census"][0] if k not in ("at",)]
    print("  " + " ".join(f"{k[:13]:>13}" for k in ["at", *names]))
    for row in m["census"]:
        print("  " + " ".join(f"{row['at']:>13}" if k == "at" else f"{row.get(k, 0):>13.1f}" for k in ["at", *names]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="*", default=[1000], help="route lengths (default 1000)")
    parser.add_argument("--frames", type=int, default=20, help="simulated camera frames per route")
    parser.add_argument("--no-mission", action="store_true", help="skip the whole-mission child runs")
    parser.add_argument(
        "--mission",
        choices=("drive", "burst"),
        default="drive",
        help="drive (default): --frames consecutive frames of a drive from the route's start, each posted once "
        "the previous frame's track is out, with a filled cache (a cold run first fills it); burst: frames at every "
        "(route / frames)-th route point posted at once, cold and warm",
    )
    parser.add_argument("--no-components", action="store_true", help="skip the in-process memory breakdown")
    parser.add_argument(
        "--profile",
        type=Path,
        default=None,
        help="drive: a cProfile per agent of the first drive mission, in this folder",
    )
    parser.add_argument(
        "--cache-dir",
        type=Path,
        default=None,
        help="the viewframe cache of the drive missions and of --holders (default: a temp folder)",
    )
    parser.add_argument(
        "--variant",
        type=_override,
        nargs="*",
        action="append",
        default=[],
        help="drive: also run the mission with these scenario settings (block.field=value ...), once per --variant",
    )
    parser.add_argument(
        "--banks-only",
        action="store_true",
        help="only the memory banks' bytes per viewframe (random patterns, no rendering)",
    )
    parser.add_argument("--json-only", action="store_true")
    parser.add_argument(
        "--keep",
        type=Path,
        default=None,
        help="write the generated scenarios, the missions' traces, results (.json) and logs (.log) in this "
        "folder and keep them (default: a temp folder, deleted)",
    )
    parser.add_argument(
        "--holders", action="store_true", help="only who holds what in a whole mission (a child process, cache filled)"
    )
    parser.add_argument(
        "--baseline",
        type=Path,
        help="also run with this checkout's code (e.g. a worktree of main): with --holders, its holders run; "
        "with drive missions, each drive mission alternating baseline and this checkout (--repeat times)",
    )
    parser.add_argument(
        "--repeat",
        type=int,
        default=1,
        help="drive: run each drive mission this many times (alternating with --baseline)",
    )
    parser.add_argument(
        "--setup-only",
        action="store_true",
        help="drive: each mission stops once the map is up (every shard's index posted): setup time and peak RSS "
        "until then",
    )
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
    if args.holders:
        with tempfile.TemporaryDirectory() as tmp:
            cache_root = args.cache_dir or Path(tmp) / "cache"
            for n in args.sizes:
                path = _make_scenario(n, Path(tmp), args.frames)
                r = {"after": holders(path, str(cache_root), cwd=HERE.parent, frames=args.frames)}
                if args.baseline is not None:
                    r["before"] = holders(path, str(cache_root), cwd=args.baseline.resolve(), frames=args.frames)
                    r["same_results"] = r["before"]["measured"]["frames"] == r["after"]["measured"]["frames"]
                results["routes"][str(n)] = r
        results["machine"]["load_avg_end"] = os.getloadavg()
        print(json.dumps(results, indent=1))
        if not args.json_only:
            for n, r in results["routes"].items():
                for label in ("before", "after"):
                    if label in r:
                        _print_holders(n, f"{label} ({'baseline' if label == 'before' else 'this checkout'})", r[label])
                if "same_results" in r:
                    print(f"  same results (frame, viewframe, correct) before and after: {r['same_results']}")
            print(f"load average {results['machine']['load_avg_start']} -> {results['machine']['load_avg_end']}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.keep is not None:
            args.keep.mkdir(parents=True, exist_ok=True)
            tmp = args.keep
        for n in args.sizes:
            path = _make_scenario(n, tmp, args.frames)
            cache_dir = tmp / f"cache{n}"
            r: dict = {}
            if not args.no_components:
                r["components"] = components(path, cache_dir)
            if not args.no_mission and args.mission == "burst":
                r["mission_cold"] = mission(path, "off", tmp / f"cold{n}.trace")
                r["mission_warm"] = mission(path, str(cache_dir), tmp / f"warm{n}.trace")
            elif not args.no_mission:
                drive_cache = str(args.cache_dir or cache_dir)
                runs = {"drive": {}}
                for variant in args.variant:
                    runs["drive " + " ".join(f"{k}={v}" for k, v in variant)] = dict(variant)
                checkouts: list[tuple[str, Path | None]] = [("", None)]
                if args.baseline is not None:
                    checkouts = [(" [baseline]", args.baseline), (" [this]", None)]
                for i, (label, overrides) in enumerate(runs.items()):
                    drive = drive_scenario(path, frames=args.frames, overrides=overrides)
                    prof = args.profile / str(n) if args.profile is not None and i == 0 else None
                    for rep in range(args.repeat):
                        for tag, checkout in checkouts:  # alternating: the same load on both
                            name = f"mission {label}{tag}" + (f" #{rep + 1}" if args.repeat > 1 else "")
                            # one trace and results file per mission (kept with --keep: compare them)
                            slug = re.sub(r"[^A-Za-z0-9=.-]+", "_", f"{n}{label}{tag}-{rep + 1}").strip("_")
                            r[name] = mission(
                                drive,
                                drive_cache,
                                tmp / f"drive{slug}.trace",
                                paced=True,
                                profile=prof if rep == 0 and checkout is None else None,
                                setup_only=args.setup_only,
                                checkout=checkout,
                            )
            results["routes"][str(n)] = r
    results["machine"]["load_avg_end"] = os.getloadavg()
    results["machine"]["peak_rss_bench_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps(results, indent=1))
    if not args.json_only:
        print()
        for n, r in results["routes"].items():
            _print_drives(n, r)
            if "components" not in r:
                continue
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
