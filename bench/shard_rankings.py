"""The associative indexer shards of a long route ranking camera frames in one process.

Measures, on the stored indices of a route (``bench/scale.py``'s generated routes, its viewframe
cache filled by a drive mission):

* CPU per frame (one thread) of a **full frame** (every shard through its coarse stage, as
  ``knowledge_sources.indexer`` ranks a frame without a track window: the frame's key, the
  ``memory.coarse_candidates`` best, the roll search among them) and of a **window** (``--window``
  route points across the first two shards' boundary, moving 10 a frame), with the memory's roll search
  (``memory.roll_search_deg``) and without it (``(0,)``);
* the **resident memory** of every shard ranking the same full frames at once in threads (as the
  agents of one process do, each with its own copy of the frame, each stored shard's rows given
  back after each ranking as the indexer does), all at once and at most ``MAPPED_RANKINGS`` at a
  time, with the roll search and without, each in a fresh process: the peak RSS over the level
  once the shards are loaded (sampled every 2 ms), and the wall time per frame;
* every ranking, with ``--dump OUT.npz``, for ``--compare A.npz B.npz``: the same viewframes in
  the same order, the variances' largest relative difference.

The code ranked is the installed package's, or another checkout's with ``PYTHONPATH=CHECKOUT``:
``--index-of CHECKOUT`` loads the stored indices that checkout's code built (a stored index is
keyed by the source of the indexing code, so each checkout has its own, built alike up to float
rounding), so that two checkouts rank the same index bytes. Indexing is not bitwise reproducible
(numpy's SIMD sums depend on where the arrays lie in memory), nor is preprocessing: two runs of
the same code differ by about 1e-7 in the variances. Prints JSON, then a table::

    python bench/shard_rankings.py --route OUT/route10000-drive.yaml --cache-dir CACHE [--frames 10] \\
        [--window 160] [--dump A.npz] [--index-of CHECKOUT] [--no-threads]
    python bench/shard_rankings.py --compare A.npz B.npz
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import mmap
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
# not this folder (bench/blackboard.py would hide the package); the package from where Python finds it
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as a mission runs (models/blas.py)

# isort: off
import knowledge_sources  # noqa: E402, F401  (the BLAS default before numpy, as the command line)
import numpy as np  # noqa: E402

# isort: on

#: the thread measurements, each in a fresh process: (roll search, at most MAPPED_RANKINGS at once)
THREAD_RUNS = {
    "roll, all at once": (True, False),
    "roll, bounded": (True, True),
    "plain, all at once": (False, False),
    "plain, bounded": (False, True),
}


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _use_index_of(checkout: Path) -> None:
    """Stored indices are looked up under ``checkout``'s indexing source (its digest is in their key)."""
    import models.index_store as store

    def digest() -> str:
        h = hashlib.sha256()
        for name in store.INDEX_MODULES:
            path = checkout / "models" / f"{name}.py"
            h.update(name.encode())
            h.update(path.read_bytes() if path.exists() else b"-")
        return h.hexdigest()

    store._source_digest = digest  # type: ignore[attr-defined]


def load(route: Path, cache_dir: Path, frames: int) -> tuple[Any, list, list[np.ndarray]]:
    """``(memory settings, [(index, coarse)] per shard, camera images)`` of the route: its stored
    shards (as the indexers load them; an error when one is missing) and its drive's first frames."""
    from models.coarse import MemoryCoarse
    from models.index_store import cached_index
    from models.scenario import load_scenario
    from models.viewframe_cache import ViewframeCache, release_pages
    from models.world import World

    scenario = load_scenario(route)
    with World(scenario, cache=ViewframeCache(cache_dir)) as world:
        views, entry = len(world.viewframes), world.entry
        images = [np.ascontiguousarray(f.image) for f in list(world.sensor_frames)[:frames]]
    mem = scenario.memory
    count = int(np.ceil(views / mem.shard_size))
    shards = []
    for s in range(count):
        mine = [k for k in range(views) if min(k // mem.shard_size, count - 1) == s]

        def missing(s: int = s) -> list:
            raise SystemExit(f"{route}: shard {s} has no stored index in {entry} (run a drive mission of it first)")

        index, _ = cached_index(entry, mem, mine, seed=s, images=missing)
        shards.append((index, MemoryCoarse(index.memory)))
        release_pages([index.memory.ranking_matrix], advice=mmap.MADV_DONTNEED)
    return mem, shards, images


def _with_rolls(shards: list, rolls: tuple[float, ...]) -> None:
    for index, _ in shards:
        index.settings = index.settings.model_copy(update={"roll_search_deg": rolls})


def _full(index: Any, coarse: Any, image: np.ndarray, k: int) -> Any:
    """A frame without a window, as the indexer ranks it (this checkout's query keys, or main's)."""
    if hasattr(index, "query_key"):
        return index.rank(image, among=coarse.candidates(index.query_key(image), k=k))
    pattern = index.pattern(image)
    return index.rank(image, among=coarse.candidates(index.memory.banks[0].query_key(pattern), k=k), pattern=pattern)


def cpu(mem: Any, shards: list, images: list[np.ndarray], *, window: int) -> tuple[dict, dict[str, np.ndarray]]:
    """CPU ms per frame (one thread) of a full frame (every shard) and of a window (two shards),
    and every ranking by name."""
    rankings: dict[str, np.ndarray] = {}
    t_full = t_window = 0.0
    for i, image in enumerate(images):
        t0 = time.process_time()
        full = [_full(index, coarse, image, mem.coarse_candidates) for index, coarse in shards]
        t1 = time.process_time()
        edge = int(shards[1][0].viewframes.min()) if len(shards) > 1 else 0  # across the first two shards
        among = np.arange(max(0, edge - window // 2 + 10 * i), edge + window - window // 2 + 10 * i)
        windows = [index.rank(image, among=among) for index, _ in shards[:2]]
        t_window += time.process_time() - t1
        t_full += t1 - t0
        for kind, parts in (("f", full), ("w", windows)):
            for s, r in enumerate(parts):
                rankings[f"{kind}{i}_s{s}_vf"], rankings[f"{kind}{i}_s{s}_var"] = r.viewframes, r.variances
    n = max(1, len(images))
    return {"full_ms": 1000 * t_full / n, "window_ms": 1000 * t_window / n}, rankings


def threads(mem: Any, shards: list, images: list[np.ndarray], *, at_once: int | None) -> dict:
    """Every shard ranking each full frame at once in threads (``at_once``: at most so many at a
    time, None: all): peak RSS over the level before (MB), wall s per frame."""
    from models.viewframe_cache import release_pages

    idle = _rss_mb()
    peak, stop = [idle], threading.Event()

    def sample() -> None:
        while not stop.is_set():
            peak[0] = max(peak[0], _rss_mb())
            time.sleep(0.002)

    barrier = threading.Barrier(len(shards))
    turn = threading.BoundedSemaphore(at_once) if at_once else contextlib.nullcontext()

    def work(index: Any, coarse: Any) -> None:
        for image in images:
            barrier.wait()
            own = image.copy()  # each agent decodes its own copy of the frame
            with turn:
                _full(index, coarse, own, mem.coarse_candidates)
                release_pages([index.memory.ranking_matrix], advice=mmap.MADV_DONTNEED)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    t0 = time.perf_counter()
    workers = [threading.Thread(target=work, args=shard) for shard in shards]
    for t in workers:
        t.start()
    for t in workers:
        t.join()
    wall = time.perf_counter() - t0
    stop.set()
    sampler.join()
    return {"peak_over_idle_mb": peak[0] - idle, "wall_s_per_frame": wall / max(1, len(images))}


def compare(a_path: Path, b_path: Path) -> dict:
    a, b = np.load(a_path), np.load(b_path)
    if sorted(a.files) != sorted(b.files):
        raise SystemExit(f"{a_path} and {b_path} hold other rankings (frames, shards or windows differ)")
    names = [k[:-3] for k in a.files if k.endswith("_vf")]
    order = [k for k in names if not np.array_equal(a[k + "_vf"], b[k + "_vf"])]
    same = [k for k in names if k not in order]
    bitwise = sum(np.array_equal(a[k + "_var"], b[k + "_var"]) for k in same)
    rel = max(
        (
            float(np.max(np.abs(a[k + "_var"] - b[k + "_var"]) / np.abs(a[k + "_var"])))
            for k in same
            if a[k + "_var"].size
        ),
        default=0.0,
    )
    return {
        "rankings": len(names),
        "order_differs": order,
        "variances_bitwise_equal": int(bitwise),
        "max_rel_diff": rel,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--route", type=Path, help="a generated route's drive scenario (bench/scale.py --keep)")
    parser.add_argument("--cache-dir", type=Path, help="the viewframe cache holding its entry and stored indices")
    parser.add_argument("--frames", type=int, default=10, help="the drive's first frames ranked")
    parser.add_argument("--window", type=int, default=160, help="route points of the windowed rankings")
    parser.add_argument("--dump", type=Path, help="write every ranking (with the roll search) to this .npz")
    parser.add_argument("--index-of", type=Path, help="load the stored indices this checkout's code built")
    parser.add_argument("--no-threads", action="store_true", help="skip the threads' resident memory")
    parser.add_argument("--compare", type=Path, nargs=2, metavar=("A", "B"), help="compare two --dump files")
    parser.add_argument("--threads-child", choices=sorted(THREAD_RUNS), help=argparse.SUPPRESS)  # one thread run
    args = parser.parse_args(argv)
    if args.compare:
        out = compare(*args.compare)
        print(json.dumps(out, indent=1))
        print(
            f"{out['rankings']} rankings: order differs in {len(out['order_differs'])}, variances bitwise equal in "
            f"{out['variances_bitwise_equal']}, largest relative difference {out['max_rel_diff']:.1e}"
        )
        return 1 if out["order_differs"] else 0
    if args.route is None or args.cache_dir is None:
        parser.error("--route and --cache-dir are needed (or --compare A B)")
    if args.frames < 1 or args.window < 1:
        parser.error("--frames and --window must be >= 1")
    if args.index_of is not None:
        _use_index_of(args.index_of.resolve())
    import models
    from knowledge_sources.indexer import MAPPED_RANKINGS

    mem, shards, images = load(args.route, args.cache_dir, args.frames)
    rolls = tuple(mem.roll_search_deg)
    if args.threads_child is not None:
        roll, bounded = THREAD_RUNS[args.threads_child]
        _with_rolls(shards, rolls if roll else (0.0,))
        print(json.dumps(threads(mem, shards, images, at_once=MAPPED_RANKINGS if bounded else None)))
        return 0
    out: dict[str, Any] = {
        "code": str(Path(models.__file__).resolve().parent.parent),
        "route": str(args.route),
        "shards": len(shards),
        "frames": len(images),
        "window": args.window,
        "load_avg": os.getloadavg(),
    }
    for label, r in (("roll search", rolls), ("no roll search", (0.0,))):
        _with_rolls(shards, r)
        t, rankings = cpu(mem, shards, images, window=args.window)
        out[label] = {"rolls": list(r), **t}
        if r == rolls and args.dump is not None:
            np.savez(args.dump, **rankings)
    if not args.no_threads:  # each in a fresh process: what one leaves allocated would hide the next's
        base = [
            sys.executable,
            str(Path(__file__).resolve()),
            "--route",
            str(args.route),
            "--cache-dir",
            str(args.cache_dir),
        ]
        base += ["--frames", str(args.frames)] + ([] if args.index_of is None else ["--index-of", str(args.index_of)])
        out["threads"] = {}
        for name in THREAD_RUNS:
            done = subprocess.run([*base, "--threads-child", name], capture_output=True, text=True, check=False)
            if done.returncode != 0:
                raise SystemExit(f"threads ({name}) failed:\n{done.stderr[-2000:]}")
            out["threads"][name] = json.loads(done.stdout.strip().splitlines()[-1])
    out["load_avg_end"] = os.getloadavg()
    print(json.dumps(out, indent=1))
    print(f"\n{out['shards']} shards, {out['frames']} frames, code {out['code']}; CPU ms per frame, one thread")
    print(f"{'':16} {'full frame':>10} {'window':>7}")
    for label in ("roll search", "no roll search"):
        print(f"{label:16} {out[label]['full_ms']:10.1f} {out[label]['window_ms']:7.1f}")
    if "threads" in out:
        print(f"every shard ranking each full frame in threads (MAPPED_RANKINGS = {MAPPED_RANKINGS}):")
        print(f"{'':20} {'peak RSS over idle MB':>21} {'wall s/frame':>12}")
        for name, r in out["threads"].items():
            print(f"{name:20} {r['peak_over_idle_mb']:21.0f} {r['wall_s_per_frame']:12.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
