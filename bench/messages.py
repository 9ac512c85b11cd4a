"""Cost of the typed level messages against the codec on the hot path.

For the messages that travel per camera frame (sensor_frame, ranking, query, answer, position)
and the viewframe, times ``Message(...)`` + ``to_body()`` (what a poster does) and
``from_body()`` (what a consumer does) against ``encode`` + ``decode`` of the same body, which
every message pays anyway. Prints JSON, then a table.

    python bench/messages.py [--repeat N] [--size 160x120] [--viewframes 512]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if sys.path and Path(sys.path[0]).resolve() == ROOT / "bench":
    sys.path[0] = str(ROOT)  # bench/blackboard.py would shadow the blackboard package

import numpy as np  # noqa: E402

from blackboard.codec import decode, encode  # noqa: E402
from knowledge_sources import levels  # noqa: E402


def _per_call_us(fn: Callable[[], Any], repeat: int) -> float:
    fn()
    best = float("inf")
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(repeat):
            fn()
        best = min(best, (time.perf_counter() - start) / repeat)
    return best * 1e6


def samples(width: int, height: int, viewframes: int) -> dict[str, levels.Message]:
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    return {
        "sensor_frame": levels.SensorFrame(frame=3, image=image, source="simulated"),
        "viewframe": levels.Viewframe(
            index=3,
            pose=[1.0, 2.0, 2.0, 90.0, 0.0],
            image=image,
            mask=np.full((height, width), -1, np.int16),
            description={"visible": ["H1", "T1"], "relations": [["H1", "left-of", "T1"]]},
            skyline=np.zeros(width // 2, np.float32),
        ),
        "viewframe (ref)": levels.Viewframe(  # the pixels in the cache entry it names (a warm run's)
            index=3,
            pose=[1.0, 2.0, 2.0, 90.0, 0.0],
            skyline=np.zeros(width // 2, np.float32),
            entry="/home/user/.cache/mapinterp/" + "0" * 64,
            entry_count=viewframes,
        ),
        "ranking": levels.Ranking(
            frame=3,
            frame_time=1.0,
            shard=0,
            shards=1,
            viewframes=list(range(viewframes)),
            variances=[float(v) for v in rng.random(viewframes)],
            reliability=2.0,
        ),
        "query": levels.Query(frame=3, number=1, landmark="H1", landmark_index=0, kind="house", viewframe=2, p=0.7),
        "answer": levels.Answer(
            query="q-000003-1",
            frame=3,
            landmark="H1",
            viewframe=2,
            present=True,
            score=0.8,
            location=[10.0, 20.0],
            detector="edges",
            reason="edges match",
        ),
        "position": levels.Position(
            frame=3,
            viewframe=2,
            position=[1.0, 2.0],
            heading_deg=90.0,
            confidence=0.9,
            queries=1,
            backtracks=0,
            latency_ms=30.0,
            ranking=[[2, 1e-5]] * 5,
            reason="accepted",
            degraded=[],
            steps=[{"landmark": "H1", "present": True}],
            strategy="associative",
        ),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=2000)
    parser.add_argument("--size", default="160x120", help="image WIDTHxHEIGHT")
    parser.add_argument("--viewframes", type=int, default=512, help="entries of a ranking")
    args = parser.parse_args(argv)
    width, height = (int(v) for v in args.size.split("x"))
    rows = []
    for level, message in samples(width, height, args.viewframes).items():
        cls = type(message)
        body = message.to_body()
        fields = {name: getattr(message, name) for name in body}
        wire = encode(body)
        decoded = decode(wire)
        make = _per_call_us(lambda: cls(**fields).to_body(), args.repeat)  # noqa: B023
        read = _per_call_us(lambda: cls.from_body(decoded), args.repeat)  # noqa: B023
        codec = _per_call_us(lambda: decode(encode(body)), args.repeat)  # noqa: B023
        rows.append(
            {
                "level": level,
                "bytes": len(wire),
                "make_to_body_us": make,
                "from_body_us": read,
                "codec_us": codec,
                "overhead": (make + read) / codec,
            }
        )
    print(json.dumps({"size": [width, height], "ranking_entries": args.viewframes, "rows": rows}))
    print(
        f"{'level':15} {'bytes':>8} {'make+to_body us':>16} {'from_body us':>13} {'encode+decode us':>17} "
        f"{'typed/codec':>12}"
    )
    for r in rows:
        print(
            f"{r['level']:15} {r['bytes']:8d} {r['make_to_body_us']:16.2f} {r['from_body_us']:13.2f} "
            f"{r['codec_us']:17.2f} {r['overhead']:12.2f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
