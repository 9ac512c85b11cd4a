"""Pure views of a trace: filters, summary, timeline, derivation chain; text and JSON.

Reading is :func:`blackboard.trace.read_trace`; nothing here touches files or zenoh.

Example::

    records = read_trace("run.trace")
    print(render_summary(summarize(filter_records(records, agent="doubler"))))
    print(render_chain(derivation_chain(records, "doubler-3f2a9c0d41b7e5a2")))
"""

from __future__ import annotations

import json
from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from typing import Any

from blackboard.trace import TraceRecord

__all__ = [
    "filter_records",
    "frame_ids",
    "derivation_chain",
    "summarize",
    "render_summary",
    "render_timeline",
    "render_chain",
    "to_json",
]

_HYP_KINDS = ("post", "update")


def frame_ids(records: Sequence[TraceRecord], frame: Any) -> set[str]:
    """Ids of hypotheses whose body has ``frame == frame``, and of all hypotheses derived from them."""
    wanted = str(frame)
    ids = {r["id"] for r in records if r.get("kind") in _HYP_KINDS and isinstance(r.get("body"), dict)
           and "frame" in r["body"] and str(r["body"]["frame"]) == wanted}
    children: dict[str, set[str]] = defaultdict(set)
    for r in records:
        if r.get("kind") == "post":
            for link in r.get("links") or ():
                children[link].add(r["id"])
    todo = list(ids)
    while todo:
        for child in children.get(todo.pop(), ()):
            if child not in ids:
                ids.add(child)
                todo.append(child)
    return ids


def filter_records(
    records: Sequence[TraceRecord],
    *,
    agent: str | None = None,
    level: str | None = None,
    id: str | None = None,
    frame: Any = None,
) -> list[TraceRecord]:
    """The records matching every given filter (None: any). ``frame`` keeps the hypotheses of
    that frame and those derived from them (see :func:`frame_ids`)."""
    ids = frame_ids(records, frame) if frame is not None else None
    return [
        r for r in records
        if (agent is None or r.get("agent") == agent)
        and (level is None or r.get("level") == level)
        and (id is None or r.get("id") == id)
        and (ids is None or r.get("id") in ids)
    ]


def derivation_chain(records: Sequence[TraceRecord], hypothesis_id: str) -> list[TraceRecord]:
    """The post records of ``hypothesis_id`` and everything it was derived from (through
    ``links``, back to the inputs), breadth first, each once. Empty if the id was never posted;
    a link to a hypothesis missing from the trace appears as ``{"kind": "missing", "id": ...}``."""
    posts = {r["id"]: r for r in records if r.get("kind") == "post" and "id" in r}
    chain: list[TraceRecord] = []
    seen: set[str] = set()
    todo = [hypothesis_id]
    if hypothesis_id not in posts:
        return []
    while todo:
        current = todo.pop(0)
        if current in seen:
            continue
        seen.add(current)
        record = posts.get(current, {"kind": "missing", "id": current})
        chain.append(record)
        todo.extend(record.get("links") or ())
    return chain


def summarize(records: Sequence[TraceRecord]) -> dict[str, Any]:
    """Counts and timing: per kind, per level, per agent (records, activations, time in act)."""
    kinds = Counter(r.get("kind") for r in records)
    levels = Counter(r.get("level") for r in records if r.get("kind") == "post" and r.get("level"))
    agents: dict[str, dict[str, Any]] = {}
    for r in records:
        name = r.get("agent")
        if not name:
            continue
        a = agents.setdefault(name, {"posts": 0, "updates": 0, "activations": 0, "errors": 0, "obviated": 0,
                                     "timeouts": 0, "act_s": 0.0, "act_max_s": 0.0, "state": "joined"})
        kind = r.get("kind")
        a["posts"] += kind == "post"
        a["updates"] += kind == "update"
        a["activations"] += kind == "activation_finish"
        a["errors"] += kind == "activation_error"
        a["obviated"] += kind == "activation_obviated"
        a["timeouts"] += kind == "timeout"
        if kind in ("activation_finish", "activation_error") and r.get("duration_s") is not None:
            a["act_s"] += float(r["duration_s"])
            a["act_max_s"] = max(a["act_max_s"], float(r["duration_s"]))
        if kind in ("agent_leave", "agent_dead"):
            a["state"] = str(r.get("reason", kind))
    times = [float(r["t"]) for r in records if isinstance(r.get("t"), (int, float))]
    start = next((r for r in records if r.get("kind") == "run_start"), None)
    return {
        "run_id": start.get("run_id") if start else None,
        "records": len(records),
        "complete": any(r.get("kind") == "run_end" for r in records),
        "start": min(times) if times else None,
        "duration_s": (max(times) - min(times)) if times else 0.0,
        "kinds": dict(sorted(kinds.items())),
        "levels": dict(sorted(levels.items())),
        "agents": dict(sorted(agents.items())),
        "rejected": [r.get("message") for r in records if r.get("kind") == "rejected"],
        "timeouts": [{"id": r.get("id"), "agent": r.get("agent"), "reason": r.get("reason")}
                     for r in records if r.get("kind") == "timeout"],
    }


def render_summary(summary: dict[str, Any]) -> str:
    """Plain-text rendering of :func:`summarize`."""
    lines = [f"run {summary['run_id'] or '?'}: {summary['records']} records over {summary['duration_s']:.3f} s"
             + ("" if summary["complete"] else " (incomplete: no run_end, the run crashed or is running)")]
    lines.append("events:  " + ", ".join(f"{k} {n}" for k, n in summary["kinds"].items()))
    lines.append("levels:  " + (", ".join(f"{k} {n}" for k, n in summary["levels"].items()) or "-"))
    lines.append(f"{'agent':<20} {'posts':>6} {'upd':>5} {'acts':>6} {'errors':>6} {'obviated':>8} "
                 f"{'timeouts':>8} {'act s':>8} {'max s':>7}  state")
    for name, a in summary["agents"].items():
        lines.append(f"{name:<20} {a['posts']:>6} {a['updates']:>5} {a['activations']:>6} {a['errors']:>6} "
                     f"{a['obviated']:>8} {a['timeouts']:>8} {a['act_s']:>8.3f} {a['act_max_s']:>7.3f}  {a['state']}")
    for message in summary["rejected"]:
        lines.append(f"rejected: {message}")
    for t in summary["timeouts"]:
        lines.append(f"timeout: {t['id']} (poster {t['agent']}): {t['reason']}")
    return "\n".join(lines)


def _describe(r: TraceRecord) -> str:
    parts = []
    if r.get("level") or r.get("id"):
        parts.append(f"{r.get('level', '?')}/{r.get('id', '?')}" + (f" v{r['version']}" if "version" in r else ""))
    if r.get("links"):
        parts.append("<- " + ",".join(r["links"]))
    for name in ("event", "reason", "message", "addressed_to"):
        if r.get(name):
            parts.append(f"{name}={r[name]}")
    if r.get("duration_s") is not None:
        parts.append(f"{1000 * float(r['duration_s']):.2f} ms")
    return " ".join(parts)


def render_timeline(records: Sequence[TraceRecord]) -> str:
    """One line per record: time since the first record, kind, agent, level/id, details."""
    if not records:
        return "(no records)"
    t0 = min(float(r["t"]) for r in records if isinstance(r.get("t"), (int, float)))
    return "\n".join(
        f"{float(r.get('t', t0)) - t0:>10.4f}s  {r.get('kind', '?'):<20} {r.get('agent', ''):<16} {_describe(r)}"
        for r in records
    )


def render_chain(chain: Sequence[TraceRecord]) -> str:
    """The derivation chain, the hypothesis first, each with its source and a short body."""
    if not chain:
        return "(hypothesis not found in the trace)"
    lines = []
    for r in chain:
        if r.get("kind") == "missing":
            lines.append(f"{r['id']}: not in the trace")
            continue
        body = json.dumps(_jsonable(r.get("body")), sort_keys=True)
        body = body if len(body) <= 120 else body[:117] + "..."
        links = ", ".join(r.get("links") or ()) or "input"
        lines.append(f"{r.get('level')}/{r.get('id')} v{r.get('version')} by {r.get('agent')} "
                     f"(credibility {r.get('credibility', 1.0):.2f}) <- {links}\n    {body}")
    return "\n".join(lines)


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (bytes, bytearray)):
        return {"__bytes__": len(value)}
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return repr(value)


def to_json(value: Any | Iterable[TraceRecord]) -> str:
    """JSON text of a summary, a record list or a chain (bytes shown as their length)."""
    return json.dumps(_jsonable(value), indent=2, sort_keys=True)
