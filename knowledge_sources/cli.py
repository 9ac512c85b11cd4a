"""The ``mapinterp`` command.

Sub-commands live one per module in :mod:`knowledge_sources.commands` and are imported only
when chosen. A mapinterp error (any of :data:`~knowledge_sources.errors.MAPINTERP_ERRORS`: a
:class:`~models.errors.ModelError` such as a malformed scenario or a missing image, or a
:class:`~blackboard.errors.BlackboardError` such as a dead agent) is printed as one sentence naming the culprit, with
exit status 2, never as a traceback; ``--debug`` shows the traceback. Output piped into a
reader that stops early (``mapinterp trace run.trace --timeline | head``) ends quietly with
status 141, as a command killed by SIGPIPE would.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence
from typing import NoReturn

from knowledge_sources.errors import MAPINTERP_ERRORS

__all__ = ["COMMANDS", "build_parser", "console_main", "main"]

#: sub-command name -> module in knowledge_sources.commands
COMMANDS: dict[str, str] = {
    "render": "render",
    "table": "table",
    "run": "run",
    "trace": "trace",
    "report": "report",
    "agent": "agent",
}

_HELP: dict[str, str] = {
    "render": "render a scenario's viewframes, their symbolic descriptions and an overview map",
    "table": "print the error-variance table of camera images against stored viewframes",
    "run": "localize the vehicle: run the agent ensemble on a scenario over the blackboard",
    "trace": "inspect a blackboard trace file",
    "report": "plot a results file: map, frames beside their viewframes, rankings, queries",
    "agent": "run one knowledge source here, joining a run on another machine (--connect ENDPOINT)",
}

#: exit status when the reader of our standard output went away (128 + SIGPIPE)
EXIT_BROKEN_PIPE = 141


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (``mapinterp run: error: argument --rate:
    must be in (0, 10000] Hz, got nan``), exit status 2; the usage is in ``--help``."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see: {self.prog} --help)\n")


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """Build the argument parser; only the chosen sub-command's module is imported."""
    parser = _Parser(
        prog="mapinterp",
        description="Localize a ground vehicle on a terrain map from its camera images, with agents "
                    "cooperating on a zenoh blackboard.",
        epilog="Run 'mapinterp COMMAND --help' for a command's options.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv for debug)")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    chosen = next((a for a in (argv or []) if a in COMMANDS), None)
    for name in COMMANDS:
        p = sub.add_parser(name, help=_HELP[name], description=_HELP[name])
        if name == chosen:
            _command_module(name).add_arguments(p)
    return parser


def _command_module(name: str):
    return importlib.import_module(f"knowledge_sources.commands.{COMMANDS[name]}")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mapinterp`` console script; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        parser = build_parser(argv)
        args = parser.parse_args(argv)
    except SystemExit as stop:  # a usage error (one line, status 2) or --help (status 0)
        return stop.code if isinstance(stop.code, int) else 2
    except KeyboardInterrupt:  # Ctrl-C while the command's modules load
        print("mapinterp: interrupted", file=sys.stderr)
        return 130
    level = [logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)]
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        status = int(_command_module(args.command).main(args) or 0)
        sys.stdout.flush()  # here, not at interpreter exit, so a closed pipe is caught below
        return status
    except BrokenPipeError:
        # the reader closed the pipe (`| head`): no traceback, and no second error when Python
        # flushes stdout at exit (the recipe of the Python signal module's documentation)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return EXIT_BROKEN_PIPE
    except MAPINTERP_ERRORS as err:
        if args.debug:
            raise
        print(f"mapinterp {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"mapinterp {args.command}: interrupted", file=sys.stderr)
        return 130


def console_main() -> int:
    """The console script: :func:`main`, except that an interrupted command (status 128 + signal,
    its results and trace already written and flushed) leaves at once, not after the interpreter
    has waited for activations still running in agent threads and torn down their sessions."""
    status = main()
    if status > 128:
        logging.shutdown()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(status)
    return status


if __name__ == "__main__":  # pragma: no cover
    sys.exit(console_main())
