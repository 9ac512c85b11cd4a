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
    "known_names",
    "check_filters",
    "frame_ids",
    "derivation_chain",
    "summarize",
    "render_summary",
    "render_timeline",
    "in_time_order",
    "render_chain",
    "chain_tree",
    "chain_dot",
    "to_json",
    "jsonable",
]

_HYP_KINDS = ("post", "update")


def frame_ids(records: Sequence[TraceRecord], frame: Any) -> set[str]:
    """Ids of hypotheses whose body has ``frame == frame``, and of all hypotheses derived from them."""
    wanted = str(frame)
    ids = {
        r["id"]
        for r in records
        if r.get("kind") in _HYP_KINDS
        and isinstance(r.get("body"), dict)
        and "frame" in r["body"]
        and str(r["body"]["frame"]) == wanted
    }
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
        r
        for r in records
        if (agent is None or r.get("agent") == agent)
        and (level is None or r.get("level") == level)
        and (id is None or r.get("id") == id)
        and (ids is None or r.get("id") in ids)
    ]


def known_names(records: Sequence[TraceRecord]) -> dict[str, list[str]]:
    """The agents and levels that appear in ``records``, sorted: ``{"agent": [...], "level": [...]}``."""
    return {
        "agent": sorted({str(r["agent"]) for r in records if r.get("agent")}),
        "level": sorted({str(r["level"]) for r in records if r.get("level")}),
    }


def check_filters(records: Sequence[TraceRecord], *, agent: str | None = None, level: str | None = None) -> None:
    """Raise ``ValueError`` naming the known agents (levels) when ``agent`` (``level``) is not in the trace."""
    known = known_names(records)
    for what, value in (("agent", agent), ("level", level)):
        if value is not None and value not in known[what]:
            names = ", ".join(known[what]) or "none"
            raise ValueError(f"no {what} {value!r} in this trace; its {what}s: {names}")


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


def summarize(records: Sequence[TraceRecord], *, complete: bool | None = None) -> dict[str, Any]:
    """Counts and timing: per kind, per level, per agent (records, activations, time in act).

    ``complete`` says whether the run ended (a ``run_end`` record); give it when ``records`` is
    a filtered selection, whose own records need not include the run's end.
    """
    kinds = Counter(r.get("kind") for r in records)
    levels = Counter(r.get("level") for r in records if r.get("kind") == "post" and r.get("level"))
    agents: dict[str, dict[str, Any]] = {}
    for r in records:
        name = r.get("agent")
        if not name:
            continue
        a = agents.setdefault(
            name,
            {
                "posts": 0,
                "updates": 0,
                "activations": 0,
                "errors": 0,
                "obviated": 0,
                "timeouts": 0,
                "act_s": 0.0,
                "act_max_s": 0.0,
                "state": "joined",
            },
        )
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
        "complete": any(r.get("kind") == "run_end" for r in records) if complete is None else bool(complete),
        "start": min(times) if times else None,
        "duration_s": (max(times) - min(times)) if times else 0.0,
        "kinds": dict(sorted(kinds.items())),
        "levels": dict(sorted(levels.items())),
        "agents": dict(sorted(agents.items())),
        "rejected": [r.get("message") for r in records if r.get("kind") == "rejected"],
        "timeouts": [
            {"id": r.get("id"), "agent": r.get("agent"), "reason": r.get("reason")}
            for r in records
            if r.get("kind") == "timeout"
        ],
    }


def render_summary(summary: dict[str, Any]) -> str:
    """Plain-text rendering of :func:`summarize`."""
    lines = [
        f"run {summary['run_id'] or '?'}: {summary['records']} records over {summary['duration_s']:.3f} s"
        + ("" if summary["complete"] else " (incomplete: no run_end, the run crashed or is running)")
    ]
    lines.append("events:  " + ", ".join(f"{k} {n}" for k, n in summary["kinds"].items()))
    lines.append("levels:  " + (", ".join(f"{k} {n}" for k, n in summary["levels"].items()) or "-"))
    lines.append(
        f"{'agent':<20} {'posts':>6} {'upd':>5} {'acts':>6} {'errors':>6} {'obviated':>8} "
        f"{'timeouts':>8} {'act s':>8} {'max s':>7}  state"
    )
    for name, a in summary["agents"].items():
        lines.append(
            f"{name:<20} {a['posts']:>6} {a['updates']:>5} {a['activations']:>6} {a['errors']:>6} "
            f"{a['obviated']:>8} {a['timeouts']:>8} {a['act_s']:>8.3f} {a['act_max_s']:>7.3f}  {a['state']}"
        )
    for message in summary["rejected"]:
        lines.append(f"rejected: {message}")
    for t in summary["timeouts"]:
        lines.append(f"timeout: {t['id']} (poster {t['agent']}): {t['reason']}")
    return "\n".join(lines)


def _body_summary(r: TraceRecord) -> str:
    """A few scalar fields of a posted body; an answer reads ``H1 present (score 0.82)``."""
    body = r.get("body")
    if not isinstance(body, dict) or r.get("kind") not in _HYP_KINDS:
        return ""
    if r.get("level") == "answer" and "present" in body:
        score = body.get("score")
        score = f" (score {float(score):.2f})" if isinstance(score, (int, float)) else ""
        where = f" in viewframe {body['viewframe']}" if "viewframe" in body else ""
        verdict = {True: "present", False: "absent"}.get(body["present"], "uncertain")
        return f"{body.get('landmark', '?')} {verdict}{score}{where}"
    if r.get("level") == "viewframe" and isinstance(body.get("entry"), str):  # pixels by reference
        entry = body["entry"].rstrip("/").rsplit("/", 1)[-1]
        return f"index={body.get('index')} pixels in cache entry {entry[:16]} (row {body.get('index')} of {body.get('entry_count')})"
    shown = []
    for key, value in body.items():
        if isinstance(value, bool) or value is None or isinstance(value, (int, str)):
            text = repr(value) if isinstance(value, str) else str(value)
        elif isinstance(value, float):
            text = f"{value:.4g}"
        else:
            continue
        if len(text) <= 40:
            shown.append(f"{key}={text}")
        if len(shown) == 6:
            break
    return " ".join(shown)


def in_time_order(records: Sequence[TraceRecord]) -> list[TraceRecord]:
    """Records by time, then by the node's sequence number (records may arrive out of order)."""

    def key(r: TraceRecord) -> tuple[float, int]:
        t = r.get("t")
        return (float(t) if isinstance(t, (int, float)) else float("inf"), int(r.get("seq", 0) or 0))

    return sorted(records, key=key)


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
    body = _body_summary(r)
    if body:
        parts.append(f"[{body}]")
    return " ".join(parts)


def render_timeline(records: Sequence[TraceRecord]) -> str:
    """One line per record in time order: time since the first record, kind, agent, level/id,
    details, and a few body fields of posts (an answer's landmark, present/absent and score)."""
    if not records:
        return "(no records)"
    times = [float(r["t"]) for r in records if isinstance(r.get("t"), (int, float))]
    t0 = min(times) if times else 0.0
    return "\n".join(
        f"{float(r.get('t', t0)) - t0:>10.4f}s  {r.get('kind', '?'):<20} {r.get('agent', ''):<16} {_describe(r)}"
        for r in in_time_order(records)
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
        body = json.dumps(jsonable(r.get("body")), sort_keys=True)
        body = body if len(body) <= 120 else body[:117] + "..."
        links = ", ".join(r.get("links") or ()) or "input"
        lines.append(
            f"{r.get('level')}/{r.get('id')} v{r.get('version')} by {r.get('agent')} "
            f"(credibility {r.get('credibility', 1.0):.2f}) <- {links}\n    {body}"
        )
    return "\n".join(lines)


def _node_label(r: TraceRecord) -> str:
    body = _body_summary(r)
    return f"{r.get('level')}/{r.get('id')} by {r.get('agent')}" + (f": {body}" if body else "")


def chain_tree(chain: Sequence[TraceRecord]):
    """The derivation chain as a :class:`rich.tree.Tree`: the hypothesis at the root, each node's
    children the hypotheses it was derived from; one met again is shown once, then "(above)"."""
    from rich.markup import escape
    from rich.tree import Tree

    if not chain:
        return Tree("(hypothesis not found in the trace)")
    by_id = {r["id"]: r for r in chain}
    root = chain[0]
    tree = Tree(f"[bold]{escape(_node_label(root))}[/bold]")
    shown = {root["id"]}

    def grow(node, record: TraceRecord) -> None:
        for link in record.get("links") or ():
            child = by_id.get(link, {"kind": "missing", "id": link})
            if child.get("kind") == "missing":
                node.add(f"[red]{escape(link)}: not in the trace[/red]")
            elif link in shown:
                node.add(f"[dim]{escape(link)} (above)[/dim]")
            else:
                shown.add(link)
                grow(node.add(escape(_node_label(child))), child)

    grow(tree, root)
    return tree


def _dot_quote(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def chain_dot(chain: Sequence[TraceRecord]) -> str:
    """The derivation chain as a Graphviz DOT digraph: an edge from each input to what was
    derived from it; nodes labelled level/id, agent and a short body, coloured per level."""
    palette = [
        "#a6cee3",
        "#b2df8a",
        "#fb9a99",
        "#fdbf6f",
        "#cab2d6",
        "#ffff99",
        "#1f78b4",
        "#33a02c",
        "#e31a1c",
        "#ff7f00",
    ]
    levels = sorted({str(r.get("level")) for r in chain if r.get("kind") != "missing"})
    colour = {lvl: palette[i % len(palette)] for i, lvl in enumerate(levels)}
    lines = ["digraph derivation {", "  rankdir=BT;", '  node [shape=box, style="rounded,filled", fontsize=10];']
    for r in chain:
        if r.get("kind") == "missing":
            lines.append(
                f'  {_dot_quote(r["id"])} [label={_dot_quote(r["id"] + chr(10) + "not in the trace")}, style="dashed"];'
            )
            continue
        body = _body_summary(r)
        label = f"{r.get('level')}/{r.get('id')}\nby {r.get('agent')}" + (f"\n{body}" if body else "")
        lines.append(
            f"  {_dot_quote(r['id'])} [label={_dot_quote(label)}, fillcolor={_dot_quote(colour[str(r.get('level'))])}];"
        )
    for r in chain:
        for link in r.get("links") or ():
            lines.append(f"  {_dot_quote(link)} -> {_dot_quote(r['id'])};")
    lines.append("}")
    return "\n".join(lines) + "\n"


def jsonable(value: Any) -> Any:
    """``value`` as plain JSON data: dict keys as strings, tuples as lists, bytes as their length
    (``{"__bytes__": n}``), anything else not JSON as its ``repr``."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, (bytes, bytearray)):
        return {"__bytes__": len(value)}
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return repr(value)


def to_json(value: Any | Iterable[TraceRecord]) -> str:
    """JSON text of a summary, a record list or a chain (bytes shown as their length)."""
    return json.dumps(jsonable(value), indent=2, sort_keys=True)
