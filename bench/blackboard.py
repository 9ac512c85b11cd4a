"""Benchmark of the blackboard: post-to-delivery latency and sustained throughput, against bare
zenoh put/subscribe of the same payloads in the same run.

Ours: a producer knowledge source posts hypotheses (``board.post``) whose body carries the
post time (``time.monotonic_ns``, system-wide on Linux) and ``size`` bytes of data; a consumer
knowledge source measures the delay when its ``act`` starts (after decoding, the agenda and
the precondition). The node (router) stores every hypothesis. In ``processes`` mode producer
and consumer are two more OS processes (the bare producer stays in the bench process).

Bare zenoh: the same topology (a router session, a producer client, a consumer client), the
same payload size, ``put`` with blocking congestion control, a callback that enqueues and a
worker thread that measures, as our agents do.

Latency: posts paced by ``--gap-us``; throughput: posts as fast as possible, counted until the
consumer has received the last one. Run from the repository root:

    python bench/blackboard.py [--quick] [--json-only]
"""

from __future__ import annotations

import sys
from pathlib import Path

_HERE = Path(__file__).resolve().parent
# running as a script puts bench/ first on sys.path, where this file would shadow the package
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
if str(_HERE.parent) not in sys.path:
    sys.path.insert(0, str(_HERE.parent))

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import platform  # noqa: E402
import queue  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
import uuid  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import zenoh  # noqa: E402

from blackboard.config import ZenohOptions, loopback_endpoint, open_session, zenoh_config  # noqa: E402
from blackboard.knowledge_source import Board, Event, KnowledgeSource  # noqa: E402
from blackboard.runtime import Runtime  # noqa: E402

__all__ = ["Producer", "Consumer", "main"]


class Producer(KnowledgeSource):
    """On 'go' {n, size, gap_s}: posts n 'item' hypotheses {t, i, data}."""

    consumes = ("go",)
    produces = ("item",)

    def act(self, event: Event, board: Board) -> None:
        body = event.hypothesis.body
        data, gap = bytes(int(body["size"])), float(body["gap_s"])
        for i in range(int(body["n"])):
            board.post("item", {"t": time.monotonic_ns(), "i": i, "data": data})
            if gap:
                time.sleep(gap)


class Consumer(KnowledgeSource):
    """Records post-to-act delays; writes them to options['out'] at shutdown (if given)."""

    consumes = ("item",)

    def setup(self, board: Board) -> None:
        self.delays_ns: list[int] = []
        self.first_t = 0
        self.last_recv = 0

    def act(self, event: Event, board: Board) -> None:
        now = time.monotonic_ns()
        body = event.hypothesis.body
        self.delays_ns.append(now - body["t"])
        if body["i"] == 0:
            self.first_t = body["t"]
        self.last_recv = now

    def results(self) -> dict[str, Any]:
        return {"delays_ns": self.delays_ns, "first_t": self.first_t, "last_recv": self.last_recv}

    def shutdown(self) -> None:
        if self.options.get("out"):
            Path(self.options["out"]).write_text(json.dumps(self.results()))


def _ours(mode: str, n: int, size: int, gap_s: float) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "consumer.json")
        with Runtime(run_id=f"bench-{uuid.uuid4().hex[:8]}", mode=mode) as rt:
            if mode == "inprocess":
                rt.add(Producer, name="producer")
                rt.add(Consumer, name="consumer")
            else:
                rt.add("bench.blackboard:Producer", name="producer")
                rt.add("bench.blackboard:Consumer", name="consumer", options={"out": out})
            rt.post("go", {"n": n, "size": size, "gap_s": gap_s})
            rt.run(timeout_s=600)
            results = rt.source("consumer").results() if mode == "inprocess" else None
        if results is None:
            results = json.loads(Path(out).read_text())
    return results


def _bare_consumer(endpoint: str, key: str, n: int, ready: Any, results: dict[str, Any]) -> None:
    session = open_session(zenoh_config(ZenohOptions(), mode="client", connect=[endpoint]))
    inbox: queue.SimpleQueue = queue.SimpleQueue()
    sub = session.declare_subscriber(key, lambda s: inbox.put(s))
    ready()
    delays: list[int] = []
    first_t = last = 0
    for i in range(n):
        payload = inbox.get().payload.to_bytes()
        now = time.monotonic_ns()
        t = int.from_bytes(payload[:8], "little")
        delays.append(now - t)
        if i == 0:
            first_t = t
        last = now
    results.update(delays_ns=delays, first_t=first_t, last_recv=last)
    sub.undeclare()
    session.close()


def _bare(mode: str, n: int, size: int, gap_s: float) -> dict[str, Any]:
    endpoint = loopback_endpoint()
    key = f"mapinterp/bench-{uuid.uuid4().hex[:8]}/item/x"
    router = open_session(zenoh_config(ZenohOptions(listen=[endpoint]), mode="router"))
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bare.json"
        if mode == "inprocess":
            started = threading.Event()
            worker = threading.Thread(target=_bare_consumer, args=(endpoint, key, n, started.set, results))
            worker.start()
            started.wait(30)
        else:
            child = subprocess.Popen(
                [sys.executable, __file__, "--bare-consumer", endpoint, key, str(n), str(out)],
                stdout=subprocess.PIPE,
                text=True,
            )
            assert child.stdout is not None and child.stdout.readline().strip() == "ready"
        producer = open_session(zenoh_config(ZenohOptions(), mode="client", connect=[endpoint]))
        time.sleep(0.2)  # the subscriber's declaration reaches the producer through the router
        pad = bytes(max(0, size - 8))
        for _ in range(n):
            producer.put(
                key, time.monotonic_ns().to_bytes(8, "little") + pad, congestion_control=zenoh.CongestionControl.BLOCK
            )
            if gap_s:
                time.sleep(gap_s)
        if mode == "inprocess":
            worker.join(600)
        else:
            child.wait(600)
            child.stdout.close()
            results = json.loads(out.read_text())
        producer.close()
    router.close()
    return results


def _stats(results: dict[str, Any], n: int) -> dict[str, float]:
    delays = np.asarray(results["delays_ns"], dtype=np.float64) / 1e6
    if len(delays) != n:
        raise RuntimeError(f"received {len(delays)} of {n}")
    span_s = (results["last_recv"] - results["first_t"]) / 1e9
    return {
        "p50_ms": float(np.percentile(delays, 50)),
        "p99_ms": float(np.percentile(delays, 99)),
        "per_s": n / span_s if span_s > 0 else float("inf"),
    }


def run(*, quick: bool = False) -> list[dict[str, Any]]:
    """Every case: (mode, size) x (latency, throughput) x (ours, bare)."""
    rows = []
    for mode in ("inprocess", "processes"):
        for size, n_lat, n_thr, gap in ((1024, 2000, 10_000, 200e-6), (100 * 1024, 300, 1000, 2e-3)):
            if quick:
                n_lat, n_thr = n_lat // 5, n_thr // 5
            row: dict[str, Any] = {"mode": mode, "size_bytes": size, "n_latency": n_lat, "n_throughput": n_thr}
            for name, fn in (("ours", _ours), ("bare", _bare)):
                lat = _stats(fn(mode, n_lat, size, gap), n_lat)
                thr = _stats(fn(mode, n_thr, size, 0.0), n_thr)
                row[name] = {
                    "p50_ms": lat["p50_ms"],
                    "p99_ms": lat["p99_ms"],
                    "per_s": thr["per_s"],
                    "burst_p50_ms": thr["p50_ms"],
                }
            row["latency_ratio_p50"] = row["ours"]["p50_ms"] / row["bare"]["p50_ms"]
            row["throughput_ratio"] = row["bare"]["per_s"] / row["ours"]["per_s"]
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    return rows


def _table(rows: list[dict[str, Any]]) -> str:
    head = (
        f"{'mode':<10} {'size':>6} | {'ours p50':>9} {'p99':>8} {'hyp/s':>8} | {'bare p50':>9} {'p99':>8} "
        f"{'msg/s':>8} | {'lat x':>6} {'thr x':>6}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        o, b = r["ours"], r["bare"]
        lines.append(
            f"{r['mode']:<10} {r['size_bytes'] // 1024:>4}KB | {o['p50_ms']:>7.3f}ms {o['p99_ms']:>6.3f}ms "
            f"{o['per_s']:>8.0f} | {b['p50_ms']:>7.3f}ms {b['p99_ms']:>6.3f}ms {b['per_s']:>8.0f} | "
            f"{r['latency_ratio_p50']:>6.2f} {r['throughput_ratio']:>6.2f}"
        )
    lines.append("lat x = ours p50 / bare p50; thr x = bare msg/s / ours hyp/s (overhead ratios, 1.0 = none)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a fifth of the messages")
    parser.add_argument("--json-only", action="store_true")
    parser.add_argument("--bare-consumer", nargs=4, metavar=("ENDPOINT", "KEY", "N", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.bare_consumer:
        endpoint, key, n, out = args.bare_consumer
        results: dict[str, Any] = {}
        _bare_consumer(endpoint, key, int(n), lambda: print("ready", flush=True), results)
        Path(out).write_text(json.dumps(results))
        return 0
    load_before = os.getloadavg()[0]
    rows = run(quick=args.quick)
    report = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "zenoh": getattr(zenoh, "__version__", "?"),
            # the machine is shared: its load says how far absolute numbers can be trusted
            "load_1min_before_after": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        },
        "rows": rows,
    }
    print(json.dumps(report, indent=2))
    if not args.json_only:
        print(_table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
