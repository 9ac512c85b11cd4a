"""``mapinterp agent FACTORY --name NAME --run-id RUN --connect ENDPOINT``: one knowledge source,
in this process, joining a run whose blackboard is elsewhere (transport mode 3).

The run is started on one machine with ``mapinterp run SCENARIO --listen ENDPOINT --run-id RUN
--remote NAME``; it prints this command for each remote agent (:func:`command_line`). The agent
keeps trying to reach ``ENDPOINT`` and the run's node for ``--connect-timeout`` seconds, works
until the node announces the end of the run (or Ctrl-C / SIGTERM), then exits 0. The node
being lost without an announcement is an error (exit 2).

Example::

    mapinterp agent knowledge_sources.detector:LandmarkDetectorAgent --name detector-house \\
        --run-id demo --connect tcp/127.0.0.1:7447 --option threshold=0.55
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from blackboard.config import ZenohOptions, add_zenoh_arguments, is_loopback, zenoh_options_from_args

HELP = "run one knowledge source here, joining a run on another machine (--connect ENDPOINT)"

__all__ = ["HELP", "add_arguments", "main", "command_line", "parse_option", "format_option", "run_id_argument"]

#: default of --connect-timeout: how long to keep trying to reach the blackboard
CONNECT_TIMEOUT_S = 30.0
#: how often the main thread looks at the SIGTERM flag while it waits for the end of the run
_POLL_S = 0.25


def parse_option(text: str) -> tuple[str, Any]:
    """``"key=value"`` -> ``(key, value)``; the value is read as JSON when it is JSON
    (``0.5``, ``true``, ``null``, ``[1, 2]``, ``"7"``), else kept as text.

    Raises:
        ValueError: no ``=`` or an empty key.
    """
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise ValueError(f"--option must be key=value, got {text!r}")
    try:
        value = json.loads(raw)
    except ValueError:
        value = raw
    return key.strip(), value


def format_option(key: str, value: Any) -> str:
    """The inverse of :func:`parse_option`: ``parse_option(format_option(k, v)) == (k, v)``
    for JSON data ``v``."""
    if isinstance(value, str):
        try:
            json.loads(value)
        except ValueError:
            return f"{key}={value}"  # plain text stays readable
    return f"{key}={json.dumps(value)}"


def command_line(
    factory: str,
    name: str,
    options: Mapping[str, Any],
    *,
    run_id: str,
    connect: str,
    zenoh_config: str | Path | None = None,
    secret: str | None = None,
) -> list[str]:
    """The ``mapinterp agent ...`` argv that joins agent ``name`` to run ``run_id`` at ``connect``
    (``shlex.join`` it to print)."""
    argv = ["mapinterp", "agent", factory, "--name", name, "--run-id", run_id, "--connect", connect]
    for key, value in options.items():
        argv += ["--option", format_option(key, value)]
    if zenoh_config is not None:
        argv += ["--zenoh-config", str(zenoh_config)]
    if secret is not None:
        argv += ["--secret", secret]
    return argv


def run_id_argument(text: str) -> str:
    """argparse ``type`` of ``--run-id``: a valid key chunk (letters, digits, ``_``, ``-``)."""
    from blackboard.hypothesis import validate_name

    try:
        return validate_name(text, "run id")
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _positive(text: str) -> float:
    from knowledge_sources.commands import bounded_number
    from knowledge_sources.mission import MAX_WAIT_S

    return bounded_number(0, MAX_WAIT_S, "s")(text)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``mapinterp agent``."""
    parser.add_argument(
        "factory",
        metavar="FACTORY",
        help="the knowledge source class, module:Class (e.g. knowledge_sources.detector:LandmarkDetectorAgent)",
    )
    parser.add_argument("--name", required=True, help="the agent's name in the run (e.g. detector-house)")
    parser.add_argument(
        "--run-id", required=True, type=run_id_argument, metavar="RUN", help="the run to join (mapinterp run --run-id)"
    )
    parser.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an option of the knowledge source; VALUE is JSON or text (repeatable)",
    )
    parser.add_argument(
        "--secret",
        default=os.environ.get("MAPINTERP_SECRET"),
        metavar="SECRET",
        help="the run's secret, as mapinterp run printed it (default: $MAPINTERP_SECRET)",
    )
    parser.add_argument(
        "--auth",
        action="store_true",
        help="authenticate to the run's router with the secret (default: when --connect "
        "is not a loopback address, as the run's router then asks for it)",
    )
    parser.add_argument(
        "--connect-timeout",
        type=_positive,
        default=CONNECT_TIMEOUT_S,
        metavar="SECONDS",
        help=f"keep trying to reach the blackboard this long (default {CONNECT_TIMEOUT_S:g})",
    )
    add_zenoh_arguments(parser)


def main(args: argparse.Namespace) -> int:
    """Join, work until the run ends (0) or Ctrl-C / SIGTERM (0); a mapinterp error on failure."""
    from blackboard.agent import AgentRunner
    from blackboard.errors import AgentError, TransportError
    from blackboard.runtime import resolve_factory

    if not args.connect:
        raise TransportError("mapinterp agent needs --connect ENDPOINT (where mapinterp run --listen listens)")
    if args.listen:
        raise TransportError("mapinterp agent is a zenoh client: use --connect, not --listen")
    options = zenoh_options_from_args(args)
    try:
        kwargs = dict(parse_option(text) for text in args.option)
    except ValueError as err:
        raise AgentError(args.name, str(err)) from None
    try:
        source = resolve_factory(args.factory)(args.name, **kwargs)
    except TypeError as err:  # an option the knowledge source does not take
        raise AgentError(args.name, f"bad options for {args.factory}: {err}") from None
    except ValueError as err:  # a bad name, a bad option value
        raise AgentError(args.name, str(err)) from None
    if not args.secret:
        raise AgentError(
            args.name, "needs the run's secret: --secret SECRET (printed by mapinterp run) or $MAPINTERP_SECRET"
        )
    # the run's router asks for the secret as password when it listens beyond this machine
    auth = args.auth or any(not is_loopback(ep) for ep in options.connect)
    runner = AgentRunner(
        source,
        run_id=args.run_id,
        connect=options.connect,
        secret=args.secret,
        zenoh_options=ZenohOptions(config_file=options.config_file, password=args.secret if auth else None),
    )
    stop = threading.Event()
    handled = (signal.SIGTERM, signal.SIGINT)
    previous: dict[int, Any] = {}
    try:
        runner.start(wait_s=args.connect_timeout)  # Ctrl-C here: KeyboardInterrupt, exit 130
        # from now on SIGTERM and Ctrl-C only ask to stop: the agent leaves cleanly, exit 0
        previous = {signum: signal.signal(signum, lambda signum, frame: stop.set()) for signum in handled}
        where = ", ".join(options.connect)
        print(f"agent {args.name} joined run {args.run_id} at {where}", file=sys.stderr, flush=True)
        while not runner.ended.wait(_POLL_S) and not stop.is_set():
            pass
        if runner.ended.is_set() and runner.node_lost:
            raise TransportError(
                f"the blackboard node of run {args.run_id} at {where} went away without ending the run"
            )
        why = "the run ended" if runner.ended.is_set() else "interrupted"
        print(f"agent {args.name}: {why}; stopping", file=sys.stderr, flush=True)
        return 0
    finally:
        runner.stop()
        for signum, handler in previous.items():
            signal.signal(signum, handler)
