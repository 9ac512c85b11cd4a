"""``mapinterp trace FILE``: inspect a blackboard trace (summary, timeline, filters, chain, JSON)."""

from __future__ import annotations

import argparse
from pathlib import Path

from blackboard.trace import read_trace
from blackboard.trace_view import (
    derivation_chain,
    filter_records,
    render_chain,
    render_summary,
    render_timeline,
    summarize,
    to_json,
)

__all__ = ["HELP", "add_arguments", "main"]

HELP = "inspect a blackboard trace file"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``mapinterp trace``."""
    parser.add_argument("file", type=Path, metavar="FILE", help="trace file written by a run (--trace)")
    parser.add_argument("--agent", help="only records of this agent")
    parser.add_argument("--level", help="only records on this level")
    parser.add_argument("--id", dest="hypothesis_id", metavar="H", help="only records of this hypothesis")
    parser.add_argument("--frame", help="only hypotheses of this frame (body.frame) and those derived from them")
    parser.add_argument("--chain", metavar="H", help="the derivation chain of hypothesis H back to the inputs")
    parser.add_argument("--timeline", action="store_true", help="one line per event instead of the summary")
    parser.add_argument("--json", action="store_true", help="JSON output")


def main(args: argparse.Namespace) -> int:
    """Print the chosen view; raises TraceError for an unreadable file (exit 2)."""
    records = read_trace(args.file)
    if args.chain:
        chain = derivation_chain(records, args.chain)
        print(to_json(chain) if args.json else render_chain(chain))
        return 0 if chain else 1
    selected = filter_records(records, agent=args.agent, level=args.level, id=args.hypothesis_id, frame=args.frame)
    if args.timeline:
        print(to_json(selected) if args.json else render_timeline(selected))
    else:
        summary = summarize(selected)
        print(to_json(summary) if args.json else render_summary(summary))
    return 0
