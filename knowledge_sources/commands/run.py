"""``mapinterp run SCENARIO``: localize the vehicle with the agent ensemble on the blackboard.

With ``--listen ENDPOINT --remote AGENT``, that agent is not started here: the command prints
the ``mapinterp agent ...`` line that starts it on another machine, and waits for it to join.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path
from typing import Any

from blackboard.config import add_zenoh_arguments, zenoh_options_from_args
from knowledge_sources.commands import bounded_number
from knowledge_sources.commands.agent import run_id_argument
from knowledge_sources.mission import MAX_RATE_HZ, MAX_WAIT_S

HELP = "localize the vehicle: run the agent ensemble on a scenario over the blackboard"

__all__ = ["HELP", "EXIT_DEGRADED", "add_arguments", "apply_cache_arguments", "main", "render_summary"]


#: progress-bar phase shown when the first hypothesis of a level is posted, before frames are localized
PHASES = {
    "scenario": "rendering viewframes",
    "viewframe": "rendering viewframes",
    "map": "storing viewframes in the associative memories",
    "index": "memories ready; camera posting frames",
    "sensor_frame": "ranking the first camera frames",
    "ranking": "asking the landmark detectors",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", type=Path, help="scenario YAML file")
    parser.add_argument("--out", type=Path, default=None, help="write the results JSON here")
    parser.add_argument("--trace", type=Path, default=None, help="record the blackboard trace here")
    parser.add_argument(
        "--strategy",
        choices=["associative", "prior"],
        default=None,
        help="scheduler strategy (default: the scenario's, normally associative)",
    )
    parser.add_argument("--processes", action="store_true", help="run each agent in its own OS process")
    parser.add_argument(
        "--no-track",
        action="store_true",
        help="no tracker: every frame localized alone (default: the scenario's tracking.enabled, normally on)",
    )
    parser.add_argument(
        "--rate",
        type=bounded_number(0, MAX_RATE_HZ, "Hz"),
        default=None,
        metavar="HZ",
        help="the camera posts frames at this rate, as a real one would (default: all at once)",
    )
    parser.add_argument(
        "--timeout",
        type=bounded_number(0, MAX_WAIT_S, "s"),
        default=None,
        metavar="SECONDS",
        help="give up (with an error naming the busy agents) after this long",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--rerun",
        nargs="?",
        const="spawn",
        default=None,
        metavar="TARGET",
        help="stream the run to Rerun as frames are localized: a new viewer (no TARGET), "
        "a viewer's URL (rerun+http://127.0.0.1:9876/proxy) or a FILE.rrd "
        "(needs pip install 'mapinterp[rerun]')",
    )
    parser.add_argument(
        "--run-id",
        default=None,
        type=run_id_argument,
        metavar="RUN",
        help="the run's id, which remote agents give to join it (default: random)",
    )
    parser.add_argument(
        "--remote",
        action="append",
        default=[],
        metavar="AGENT",
        help="do not start this agent of the mission here; wait for it to join from "
        "elsewhere with `mapinterp agent` (repeatable; the commands are printed)",
    )
    parser.add_argument(
        "--secret",
        default=os.environ.get("MAPINTERP_SECRET"),
        metavar="SECRET",
        help="the run's secret the --remote agents give to join (default: $MAPINTERP_SECRET, "
        "else a fresh one, printed in their commands)",
    )
    parser.add_argument(
        "--auth",
        action="store_true",
        default=None,
        help="zenoh user/password authentication with the run's secret (default: on when "
        "--listen is not a loopback address)",
    )
    parser.add_argument(
        "--wait-remote",
        type=bounded_number(0, MAX_WAIT_S, "s"),
        default=60.0,
        metavar="SECONDS",
        help="how long to wait for the --remote agents to join (default 60)",
    )
    cache = parser.add_mutually_exclusive_group()
    cache.add_argument(
        "--no-cache",
        action="store_true",
        help="render every viewframe, neither reading nor filling the viewframe cache",
    )
    cache.add_argument(
        "--cache-dir",
        type=Path,
        default=None,
        metavar="DIR",
        help="the viewframe cache folder (default: $MAPINTERP_CACHE, else ~/.cache/mapinterp)",
    )
    parser.add_argument(
        "--inline-viewframes",
        action="store_true",
        help="post every viewframe with its pixels, not by reference to the viewframe cache entry (for "
        "agents on hosts that do not see the cache folder; as render: {inline: true} in the scenario)",
    )
    add_zenoh_arguments(parser)


def apply_cache_arguments(args: argparse.Namespace) -> None:
    """``--no-cache`` / ``--cache-dir`` as ``$MAPINTERP_CACHE``, which this process's worlds and
    the agent processes it starts read (:mod:`models.viewframe_cache`). (``--inline-viewframes``
    is the map renderer's option ``inline``: :func:`knowledge_sources.mission.run_mission`.)"""
    import os

    from models.viewframe_cache import CACHE_ENV

    if getattr(args, "no_cache", False):
        os.environ[CACHE_ENV] = "off"
    elif getattr(args, "cache_dir", None) is not None:
        os.environ[CACHE_ENV] = str(args.cache_dir.expanduser().resolve())


def render_summary(results: dict[str, Any]) -> Any:
    """A rich table of a results dict: one row per frame, then the summary."""
    from rich.table import Table

    table = Table(title=f"{results['scenario']} — strategy {results['strategy']} ({results.get('mode', '')})")
    tracked = bool(results.get("tracking"))
    cols = (
        "frame",
        "viewframe",
        "truth",
        "ok",
        "conf",
        *(("single", "state") if tracked else ()),
        "queries",
        "backtracks",
        "ms",
    )
    for col in cols:
        table.add_column(col, justify="right")
    for f in results["frames"]:
        ok = {True: "[green]yes[/]", False: "[red]no[/]", None: "-"}[f["correct"]]
        table.add_row(
            str(f["frame"]),
            "-" if f["viewframe"] is None else str(f["viewframe"]),
            "-" if f["truth_viewframe"] is None else str(f["truth_viewframe"]),
            ok,
            f"{f['confidence']:.2f}",
            *((_single(f), f.get("state") or "-") if tracked else ()),
            str(f["queries"]),
            str(f["backtracks"]),
            "-" if f["latency_ms"] is None else f"{f['latency_ms']:.0f}",
        )
    s = results["summary"]
    top1 = "n/a" if s["top1"] is None else f"{s['top1']:.1%}"
    err = "n/a" if s["mean_error_m"] is None else f"{s['mean_error_m']:.1f} m"
    table.caption = (
        f"frames {s['frames']}, localized {s['localized']}, top-1 {top1}, mean error {err}, "
        f"mean queries {s['mean_queries']:.2f}, latency p50 {s['latency_ms_p50']:.0f} ms, "
        f"{s.get('frames_per_s') or 0:.1f} frames/s"
    )
    if tracked and s.get("top1_frame_only") is not None:
        table.caption += f"; tracked (single frame alone: top-1 {s['top1_frame_only']:.1%})"
    return table


def _single(frame: dict[str, Any]) -> str:
    """The single-frame decision of a tracked frame: its viewframe, marked when right."""
    only = frame.get("frame_only") or {}
    vf = only.get("viewframe")
    mark = {True: "[green]", False: "[red]", None: ""}[only.get("correct")]
    return "-" if vf is None else f"{mark}{vf}[/]" if mark else str(vf)


def _print_remote(commands: dict[str, list[str]], wait_s: float) -> None:
    """The exact command line of each remote agent, one per line (plain print: never wrapped)."""
    print(
        f"waiting up to {wait_s:g} s for the remote agents {', '.join(commands)}; start each where it should run with:",
        file=sys.stderr,
    )
    for argv in commands.values():
        print(f"  {shlex.join(argv)}", file=sys.stderr)
    if any(host in argv[argv.index("--connect") + 1] for argv in commands.values() for host in ("0.0.0.0", "[::]")):
        print("  (replace the wildcard address by this machine's address)", file=sys.stderr)
    sys.stderr.flush()


#: exit status of a run that finished degraded: agents died, frames never came (some localized)
EXIT_DEGRADED = 1


def main(args: argparse.Namespace) -> int:
    """Run the mission; returns 0 (every agent ok, every frame posted), :data:`EXIT_DEGRADED`,
    or ``128 + signal`` when interrupted (the results so far are written). Raises
    :class:`RunFailed` (status 2) when no frame was localized."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from blackboard.signals import interrupt_on_signals
    from knowledge_sources.errors import RunFailed
    from knowledge_sources.mission import run_mission
    from knowledge_sources.results import check_writable, write_results
    from models.scenario import load_scenario

    # refuse unwritable outputs before anything runs (a folder, /proc/version, a read-only file)
    if args.out is not None:
        check_writable(args.out, "--out")
    if args.trace is not None:
        check_writable(args.trace, "--trace")
    apply_cache_arguments(args)
    scenario = load_scenario(args.scenario)
    console = Console(stderr=True)
    show = not args.no_progress and sys.stderr.isatty()
    live = None
    if args.rerun is not None:
        from knowledge_sources.rerun_export import RerunLogger, open_stream, require_rerun

        require_rerun()  # before a long run: say at once when the extra is missing
    with (
        interrupt_on_signals(),
        Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=console,
            disable=not show,
            transient=True,
        ) as bar,
    ):
        if args.rerun is not None:
            from knowledge_sources.replay import replay

            task0 = bar.add_task("rendering the views for rerun", total=None)
            live = RerunLogger(open_stream(args.rerun, recording_id=args.run_id or scenario.name), replay(scenario))
            bar.remove_task(task0)
        task = bar.add_task(f"{scenario.name}: starting agents", total=None)

        def progress(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total, description=f"{scenario.name}: localizing")

        def on_hypothesis(level: str, body: Any, t: float) -> None:
            phase = PHASES.get(level)
            if phase is not None and not bar.tasks[-1].completed:
                bar.update(task, description=f"{scenario.name}: {phase}")
            if live is not None:
                live.on_hypothesis(level, body, t)

        results = run_mission(
            scenario,
            strategy=args.strategy,
            processes=args.processes,
            zenoh=zenoh_options_from_args(args),
            trace_path=args.trace,
            timeout_s=args.timeout,
            progress=progress,
            frame_rate=args.rate,
            remote=args.remote,
            run_id=args.run_id,
            wait_remote_s=args.wait_remote,
            secret=args.secret,
            auth=args.auth,
            on_wait_remote=lambda commands: _print_remote(commands, args.wait_remote),
            on_hypothesis=on_hypothesis,
            track=False if args.no_track else None,
            inline_viewframes=getattr(args, "inline_viewframes", False),
        )
        # still under the handlers: a second Ctrl-C while the results are written exits at once
        if args.out is not None:
            write_results(args.out, results)
    if live is not None:
        live.rec.flush()
        live.rec.disconnect()
        console.print(f"{live.frames_logged} frames sent to rerun ({args.rerun})")
    Console().print(render_summary(results))
    if args.out is not None:
        console.print(f"results written to {args.out}")
    if args.trace is not None:
        console.print(f"blackboard trace written to {args.trace} (inspect with: mapinterp trace {args.trace})")
    s = results["summary"]
    if results["degraded"]:
        console.print(f"[yellow]degraded run: {'; '.join(results['degraded'])}[/]")
    if results["interrupted"]:
        import signal

        print(
            f"mapinterp run: interrupted by {results['interrupted']}: {s['localized']} of "
            f"{s['frames_expected']} frames localized",
            file=sys.stderr,
        )
        return 128 + signal.Signals[results["interrupted"]].value
    if s["localized"] == 0:
        raise RunFailed(
            f"no frame localized ({s['frames_expected']} expected, {s['posted']} posted"
            + (f"; {'; '.join(results['degraded'])}" if results["degraded"] else "")
            + ")"
        )
    return EXIT_DEGRADED if results["degraded"] else 0
