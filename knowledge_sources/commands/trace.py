"""``mapinterp trace FILE``: inspect a blackboard trace (summary, timeline, filters, chain, JSON, export).

``--export FILE`` writes, by its suffix: ``.json`` the Chrome trace-event format that
ui.perfetto.dev and chrome://tracing open (:mod:`blackboard.trace_export`; filters apply);
``.dot`` the Graphviz DOT of ``--chain H``; ``.rrd`` a Rerun recording of the run's frames
(:mod:`knowledge_sources.rerun_export`; needs ``pip install 'mapinterp[rerun]'``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from blackboard.errors import TraceError
from blackboard.trace import read_trace
from blackboard.trace_view import (
    chain_dot,
    chain_tree,
    check_filters,
    derivation_chain,
    filter_records,
    in_time_order,
    render_timeline,
    summarize,
    to_json,
)

__all__ = ["HELP", "add_arguments", "main", "summary_tables"]

HELP = "inspect a blackboard trace file"

EXPORTS = (".json", ".dot", ".rrd")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``mapinterp trace``."""
    parser.add_argument("file", type=Path, metavar="FILE", help="trace file written by a run (--trace)")
    parser.add_argument("--agent", help="only records of this agent")
    parser.add_argument("--level", help="only records on this level")
    parser.add_argument("--id", dest="hypothesis_id", metavar="H", help="only records of this hypothesis")
    parser.add_argument("--frame", help="only hypotheses of this frame (body.frame) and those derived from them")
    parser.add_argument(
        "--chain", metavar="H", help="the derivation chain of hypothesis H back to the inputs, as a tree"
    )
    parser.add_argument(
        "--timeline", action="store_true", help="one line per event, in time order, instead of the summary"
    )
    parser.add_argument("--json", action="store_true", help="JSON output")
    parser.add_argument(
        "--export",
        type=Path,
        metavar="OUT",
        help="write OUT.json (Perfetto/Chrome trace events), OUT.dot (Graphviz, with --chain) "
        "or OUT.rrd (Rerun recording)",
    )
    parser.add_argument(
        "--scenario",
        type=Path,
        default=None,
        help="scenario file for --export .rrd (default: the one the trace's run used)",
    )


def summary_tables(summary: dict) -> list:
    """The summary as rich renderables: a headline, event and level counts, a table of agents."""
    from rich.table import Table
    from rich.text import Text

    head = Text(f"run {summary['run_id'] or '?'}: {summary['records']} records over {summary['duration_s']:.3f} s")
    if not summary["complete"]:
        head.append(" (incomplete: no run_end, the run crashed or is running)", style="bold red")
    counts = Table(title=None, show_header=True, header_style="bold", box=None, pad_edge=False)
    counts.add_column("events")
    counts.add_column("levels (posts)")
    counts.add_row(
        ", ".join(f"{k} {n}" for k, n in summary["kinds"].items()) or "-",
        ", ".join(f"{k} {n}" for k, n in summary["levels"].items()) or "-",
    )
    agents = Table(show_header=True, header_style="bold")
    for name, justify in (
        ("agent", "left"),
        ("posts", "right"),
        ("upd", "right"),
        ("acts", "right"),
        ("errors", "right"),
        ("obviated", "right"),
        ("timeouts", "right"),
        ("act s", "right"),
        ("max s", "right"),
        ("state", "left"),
    ):
        agents.add_column(name, justify=justify)  # type: ignore[arg-type]
    for name, a in summary["agents"].items():
        agents.add_row(
            name,
            str(a["posts"]),
            str(a["updates"]),
            str(a["activations"]),
            str(a["errors"]),
            str(a["obviated"]),
            str(a["timeouts"]),
            f"{a['act_s']:.3f}",
            f"{a['act_max_s']:.3f}",
            str(a["state"]),
            style="red" if a["errors"] or a["timeouts"] else None,
        )
    out = [head, counts, agents]
    out += [Text(f"rejected: {m}", style="yellow") for m in summary["rejected"]]
    out += [
        Text(f"timeout: {t['id']} (poster {t['agent']}): {t['reason']}", style="yellow") for t in summary["timeouts"]
    ]
    return out


def _console():
    """A rich console; piped output gets 160 columns (or $COLUMNS), not rich's 80."""
    import shutil
    import sys

    from rich.console import Console

    width = None if sys.stdout.isatty() else shutil.get_terminal_size((160, 24)).columns
    return Console(soft_wrap=True, highlight=False, width=width)


def main(args: argparse.Namespace) -> int:
    """Print the chosen view; raises TraceError for an unreadable file or an unknown filter (exit 2)."""
    records = read_trace(args.file)
    export: Path | None = args.export
    if export is not None and export.suffix.lower() not in EXPORTS:
        raise TraceError(export, f"--export writes {', '.join(EXPORTS)} files, not {export.suffix or 'no suffix'}")
    try:
        check_filters(records, agent=args.agent, level=args.level)
    except ValueError as exc:
        raise TraceError(args.file, str(exc)) from None
    if args.chain:
        chain = derivation_chain(records, args.chain)
        if not chain:
            raise TraceError(args.file, f"no hypothesis {args.chain!r} was posted in this trace")
        if export is not None and export.suffix.lower() == ".dot":
            export.parent.mkdir(parents=True, exist_ok=True)
            export.write_text(chain_dot(chain))
            print(f"derivation chain of {args.chain} ({len(chain)} hypotheses) written to {export}")
        elif args.json:
            print(to_json(chain))
        else:
            _console().print(chain_tree(chain))
        return 0
    if export is not None and export.suffix.lower() == ".dot":
        raise TraceError(export, "a .dot export draws a derivation chain: give --chain H")
    selected = filter_records(records, agent=args.agent, level=args.level, id=args.hypothesis_id, frame=args.frame)
    if export is not None:
        export.parent.mkdir(parents=True, exist_ok=True)
        if export.suffix.lower() == ".json":
            from blackboard.trace_export import chrome_trace_json

            export.write_text(chrome_trace_json(selected))
            print(f"{len(selected)} records written to {export} (open it in ui.perfetto.dev or chrome://tracing)")
        else:
            from knowledge_sources.rerun_export import export_trace

            export_trace(records, export, scenario_path=args.scenario, trace_path=args.file)
            print(f"rerun recording written to {export} (open it with: rerun {export})")
        return 0
    if args.timeline:
        print(to_json(in_time_order(selected)) if args.json else render_timeline(selected))
        return 0
    complete = any(r.get("kind") == "run_end" for r in records)
    summary = summarize(selected, complete=complete)
    if summary["run_id"] is None:  # the filter dropped run_start
        summary["run_id"] = summarize(records[:1])["run_id"] if records else None
    if args.json:
        print(to_json(summary))
    else:
        console = _console()
        for part in summary_tables(summary):
            console.print(part)
    return 0
