"""A trace in the Chrome trace-event format, which ui.perfetto.dev and chrome://tracing open.

A pure function from trace records (:func:`blackboard.trace.read_trace`) to the JSON object
format of the trace-event specification::

    {"traceEvents": [...], "displayTimeUnit": "ms", "otherData": {"run_id": ...}}

* one process (``pid`` 1, named after the run), one thread per agent (``tid`` 1, 2, ... in order
  of first appearance, named by ``thread_name`` metadata events; the node's own events are on
  ``tid`` 0, "blackboard");
* each activation is a complete slice (``ph: "X"``, ``ts`` and ``dur`` in microseconds since the
  first record) named ``level <- event`` with the hypothesis id, version and rating in ``args``;
  failed activations are slices in the category ``activation_error``;
* each post and update is an instant event (``ph: "i"``, thread scope) with its id, version,
  links and a short body; agent joins, leaves, deaths, timeouts and rejections are instant events
  too, run start, quiescence and run end global ones (``s: "g"``);
* each link of a post (the hypothesis it was derived from) is a flow: ``ph: "s"`` at the
  linked hypothesis's post, ``ph: "f"`` (``bp: "e"``) at the new post, sharing a flow ``id``.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from blackboard.trace import TraceRecord
from blackboard.trace_view import jsonable

__all__ = ["to_chrome_trace", "chrome_trace_json"]

_PID = 1
_GLOBAL = {"run_start", "run_end", "quiescent"}
_BODY_CHARS = 200


def _short(value: Any) -> Any:
    text = json.dumps(value, default=repr, sort_keys=True)
    return value if len(text) <= _BODY_CHARS else text[: _BODY_CHARS - 3] + "..."


def to_chrome_trace(records: Sequence[TraceRecord]) -> dict[str, Any]:
    """The trace-event JSON object of ``records`` (see the module docstring)."""
    times = [float(r["t"]) for r in records if isinstance(r.get("t"), (int, float))]
    t0 = min(times) if times else 0.0
    start = next((r for r in records if r.get("kind") == "run_start"), {})
    run_id = start.get("run_id") or "run"

    tids: dict[str, int] = {}

    def tid_of(agent: str | None) -> int:
        if not agent:
            return 0
        if agent not in tids:
            tids[agent] = len(tids) + 1
        return tids[agent]

    def us(t: float) -> float:
        return round((t - t0) * 1e6, 3)

    events: list[dict[str, Any]] = []
    post_at: dict[str, tuple[float, int]] = {}  # hypothesis id -> (ts, tid) of its first post
    flow_id = 0
    args: dict[str, Any]
    for r in sorted(records, key=lambda rec: (float(rec.get("t", t0)), rec.get("seq", 0))):
        kind = r.get("kind", "?")
        t = float(r.get("t", t0))
        tid = tid_of(r.get("agent"))
        base = {"pid": _PID, "tid": tid}
        if kind in ("activation_finish", "activation_error") and r.get("duration_s") is not None:
            dur = max(0.0, float(r["duration_s"]))
            args = {k: jsonable(r[k]) for k in ("id", "version", "event", "rating", "reason", "message") if k in r}
            events.append(
                {
                    **base,
                    "ph": "X",
                    "name": f"{r.get('level', '?')} <- {r.get('event', '?')}",
                    "cat": "activation" if kind == "activation_finish" else "activation_error",
                    "ts": us(t - dur),
                    "dur": round(dur * 1e6, 3),
                    "args": args,
                }
            )
        elif kind in ("post", "update", "retract"):
            hid = r.get("id", "?")
            ts = us(t)
            args = {
                "id": hid,
                "level": r.get("level"),
                "version": r.get("version"),
                "links": list(r.get("links") or ()),
                "credibility": r.get("credibility"),
                "body": _short(jsonable(r.get("body"))),
            }
            events.append(
                {
                    **base,
                    "ph": "i",
                    "s": "t",
                    "name": f"{kind} {r.get('level', '?')}",
                    "cat": kind,
                    "ts": ts,
                    "args": args,
                }
            )
            if kind == "post":
                post_at.setdefault(hid, (ts, tid))
                for link in r.get("links") or ():
                    if link not in post_at:
                        continue
                    flow_id += 1
                    src_ts, src_tid = post_at[link]
                    name = f"{link} -> {hid}"
                    events.append(
                        {
                            "pid": _PID,
                            "tid": src_tid,
                            "ph": "s",
                            "id": flow_id,
                            "cat": "link",
                            "name": name,
                            "ts": src_ts,
                        }
                    )
                    events.append({**base, "ph": "f", "bp": "e", "id": flow_id, "cat": "link", "name": name, "ts": ts})
        elif kind not in ("activation_start",):
            args = {k: jsonable(v) for k, v in r.items() if k not in ("t", "kind", "agent", "seq")}
            events.append(
                {
                    **base,
                    "ph": "i",
                    "s": "g" if kind in _GLOBAL else "t",
                    "name": kind,
                    "cat": "event",
                    "ts": us(t),
                    "args": args,
                }
            )
    meta = [
        {"pid": _PID, "tid": 0, "ph": "M", "name": "process_name", "args": {"name": f"mapinterp {run_id}"}},
        {"pid": _PID, "tid": 0, "ph": "M", "name": "thread_name", "args": {"name": "blackboard"}},
    ]
    meta += [
        {"pid": _PID, "tid": tid, "ph": "M", "name": "thread_name", "args": {"name": agent}}
        for agent, tid in tids.items()
    ]
    meta += [
        {"pid": _PID, "tid": tid, "ph": "M", "name": "thread_sort_index", "args": {"sort_index": tid}}
        for tid in [0, *tids.values()]
    ]
    return {
        "traceEvents": meta + events,
        "displayTimeUnit": "ms",
        "otherData": {"run_id": run_id, "t0_unix_s": t0, "records": len(records)},
    }


def chrome_trace_json(records: Sequence[TraceRecord]) -> str:
    """:func:`to_chrome_trace` as JSON text."""
    return json.dumps(to_chrome_trace(records), separators=(",", ":"))
