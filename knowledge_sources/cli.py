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
    "schema": "schema",
}

_HELP: dict[str, str] = {
    "render": "render a scenario's viewframes, their symbolic descriptions and an overview map",
    "table": "print the error-variance table of camera images against stored viewframes",
    "run": "localize the vehicle: run the agent ensemble on a scenario over the blackboard",
    "trace": "inspect a blackboard trace file",
    "report": "write an HTML report of results files: map, frames wrong-first with their images and answers",
    "agent": "run one knowledge source here, joining a run on another machine (--connect ENDPOINT)",
    "schema": "print the scenario file's JSON Schema (for editors' YAML completion)",
}

#: exit status when the reader of our standard output went away (128 + SIGPIPE)
EXIT_BROKEN_PIPE = 141


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (``mapinterp run: error: argument --rate:
    must be in (0, 10000] Hz, got nan``), exit status 2; the usage is in ``--help``."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see: {self.prog} --help)\n")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("mapinterp")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree not installed
        return "unknown (not installed)"


def _global_flags(parser: argparse.ArgumentParser, *, top: bool) -> None:
    """-v and --debug, on the top parser and again on each sub-command's (so they work after it)."""
    default: dict[str, object] = {} if top else {"default": argparse.SUPPRESS}
    parser.add_argument(
        "-v", "--verbose", action="count", help="more logging (-vv for debug)", **({"default": 0} if top else default)
    )
    parser.add_argument(
        "--debug", action="store_true", help="show tracebacks of errors", **({"default": False} if top else default)
    )


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """Build the argument parser; only the chosen sub-command's module is imported (all of
    them for ``--print-completion``, which writes a bash/zsh/tcsh completion script via shtab)."""
    parser = _Parser(
        prog="mapinterp",
        description="Localize a ground vehicle on a terrain map from its camera images, with agents "
        "cooperating on a zenoh blackboard.",
        epilog="Run 'mapinterp COMMAND --help' for a command's options. Shell completion: "
        'eval "$(mapinterp --print-completion bash)" (or zsh, tcsh).',
    )
    parser.add_argument("--version", action="version", version=f"mapinterp {_version()}")
    _global_flags(parser, top=True)
    argv = list(argv or [])
    completing = "--print-completion" in argv or any(a.startswith("--print-completion=") for a in argv)
    if completing:
        import shtab

        shtab.add_argument_to(parser, ["--print-completion"], help="print a shell completion script and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    chosen = next((a for a in argv if a in COMMANDS), None)
    for name in COMMANDS:
        p = sub.add_parser(name, help=_HELP[name], description=_HELP[name])
        _global_flags(p, top=False)
        if name == chosen or completing:
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
