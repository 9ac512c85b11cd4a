"""A mission: the whole agent ensemble localizing a scenario's camera frames on the blackboard.

:func:`run_mission` is what ``mapinterp run``, the scenario pytest plugin and the end-to-end
benchmark call. It starts the knowledge sources

* ``map-renderer`` (:class:`~knowledge_sources.map_renderer.MapRenderer`),
* ``camera`` (:class:`~knowledge_sources.camera.Camera`),
* ``indexer-<b>``, one :class:`~knowledge_sources.indexer.AssociativeIndexer` per shard of
  viewframes (``ceil(route points / memory.shard_size)`` shards, each a set of memory banks),
* ``detector-<kind>``, one :class:`~knowledge_sources.detector.LandmarkDetectorAgent` per
  landmark kind of the scenario,
* ``skyline`` (:class:`~knowledge_sources.skyline.SkylineRanker`) when ``skyline.enabled``,
* ``scheduler`` (:class:`~knowledge_sources.scheduler.Scheduler`), fusing the rankings of the
  indexers and the skyline,
* ``verifier`` (:class:`~knowledge_sources.verifier.Verifier`) when ``verify.enabled``: the
  scheduler's render-and-compare scores of a frame's first candidates,
* ``refiner`` (:class:`~knowledge_sources.refiner.PoseRefiner`) when ``refine.enabled``,
* ``tracker`` (:class:`~knowledge_sources.tracker.Tracker`), unless tracking is off (the
  scenario's ``tracking.enabled``, ``mapinterp run --no-track``),

posts the scenario, runs until the blackboard is quiescent and turns the ``position``
hypotheses into the results of :mod:`knowledge_sources.results`.

Agents named in ``remote`` are not started here: someone starts them elsewhere with the
``mapinterp agent ...`` command lines passed to ``on_wait_remote`` (see
:mod:`knowledge_sources.commands.agent`), and the scenario is posted once they have joined.
"""

from __future__ import annotations

import logging
import math
import shlex
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from blackboard.config import ZenohOptions, is_loopback
from blackboard.errors import AgentError, AgentInputError
from blackboard.knowledge_source import Event
from blackboard.runtime import Runtime
from blackboard.signals import signal_name
from knowledge_sources import levels
from knowledge_sources.errors import UsageError
from knowledge_sources.results import add_map_coordinates, frame_record, summarize, with_track
from knowledge_sources.scheduler import detector_name
from models.blas import single_blas_thread
from models.errors import ScenarioError
from models.preflight import check_scenario, frame_count
from models.route_views import route_points_of, view_count
from models.scenario import Scenario, load_scenario

__all__ = ["run_mission", "agent_plan", "MAX_RATE_HZ", "MAX_WAIT_S"]

log = logging.getLogger(__name__)

#: the camera's --rate is at most this (Hz); --timeout and --wait-remote at most this (seconds)
MAX_RATE_HZ = 10_000.0
MAX_WAIT_S = 7 * 24 * 3600.0
#: the tracker's agent name (the scheduler addresses its track queries to it)
TRACKER = "tracker"
#: the verifier's agent name (the scheduler addresses its verify queries to it)
VERIFIER = "verifier"


def agent_plan(
    scenario: Scenario,
    *,
    strategy: str | None = None,
    frame_rate: float | None = None,
    track: bool | None = None,
    paced: bool = False,
    inline_viewframes: bool = False,
) -> list[tuple[str, str, dict[str, Any]]]:
    """The agents of a mission: ``(factory, name, options)`` triples, options being plain data.

    ``track``: include the tracker (default: the scenario's ``tracking.enabled``); ``paced``:
    the camera posts each frame once the frame before is answered (its track when tracking,
    else its position); ``inline_viewframes``: the map renderer's option ``inline`` (the pixels
    in every viewframe message, as the scenario's ``render: {inline: true}``)."""
    sched, ver = scenario.scheduler, scenario.verify
    tracked = scenario.tracking.enabled if track is None else bool(track)
    views = view_count(len(scenario.route), scenario.views_per_leg)
    shards = max(1, math.ceil(views / scenario.memory.shard_size))
    pace = (levels.TRACK if tracked else levels.POSITION) if paced else None
    plan: list[tuple[str, str, dict[str, Any]]] = [
        ("knowledge_sources.map_renderer:MapRenderer", "map-renderer", {"inline": True} if inline_viewframes else {}),
        ("knowledge_sources.camera:Camera", "camera", {"rate_hz": frame_rate, "pace": pace}),
    ]
    for s in range(shards):
        plan.append(
            (
                "knowledge_sources.indexer:AssociativeIndexer",
                f"indexer-{s}",
                {"shard": s, "shards": shards, "block": scenario.memory.shard_size, "tracked": tracked},
            )
        )
    sky = scenario.skyline
    match = sky.match_options()
    sources = {"associative": scenario.memory.weight}
    if sky.enabled:
        plan.append(
            (
                "knowledge_sources.skyline:SkylineRanker",
                "skyline",
                {
                    "fov_y_deg": scenario.camera.fov_y_deg,
                    **match,
                    "coarse_candidates": sky.coarse_candidates,
                    "tracked": tracked,
                },
            )
        )
        sources["skyline"] = sky.weight
    named: dict[str, str] = {}
    for kind in sorted({lm.kind for lm in scenario.landmarks}):
        if detector_name(kind) in named:
            raise ScenarioError(
                scenario.path,
                "landmarks",
                f"kinds {named[detector_name(kind)]!r} and {kind!r} both "
                f"name the detector agent {detector_name(kind)!r}: rename one",
            )
        named[detector_name(kind)] = kind
        plan.append(
            (
                "knowledge_sources.detector:LandmarkDetectorAgent",
                detector_name(kind),
                {
                    "threshold": sched.detector_threshold,
                    "absent_threshold": sched.absent_threshold,
                    "calibration": {k: list(v) for k, v in sched.calibration.items()},
                    "align_deg": list(sched.align_deg),
                    "scales": list(sched.detector_scales),
                    "camera_height": scenario.camera.height,
                    "fov_y_deg": scenario.camera.fov_y_deg,
                },
            )
        )
    plan.append(
        (
            "knowledge_sources.scheduler:Scheduler",
            "scheduler",
            {
                "strategy": strategy or sched.strategy,
                "candidates": sched.candidates,
                "accept": sched.accept,
                "reliability": sched.reliability,
                "beta": sched.beta,
                "min_pixels": sched.min_pixels,
                "query_timeout_s": sched.query_timeout_s,
                "sources": sources,
                "tracked": tracked,
                "tracker": TRACKER,
                "track_timeout_s": sched.track_timeout_s,
                "backtracking": sched.backtracking,
                "questions": sched.questions,
                "floor": sched.floor,
                "max_llr": sched.max_llr,
                "neighbour_visibility": sched.neighbour_visibility,
                "position_evidence": sched.position_evidence,
                "position_spread": list(sched.position_spread),
                "position_dof": sched.position_dof,
                "max_position_llr": sched.max_position_llr,
                **(
                    {
                        "verify_candidates": ver.candidates,
                        "verify_margin": ver.margin,
                        "verify_weight": ver.weight,
                        "verify_timeout_s": ver.timeout_s,
                        "verify_when": ver.when,
                        "verifier": VERIFIER,
                    }
                    if ver.enabled
                    else {}
                ),
            },
        )
    )
    if ver.enabled:
        plan.append(
            (
                "knowledge_sources.verifier:Verifier",
                VERIFIER,
                {
                    **{k: match[k] for k in ("step_deg", "max_heading_deg", "max_pitch_deg", "truncate_deg")},
                    "rolls_deg": list(ver.roll_search_deg),
                    "max_roll_deg": ver.max_roll_deg,
                },
            )
        )
    ref = scenario.refine
    if ref.enabled:
        plan.append(
            (
                "knowledge_sources.refiner:PoseRefiner",
                "refiner",
                {
                    "position": ref.position,
                    "recheck": ref.recheck,
                    "memory_heading": ref.memory_heading,
                    "along_m": ref.along_m,
                    "across_m": ref.across_m,
                    "levels": ref.levels,
                    "grid": ref.grid,
                    "edge_weight": ref.edge_weight,
                    **{k: v for k, v in match.items() if k != "roll_candidates"},  # one reference per match
                    "max_roll_deg": ref.max_roll_deg,
                },
            )
        )
    if tracked:
        plan.append(
            (
                "knowledge_sources.tracker:Tracker",
                TRACKER,
                {
                    "spec": scenario.tracking.model_dump(),
                    "min_pixels": sched.min_pixels,
                    "sources": sources,
                    "await_query": True,
                    "verify_weight": ver.weight if ver.enabled else 0.0,
                },
            )
        )
    return plan


def _check_numbers(n_frames: int, *, timeout_s: float, frame_rate: float | None, wait_remote_s: float) -> None:
    """The run's own numbers (command-line options): finite, positive, and coherent."""
    for option, value in (("--timeout", timeout_s), ("--wait-remote", wait_remote_s)):
        if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0 or value > MAX_WAIT_S:
            raise UsageError(option, f"must be a number of seconds in (0, {MAX_WAIT_S:g}], got {value!r}")
    if frame_rate is None:
        return
    if not isinstance(frame_rate, (int, float)) or not math.isfinite(frame_rate) or not 0 < frame_rate <= MAX_RATE_HZ:
        raise UsageError("--rate", f"must be a frame rate in (0, {MAX_RATE_HZ:g}] Hz, got {frame_rate!r}")
    span = (n_frames - 1) / frame_rate
    if span >= timeout_s:
        raise UsageError(
            "--rate",
            f"{n_frames} frames at {frame_rate:g} Hz take {span:g} s, longer than the "
            f"run's timeout of {timeout_s:g} s (raise --rate or --timeout)",
        )


def run_mission(
    scenario: Scenario | str | Path,
    *,
    strategy: str | None = None,
    processes: bool = False,
    zenoh: ZenohOptions | None = None,
    trace_path: str | Path | None = None,
    timeout_s: float | None = None,
    progress: Callable[[int, int], None] | None = None,
    kill_after: tuple[str, str, int] | None = None,
    frame_rate: float | None = None,
    remote: Sequence[str] = (),
    run_id: str | None = None,
    wait_remote_s: float = 60.0,
    on_wait_remote: Callable[[dict[str, list[str]]], None] | None = None,
    track: bool | None = None,
    secret: str | None = None,
    auth: bool | None = None,
    on_hypothesis: Callable[[str, Any, float], None] | None = None,
    paced: bool = False,
    inline_viewframes: bool = False,
) -> dict[str, Any]:
    """Localize every camera frame of ``scenario`` through the blackboard; returns the results dict.

    While the agents run, numpy's BLAS runs one thread per call in this process and in the agents'
    processes (:func:`models.blas.single_blas_thread`; unless ``OPENBLAS_NUM_THREADS`` or
    ``OMP_NUM_THREADS`` is set): the agents share the cores.

    Parameters
    ----------
    scenario : Scenario or path
        Must come from a file (agents in other processes load it by path).
    strategy : "associative" or "prior", optional
        Default: the scenario's ``scheduler.strategy``.
    processes : bool
        Each agent in its own OS process (default: one process, one zenoh session per agent).
    zenoh : ZenohOptions, optional
        ``connect``/``listen`` endpoints or a user config (default: loopback only).
    trace_path : path, optional
        Where the blackboard trace is written.
    timeout_s : float, optional
        Upper bound on the whole run; default scales with the route and frame counts.
    progress : callable(done, total), optional
        Called as positions are posted.
    frame_rate : float, optional
        The camera posts frames at this rate (Hz), as a real one would; default all at once.
    paced : bool
        The camera posts each frame once the frame before is answered (its track when tracking,
        else its position): the system's capacity with the track of every frame's predecessor
        there as the frame is ranked. Not with ``frame_rate``.
    inline_viewframes : bool
        The map renderer posts every viewframe with its pixels, not by reference to the viewframe
        cache entry (for agents on hosts that do not see the cache folder; as the scenario's
        ``render: {inline: true}``).
    kill_after : (agent, level, n), optional
        Fault injection for tests and demos: kill ``agent`` once ``n`` hypotheses are posted on
        ``level``.
    remote : names of agents of :func:`agent_plan`, optional
        Not started here: the run waits up to ``wait_remote_s`` for them to join (over
        ``zenoh.listen``, or ``zenoh.connect``) before posting the scenario, then counts them
        like local agents.
    run_id : str, optional
        The run's id (remote agents give it with ``--run-id``); default random.
    secret : str, optional
        The run's secret that remote agents give (``mapinterp agent --secret``); default random.
    auth : bool, optional
        Zenoh user/password authentication with the secret; default on when ``zenoh.listen``
        has a non-loopback endpoint.
    on_wait_remote : callable(commands), optional
        Called before waiting with ``{agent: argv of its mapinterp agent command}``; default:
        logged at WARNING.
    track : bool, optional
        Run the tracker (default: the scenario's ``tracking.enabled``); off, the results are the
        single-frame decisions. With ``tracking.smoothing``, the tracks are smoothed over the
        whole drive (forward-backward) before they become the results.
    on_hypothesis : callable(level, body, timestamp), optional
        Called with every hypothesis as it is first posted (phase labels, live viewers).

    Raises
    ------
    AgentError
        A ``remote`` name is not an agent of this mission, or did not join within ``wait_remote_s``.
    """
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    if scenario.path is None:
        raise ScenarioError(None, None, "the scenario must come from a file to run on the blackboard")
    check_scenario(scenario, mission=True)  # every check that can run before the run, runs now
    strategy = strategy or scenario.scheduler.strategy
    track = scenario.tracking.enabled if track is None else bool(track)
    n_frames = frame_count(scenario)
    if timeout_s is None:
        timeout_s = 120.0 + 0.5 * view_count(len(scenario.route), scenario.views_per_leg) + 2.0 * n_frames
        if scenario.refine.enabled:  # the refiner renders up to 2 + levels * grid**2 views a frame
            renders = 2 + (scenario.refine.levels * scenario.refine.grid**2 if scenario.refine.position else 0)
            timeout_s += 0.2 * n_frames * renders
        if scenario.verify.enabled:  # the verifier renders one view a candidate
            timeout_s += 0.2 * n_frames * scenario.verify.candidates
    _check_numbers(n_frames, timeout_s=timeout_s, frame_rate=frame_rate, wait_remote_s=wait_remote_s)
    if paced and frame_rate is not None:
        raise UsageError("--rate", "a camera paced on answers has no fixed rate: give one of the two")
    done = 0
    posted: dict[str, int] = {}

    def on_event(event: Event) -> None:
        nonlocal done
        h = event.hypothesis
        if h.version != 1:
            return
        posted[h.level] = posted.get(h.level, 0) + 1
        if on_hypothesis is not None:
            on_hypothesis(h.level, h.body, h.timestamp)
        if h.level == levels.POSITION:
            done += 1
            if progress is not None:
                progress(done, n_frames)
        if kill_after is not None and h.level == kill_after[1] and posted[h.level] == kill_after[2]:
            runtime.kill(kill_after[0])

    plan = agent_plan(
        scenario,
        strategy=strategy,
        frame_rate=frame_rate,
        track=track,
        paced=paced,
        inline_viewframes=inline_viewframes,
    )
    remote = sorted(set(remote))
    unknown = [name for name in remote if name not in {n for _, n, _ in plan}]
    if unknown:
        raise AgentError(
            ", ".join(unknown),
            "--remote names no agent of this mission; its agents are: " + ", ".join(n for _, n, _ in plan),
        )
    started = time.perf_counter()
    interrupted: str | None = None
    # the agents share the process: one BLAS thread each (models/blas.py), set before they start
    with (
        single_blas_thread(),
        Runtime(
            mode="processes" if processes else "inprocess",
            zenoh=zenoh,
            trace_path=trace_path,
            run_id=run_id,
            secret=secret,
            auth=auth,
        ) as runtime,
    ):
        try:
            if remote:
                waiting_since = time.monotonic()
                runtime.expect_remote(remote)
                _announce_remote(runtime, plan, remote, zenoh, on_wait_remote)
            for factory, name, options in plan:
                if name not in remote:
                    runtime.add(factory, name=name, options=options)
            if remote:
                try:
                    runtime.wait_joined(remote, timeout_s=max(0.0, waiting_since + wait_remote_s - time.monotonic()))
                except AgentError as err:
                    raise AgentError(
                        err.agent,
                        f"did not join run {runtime.run_id} within {wait_remote_s:g} s "
                        "(was it started with the printed mapinterp agent command?)",
                    ) from None
            request = levels.Scenario(path=str(Path(scenario.path).resolve()), strategy=strategy)
            runtime.post(request.level, request.to_body(), id=request.id())
            outcome = runtime.run(timeout_s=timeout_s, progress=on_event)
        except KeyboardInterrupt as err:  # Ctrl-C or SIGTERM (blackboard.signals): keep what is done
            interrupted = signal_name(err)
            log.warning("run %s interrupted by %s: stopping the agents", runtime.run_id, interrupted)
            outcome = runtime.snapshot()
            runtime.close(fast=True, reason=f"interrupted by {interrupted}")
        except AgentError as err:
            errors = runtime.snapshot().input_errors
            if errors:  # the real cause: an agent met a user's input error, then the run stalled
                name, message = next(iter(errors.items()))
                raise AgentInputError(name, message) from err
            raise
    if outcome.input_errors and interrupted is None:
        name, message = next(iter(outcome.input_errors.items()))
        raise AgentInputError(name, message)
    positions = {
        p.frame: p
        for p in (levels.Position.from_hypothesis(h) for h in outcome.hypotheses if h.level == levels.POSITION)
    }
    poses = {p.frame: p for p in (levels.Pose.from_hypothesis(h) for h in outcome.hypotheses if h.level == levels.POSE)}
    truths = {
        t.frame: t for t in (levels.Truth.from_hypothesis(h) for h in outcome.hypotheses if h.level == levels.TRUTH)
    }
    tracks = {
        t.frame: t for t in (levels.Track.from_hypothesis(h) for h in outcome.hypotheses if h.level == levels.TRACK)
    }
    frames_seen = {
        levels.SensorFrame.from_hypothesis(h).frame for h in outcome.hypotheses if h.level == levels.SENSOR_FRAME
    }
    first_frame = min((h.timestamp for h in outcome.hypotheses if h.level == levels.SENSOR_FRAME), default=None)
    last_position = max((h.timestamp for h in outcome.hypotheses if h.level == levels.POSITION), default=None)
    agents = dict(outcome.agents)
    elapsed = time.perf_counter() - started
    dead = {name: status for name, status in agents.items() if status.startswith("dead")}
    # agents not ok: dead ones, and live ones whose activations raised (what they did not post is missing)
    not_ok = {**{name: why for name, why in outcome.failures.items() if name not in dead}, **dead}
    route_xy = [[float(x), float(y)] for x, y in scenario.route]
    route_points = route_points_of(scenario)
    estimates = _track_estimates(tracks, sorted(frames_seen), scenario) if track else {}
    records = []
    for f in sorted(frames_seen | set(range(n_frames))):
        if f not in frames_seen:
            why = (
                "interrupted before the camera posted it"
                if interrupted
                else "the camera never posted it" + (f" (agents not ok: {not_ok})" if not_ok else "")
            )
        elif interrupted:
            why = f"interrupted by {interrupted} before it was localized"
        else:
            why = "no position was posted" + (f" (agents not ok: {not_ok})" if not_ok else "")
        rec = frame_record(
            positions.get(f),
            frame=f,
            truth=truths.get(f),
            route_xy=route_xy,
            missing=why,
            pose=poses.get(f),
            route_points=route_points,
        )
        rec["missing"] = f not in frames_seen
        rec["interrupted"] = interrupted is not None and f not in positions
        p = positions.get(f)
        rec["track_prior"] = bool(p is not None and p.track_prior)
        untracked = track and f in positions and f not in estimates
        if untracked:
            rec["reason"] += "; no track was posted (the single-frame decision stands)"
        rec = with_track(rec, estimates.get(f))
        if untracked:
            rec["state"] = "lost"  # not tracked: the blind single-frame decision is the answer
        records.append(rec)
    summary = summarize(records)
    summary["frames_expected"] = n_frames
    summary["posted"] = len(frames_seen)
    summary["missing"] = sum(1 for r in records if r.get("missing"))
    summary["wall_s"] = elapsed
    # throughput of localization proper: first camera frame posted to last position posted
    span = None if first_frame is None or last_position is None else last_position - first_frame
    summary["localization_s"] = span
    summary["frames_per_s"] = (len(frames_seen) / span) if span else None
    degraded = [f"agent {name} {status}" for name, status in sorted(dead.items())]
    degraded += [f"agent {name}: {why}" for name, why in sorted(outcome.failures.items()) if name not in dead]
    if track:
        degraded += _tracking_degraded(positions, estimates)
    if summary["missing"]:
        degraded.append(f"{summary['missing']} of {n_frames} frames never posted")
    if interrupted:
        degraded.append(f"interrupted by {interrupted}")
    results = {
        "scenario": scenario.name,
        "scenario_path": str(Path(scenario.path).resolve()),
        "strategy": strategy,
        "tracking": track,
        "smoothing": bool(track and scenario.tracking.smoothing),
        "mode": "processes" if processes else "inprocess",
        "agents": agents,
        "frames": records,
        "summary": summary,
        "degraded": degraded,
        "interrupted": interrupted,
    }
    if scenario.map_frame is not None:
        add_map_coordinates(results, scenario.map_frame)
    return results


def _tracking_degraded(positions: dict[int, levels.Position], estimates: dict[int, dict[str, Any]]) -> list[str]:
    """What the tracker's absence cost a tracked run: frames analysed blind because the track
    of the frame before did not come (the scheduler's fallback), frames left without a track."""
    out = []
    blind = sorted(f for f, p in positions.items() if any(d.startswith(f"{TRACKER}:") for d in p.degraded))
    if blind:
        out.append(f"{TRACKER}: {len(blind)} frames analysed blind, the track of the frame before missing: {blind}")
    untracked = sorted(f for f in positions if f not in estimates)
    if untracked:
        out.append(f"{TRACKER}: no track for {len(untracked)} frames (their single-frame decisions stand): {untracked}")
    return out


def _track_estimates(
    tracks: dict[int, levels.Track], frames: Sequence[int], scenario: Scenario
) -> dict[int, dict[str, Any]]:
    """Each frame's track as the results need it (:func:`~knowledge_sources.results.with_track`):
    the tracker's online estimates, or with ``tracking.smoothing`` the estimates of a
    forward-backward pass over every frame's evidence (offline)."""
    order = [f for f in frames if f in tracks]
    if not scenario.tracking.smoothing:
        return {
            f: {
                "route_point": t.route_point,
                "position": t.position,
                "heading_deg": t.heading_deg,
                "confidence": t.confidence,
                "state": t.state,
                "arc_m": t.arc_m,
                "belief": t.belief,
            }
            for f, t in tracks.items()
        }
    import numpy as np

    from models.tracking import smooth

    logliks = [None if tracks[f].loglik is None else np.asarray(tracks[f].loglik, np.float64) for f in order]
    estimates = smooth(scenario.route, logliks, spec=scenario.tracking, dts=[tracks[f].dt for f in order])
    return {f: {**e.to_dict(), "belief": e.belief} for f, e in zip(order, estimates)}


def _announce_remote(
    runtime: Runtime,
    plan: list[tuple[str, str, dict[str, Any]]],
    remote: list[str],
    zenoh: ZenohOptions | None,
    on_wait_remote: Callable[[dict[str, list[str]]], None] | None,
) -> None:
    """Tell the user how to start each remote agent: where to connect is the first ``listen``
    endpoint, else the first ``connect`` one (a router both reach), else the node's own."""
    from knowledge_sources.commands.agent import command_line

    zenoh = zenoh or ZenohOptions()
    endpoint = (zenoh.listen or zenoh.connect or [runtime.node.endpoint])[0]
    commands = {
        name: command_line(
            factory,
            name,
            options,
            run_id=runtime.run_id,
            connect=endpoint,
            zenoh_config=zenoh.config_file,
            secret=runtime.secret,
        )
        + (["--auth"] if runtime.auth and is_loopback(endpoint) else [])
        for factory, name, options in plan
        if name in remote
    }
    if on_wait_remote is not None:
        on_wait_remote(commands)
    else:
        for name, argv in commands.items():
            log.warning("waiting for remote agent %s: start it with %s", name, shlex.join(argv))
