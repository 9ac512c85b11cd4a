"""Stored indices (models/index_store.py): what a second run of a map saves by loading each
indexer shard's memory banks instead of indexing them again.

Two modes, each printing JSON then a table, with the UTC time and load average:

``--entry DIR --work DIR``: the shards of a viewframe cache entry (e.g. a 10,000-viewframe route
filled by ``bench/scale.py``), measured directly, without missions. The entry's ``meta.json`` and
``image.npy`` are hard-linked (else copied) into ``WORK/<entry name>/`` so the stored indices go
there, never into the entry read. The shards are those of a mission (``memory.shard_size``
consecutive route points each, seed = shard), with the default memory settings (or ``--memory``
JSON). Child processes, alternating: *build* (each shard indexed from the memory-mapped images,
as a miss does: seconds per shard; then stored: seconds per shard), *load* (each shard loaded:
seconds, resident memory after loading every shard and after one full ranking of each), again
*build* (indexing alone, not stored) and *load*. Rankings: the build child ranks a fixed query
pattern per shard (saved to a file) with the index it built and with the one it stored and
loaded back; every load child ranks the same patterns; all must be identical bit for bit.

``--route N --work DIR``: whole missions on a generated route of N viewframes (``bench/scale.py``'s
drive, ``--frames`` frames), all with the viewframe cache in ``WORK/cache``, filled first:
this checkout with no stored index (a miss: it indexes and stores), then alternating the
baseline (``--baseline-commit``, exported with ``git archive`` into WORK: the code before stored
indices, which indexes every run) and this checkout (a hit). Per run: setup seconds (until the
first frame), wall, peak RSS, whether the answers equal the baseline's, and the CPU seconds of
the indexer agents' threads on the viewframe messages (receiving, decoding, keeping the image)
and on the map (indexing or loading).

    python bench/index_store.py --entry /work/cache/scale10k/<key> --work /work/cache/me-10k
    python bench/index_store.py --route 2000 --work /work/cache/me-2k --baseline-commit a846c8d
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]
sys.path.insert(0, str(HERE.parent))

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

MB = 1024.0 * 1024.0

_SHARDS = """
import json, os, resource, sys, time
import numpy as np
from models.index import ViewframeIndex
from models.index_store import index_key, load_index, store_index
from models.scenario import MemorySpec
from models.viewframe_cache import entry_field, release_pages

def rss_mb():
    with open("/proc/self/status") as f:
        d = {l.split(":")[0]: int(l.split()[1]) for l in f if l.startswith(("VmRSS", "RssAnon", "RssFile"))}
    return {"rss_mb": d["VmRSS"] / 1024, "anon_mb": d["RssAnon"] / 1024, "file_mb": d["RssFile"] / 1024}

mode, entry, opts = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
spec = MemorySpec(**opts["memory"])
images = entry_field(entry, "image")
n = images.shape[0]
block = spec.shard_size
shards = max(1, -(-n // block))
members = [list(range(s * block, min(n, (s + 1) * block))) for s in range(shards)]
if opts.get("limit"):
    members = members[: opts["limit"]]
out = {"mode": mode, "shards": len(members), "viewframes": sum(map(len, members)), "per_shard": []}
queries = opts["queries"]
t_all = time.perf_counter()
indices = []
for s, mine in enumerate(members):
    key = index_key(spec, mine, seed=s, entry=entry)
    row = {"shard": s, "viewframes": len(mine)}
    if mode in ("build", "build+store"):
        t = time.perf_counter()
        index = ViewframeIndex(spec, seed=s)
        index.add((np.asarray(images[k]) for k in mine), mine)
        index.memory.ranking_matrix  # the last bank finalized: as ranked
        row["build_s"] = time.perf_counter() - t
        release_pages(images[k] for k in mine)
        pattern = index.pattern(images[mine[len(mine) // 2]])
        if mode == "build+store":
            np.save(os.path.join(queries, f"q{s}.npy"), pattern)
            t = time.perf_counter()
            assert store_index(index, entry, key, replace=True) is not None
            row["store_s"] = time.perf_counter() - t
            back = load_index(entry, key, spec, seed=s)
            a, b = index.rank_pattern(pattern), back.rank_pattern(pattern)
            row["loaded_back_identical"] = bool(np.array_equal(a.viewframes, b.viewframes)
                                                and np.array_equal(a.variances, b.variances))
            np.save(os.path.join(queries, f"r{s}.npy"), np.stack([a.viewframes.astype(np.float64), a.variances]))
        indices.append(None)  # built indices are dropped: the build child measures time, not memory
        del index
    else:
        t = time.perf_counter()
        index = load_index(entry, key, spec, seed=s)
        assert index is not None, f"shard {s}: no stored index"
        row["load_s"] = time.perf_counter() - t
        indices.append(index)
    out["per_shard"].append(row)
out["total_s"] = time.perf_counter() - t_all
if mode == "load":
    out["after_load"] = rss_mb()
    t = time.perf_counter()
    same = []
    for s, index in enumerate(indices):
        pattern = np.load(os.path.join(queries, f"q{s}.npy"))
        r = index.rank_pattern(pattern)
        want = np.load(os.path.join(queries, f"r{s}.npy"))
        same.append(bool(np.array_equal(r.viewframes, want[0].astype(np.int64)) and np.array_equal(r.variances, want[1])))
    out["rank_all_s"] = time.perf_counter() - t
    out["after_ranking"] = rss_mb()
    out["rankings_identical"] = all(same)
    out["rankings_compared"] = len(same)
out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(out))
"""


#: prepended to bench/scale.py's mission child: the CPU seconds of the indexer agents' threads on the
#: viewframe messages (receiving, decoding, keeping) and on the map (building), written to $INDEXER_CPU
_INDEXER_CPU = """
import atexit, json, os, time
from blackboard.agent import AgentRunner
_cpu = {"viewframe": 0.0, "map": 0.0, "viewframe_messages": 0}
_on_sample, _run = AgentRunner._on_sample, AgentRunner._run_one
def _sample(self, sample):
    if not self.name.startswith("indexer") or not str(sample.key_expr).split("/")[-2:-1] == ["viewframe"]:
        return _on_sample(self, sample)
    c = time.thread_time()
    try:
        return _on_sample(self, sample)
    finally:
        _cpu["viewframe"] += time.thread_time() - c
        _cpu["viewframe_messages"] += 1
def _one(self):
    level = self._agenda[0][2].hypothesis.level if self._agenda else None
    if not self.name.startswith("indexer") or level not in ("viewframe", "map"):
        return _run(self)
    c = time.thread_time()
    try:
        return _run(self)
    finally:
        _cpu[level] += time.thread_time() - c
AgentRunner._on_sample, AgentRunner._run_one = _sample, _one
atexit.register(lambda: open(os.environ["INDEXER_CPU"], "w").write(json.dumps(_cpu)))
"""


def _child(script: str, args: list[str], *, cwd: Path, env: dict | None = None, timeout: float = 7200) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", script, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )
    if done.returncode != 0:
        raise RuntimeError(f"child {args[:1]} failed: {done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _stamp() -> dict:
    return {"utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "load_avg": os.getloadavg()}


def _link_entry(entry: Path, work: Path) -> Path:
    """``WORK/<entry name>/`` holding the entry's meta.json and image.npy (hard links, else copies)."""
    mine = work / entry.name
    mine.mkdir(parents=True, exist_ok=True)
    for name in ("meta.json", "image.npy"):
        dst = mine / name
        if dst.exists():
            continue
        try:
            os.link(entry / name, dst)
        except OSError:
            shutil.copy2(entry / name, dst)
    return mine


def shards_mode(args: argparse.Namespace) -> dict:
    entry = _link_entry(args.entry.resolve(), args.work.resolve())
    queries = args.work.resolve() / "queries"
    queries.mkdir(exist_ok=True)
    opts = {"memory": json.loads(args.memory), "queries": str(queries), "limit": args.limit}
    runs = []
    for mode in ("build+store", "load", "build", "load"):
        r = _child(_SHARDS, [mode, str(entry), json.dumps(opts)], cwd=HERE.parent)
        r.update(_stamp())
        runs.append(r)
        print(f"{r['utc']} {mode}: {r['total_s']:.1f} s (load {r['load_avg']})", file=sys.stderr)
    return {"entry": str(args.entry), "runs": runs, "start": args.start}


def _print_shards(doc: dict) -> None:
    print(f"\nstored indices of {doc['entry']} (started {doc['start']['utc']}, load {doc['start']['load_avg']})")
    print(
        f"{'run':<12} {'UTC':<21} {'load avg':<18} {'shards':>6} {'total s':>8} {'s/shard':>8} "
        f"{'store s/shard':>13} {'RSS load MB':>12} {'RSS ranked MB':>14} {'(anon/file)':>14} {'identical':>9}"
    )
    for r in doc["runs"]:
        per = r["per_shard"]
        key = "load_s" if r["mode"] == "load" else "build_s"
        mean = sum(x[key] for x in per) / len(per)
        store = [x["store_s"] for x in per if "store_s" in x]
        ident = r.get("rankings_identical")
        if r["mode"] == "build+store":
            ident = all(x["loaded_back_identical"] for x in per)
        la = "/".join(f"{v:.1f}" for v in r["load_avg"])
        ranked = r.get("after_ranking")
        split = f"{ranked['anon_mb']:.0f}/{ranked['file_mb']:.0f}" if ranked else ""
        print(
            f"{r['mode']:<12} {r['utc']:<21} {la:<18} {r['shards']:>6} {r['total_s']:>8.2f} {mean:>8.3f} "
            f"{(sum(store) / len(store)) if store else float('nan'):>13.3f} "
            f"{r.get('after_load', {}).get('rss_mb', float('nan')):>12.0f} "
            f"{r.get('after_ranking', {}).get('rss_mb', float('nan')):>14.0f} "
            f"{split:>14} "
            f"{str(ident):>9}"
        )


def route_mode(args: argparse.Namespace) -> dict:
    import importlib.util

    spec = importlib.util.spec_from_file_location("scale", HERE / "scale.py")
    scale = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(scale)
    work = args.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    base = work / f"base-{args.baseline_commit}"
    if not base.exists():
        base.mkdir()
        archive = subprocess.run(
            ["git", "-C", str(HERE.parent), "archive", args.baseline_commit], check=True, capture_output=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", str(base)], input=archive, check=True)
    path = scale._make_scenario(args.route, work, args.frames)
    drive = scale.drive_scenario(path, frames=args.frames)
    cache = work / "cache"
    env = {**os.environ, "MAPINTERP_CACHE": str(cache), "PYOPENGL_PLATFORM": "egl"}

    def run(label: str, cwd: Path) -> dict:
        trace = work / f"{label}.trace"
        opts = {"paced": True, "profile": None, "results": str(trace.with_suffix(".json"))}
        cpu = work / f"{label}.cpu.json"
        r = scale._child(
            _INDEXER_CPU + scale._CHILD,
            [str(drive), str(trace), json.dumps(opts)],
            what=label,
            cwd=cwd,
            env={**env, "INDEXER_CPU": str(cpu)},
            timeout=3600,
            log=trace.with_suffix(".log"),
        )
        r.update(_stamp())
        r["indexer_cpu_s"] = json.loads(cpu.read_text())
        r["answers"] = [
            (f["frame"], f.get("viewframe")) for f in json.loads(trace.with_suffix(".json").read_text())["frames"]
        ]
        print(f"{r['utc']} {label}: setup {r['setup_s']:.1f} s (load {r['load_avg']})", file=sys.stderr)
        return r

    runs = {}
    if not any(cache.glob("*/meta.json")):
        runs["fill (this checkout, renders)"] = run("fill", HERE.parent)
    for entry in cache.glob("*/index"):
        shutil.rmtree(entry)  # this checkout's first run of the filled cache: no stored index yet
    runs["this, miss (indexes, stores)"] = run("miss", HERE.parent)
    for i in range(args.rounds):
        runs[f"baseline {i + 1} (indexes)"] = run(f"base{i + 1}", base)
        runs[f"this {i + 1} (stored index)"] = run(f"hit{i + 1}", HERE.parent)
    ref = runs["baseline 1 (indexes)"]["answers"]
    for r in runs.values():
        r["same_answers_as_baseline"] = r["answers"] == ref
        del r["answers"]
    return {
        "route": args.route,
        "frames": args.frames,
        "baseline": args.baseline_commit,
        "runs": runs,
        "start": args.start,
    }


def _print_route(doc: dict) -> None:
    print(f"\nwhole missions, route of {doc['route']} viewframes, {doc['frames']} drive frames, viewframe cache filled")
    print(
        f"{'run':<32} {'UTC':<21} {'load avg':<18} {'setup s':>8} {'wall s':>8} {'peak RSS MB':>11} {'same':>5} "
        f"{'indexers CPU s: viewframe msgs':>30} {'map (index)':>11}"
    )
    for label, r in doc["runs"].items():
        la = "/".join(f"{v:.1f}" for v in r["load_avg"])
        cpu = r["indexer_cpu_s"]
        print(
            f"{label:<32} {r['utc']:<21} {la:<18} {r['setup_s']:>8.1f} {r['wall_s']:>8.1f} "
            f"{r['peak_rss_mb']:>11.0f} {str(r['same_answers_as_baseline']):>5} "
            f"{cpu['viewframe']:>22.2f} ({cpu['viewframe_messages']:>5}) {cpu['map']:>11.2f}"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--entry", type=Path, help="a viewframe cache entry folder: measure its shards directly")
    parser.add_argument("--route", type=int, help="whole missions on a generated route of this many viewframes")
    parser.add_argument("--work", type=Path, required=True, help="a folder of this benchmark's own (cache, links)")
    parser.add_argument("--memory", default="{}", help="--entry: memory settings (JSON), default the schema's")
    parser.add_argument("--limit", type=int, default=None, help="--entry: only the first this many shards")
    parser.add_argument("--frames", type=int, default=20, help="--route: drive frames")
    parser.add_argument("--rounds", type=int, default=2, help="--route: baseline/this alternations")
    parser.add_argument("--baseline-commit", default="a846c8d", help="--route: the code before stored indices")
    parser.add_argument("--json-only", action="store_true")
    args = parser.parse_args(argv)
    if (args.entry is None) == (args.route is None):
        parser.error("give one of --entry and --route")
    args.start = _stamp()
    doc = shards_mode(args) if args.entry is not None else route_mode(args)
    doc["end"] = _stamp()
    print(json.dumps(doc, indent=1))
    if not args.json_only:
        (_print_shards if args.entry is not None else _print_route)(doc)
        print(f"ended {doc['end']['utc']}, load {doc['end']['load_avg']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
