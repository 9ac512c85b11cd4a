"""A run as a Rerun recording (``.rrd``, or sent to a Rerun viewer): rerun-sdk is optional.

``pip install 'mapinterp[rerun]'`` installs it; without it :func:`require_rerun` raises a
:class:`RerunMissingError` (a :class:`~models.errors.ModelError`, so the command line prints it
as one line) saying so. Entities, on the ``frame`` timeline
(sequence: the camera frame index) and the ``run_time`` timeline (seconds since the run started,
when the frame's position was posted):

==========================  ==============================================================
``camera/image``            the camera frame (RGB)
``camera/image/answers``    the landmark questions and answers: the region asked about (the
                            landmark's box in the candidate viewframe), labelled
                            ``H1 present 0.91 (V6)``, green present, red absent, yellow
                            uncertain (a score between the detector's thresholds)
``viewframe/chosen``        the viewframe the scheduler chose (none when not localized)
``viewframe/true``          the viewframe nearest the true pose
``edges/camera``            the camera frame's edge image, as the associative memory sees it
``edges/chosen``            the chosen viewframe's edge image
``ranking``                 the error variances of the five best viewframes (bar chart),
                            ``ranking/labels`` which viewframes they are
``scheduler/steps``         the scheduler's steps and its reason, as markdown
``map/terrain``             (static) the hillshaded DEM, north up, one pixel per DEM cell
``map/route``, ``map/landmarks``  (static) route and landmark positions
``map/truth``, ``map/estimate``   the frame's true and estimated positions
``map/track``               the estimated positions so far
==========================  ==============================================================

Map entities are in the map image's pixel coordinates: world (x, y) metres is
``(x / cell + 0.5, rows - 0.5 - y / cell)``.
"""

from __future__ import annotations

import json
import logging
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from models.errors import InputError, ModelError

__all__ = [
    "RerunMissingError",
    "require_rerun",
    "RerunLogger",
    "open_stream",
    "export_trace",
    "log_run",
    "run_from_trace",
]

log = logging.getLogger(__name__)

#: a detector's answer: present True, absent False, None when its score falls between the thresholds
_VERDICT = {True: "present", False: "absent", None: "uncertain"}
_VERDICT_COLOUR = {"present": [40, 200, 60], "absent": [230, 40, 40], "uncertain": [240, 200, 0]}

MISSING = "rerun-sdk is not installed: pip install 'mapinterp[rerun]' (or pip install rerun-sdk)"


class RerunError(ModelError):
    """A Rerun viewer could not be started or reached, or a recording not written."""


class RerunMissingError(RerunError):
    """The optional rerun-sdk is not installed."""


def require_rerun() -> Any:
    """The ``rerun`` module, or a :class:`RerunMissingError` saying how to install it."""
    try:
        import rerun
    except ImportError:
        raise RerunMissingError(MISSING) from None
    return rerun


def run_from_trace(records: list[dict[str, Any]]) -> dict[str, Any]:
    """The parts of a traced run the recording shows: per frame its position body, answers and
    truth pose; the run id and start time."""
    t_first = min((float(r["t"]) for r in records if isinstance(r.get("t"), (int, float))), default=0.0)
    start = next((r for r in records if r.get("kind") == "run_start"), {})
    positions: dict[int, dict[str, Any]] = {}
    times: dict[int, float] = {}
    answers: dict[int, list[dict[str, Any]]] = defaultdict(list)
    truths: dict[int, list[float]] = {}
    for r in records:
        if r.get("kind") != "post" or not isinstance(r.get("body"), dict):
            continue
        body, level = r["body"], r.get("level")
        if "frame" not in body:
            continue
        f = int(body["frame"])
        if level == "position":
            positions[f], times[f] = body, float(r["t"]) - t_first
        elif level == "answer":
            answers[f].append(body)
        elif level == "truth":
            truths[f] = list(body.get("pose") or [])
    return {
        "run_id": start.get("run_id", "run"),
        "positions": positions,
        "times": times,
        "answers": dict(answers),
        "truths": truths,
    }


def _u8(image: np.ndarray) -> np.ndarray:
    a = np.asarray(image, dtype=np.float32)
    lo, hi = float(a.min()), float(a.max())
    return np.zeros(a.shape, np.uint8) if hi <= lo else ((a - lo) / (hi - lo) * 255).astype(np.uint8)


def _hillshade_rgb(terrain) -> np.ndarray:
    import matplotlib

    shade = terrain.hillshade()[::-1]
    h = terrain.heights[::-1]
    colours = matplotlib.colormaps["gist_earth"]((h - h.min()) / (np.ptp(h) or 1.0))[..., :3]
    return (np.clip(colours * (0.35 + 0.65 * shade[..., None]), 0, 1) * 255).astype(np.uint8)


def _steps_markdown(body: dict[str, Any]) -> str:
    lines = [
        f"**frame {body.get('frame')}**: viewframe {body.get('viewframe')}, confidence "
        f"{float(body.get('confidence', 0.0)):.2f}, {body.get('queries', 0)} queries, "
        f"{body.get('backtracks', 0)} backtracks",
        "",
        f"reason: {body.get('reason', '')}",
        "",
    ]
    for i, step in enumerate(body.get("steps") or []):
        lines.append(f"{i + 1}. " + json.dumps(step, sort_keys=True, default=str))
    return "\n".join(lines)


class RerunLogger:
    """Logs a run to the recording stream ``rec``: the static map at construction, then one
    frame per :meth:`frame` call, or live from the blackboard's hypotheses by :meth:`on_hypothesis`."""

    def __init__(self, rec, replay) -> None:
        self.rr = require_rerun()
        self.rec, self.replay = rec, replay
        terrain = replay.environment.terrain
        self._rows, self._cs = terrain.shape[0], terrain.cell_size
        self.route = [tuple(p) for p in replay.scenario.route]
        from models.route_views import view_route

        self.views_per_leg = replay.scenario.views_per_leg
        self.route_points = view_route(self.route, self.views_per_leg)[2]  # each viewframe's route point
        self.track: list[list[float]] = []
        self._answers: dict[int, list[dict[str, Any]]] = defaultdict(list)
        self._truths: dict[int, list[float]] = {}
        self._t0: float | None = None
        self.frames_logged = 0
        rr = self.rr
        rec.log("map/terrain", rr.Image(_hillshade_rgb(terrain)), static=True)
        rec.log(
            "map/route", rr.LineStrips2D([[self.px(x, y) for x, y in self.route]], colors=[[20, 20, 20]]), static=True
        )
        lms = replay.environment.landmarks
        if lms:
            rec.log(
                "map/landmarks",
                rr.Points2D(
                    [self.px(lm.x, lm.y) for lm in lms],
                    labels=[lm.id for lm in lms],
                    colors=[[250, 200, 0]] * len(lms),
                    radii=2.0,
                ),
                static=True,
            )

    def px(self, x: float, y: float) -> list[float]:
        """Map-image pixel coordinates of world (x, y) metres."""
        return [x / self._cs + 0.5, self._rows - 0.5 - y / self._cs]

    def on_hypothesis(self, level: str, body: Any, t: float) -> None:
        """Feed every posted hypothesis (level, body, time.time()); a position logs its frame."""
        if self._t0 is None:
            self._t0 = t
        if not isinstance(body, dict) or "frame" not in body:
            return
        f = int(body["frame"])
        if level == "answer":
            self._answers[f].append(body)
        elif level == "truth":
            self._truths[f] = list(body.get("pose") or [])
        elif level == "position":
            self.frame(f, body, answers=self._answers.pop(f, []), truth=self._truths.get(f), run_time=t - self._t0)

    def frame(
        self,
        f: int,
        body: dict[str, Any],
        *,
        answers: Sequence[dict[str, Any]] = (),
        truth: list[float] | None = None,
        run_time: float | None = None,
    ) -> None:
        """Log camera frame ``f`` with its position ``body`` (empty: not localized), answers and truth."""
        from knowledge_sources.replay import answer_box
        from knowledge_sources.results import nearest_viewframe
        from models.route_views import view_on_point

        rr, rec, replay = self.rr, self.rec, self.replay
        rec.set_time("frame", sequence=f)
        if run_time is not None:
            rec.set_time("run_time", duration=run_time)
        frame = replay.frames.get(f)
        if frame is not None:
            rec.log("camera/image", rr.Image(frame.image))
            rec.log("edges/camera", rr.Image(_u8(replay.edges(frame.image))))
        mins, sizes, labels, colours = [], [], [], []
        for a in answers:
            vf_index = a.get("viewframe")
            box = (
                None
                if vf_index is None or not 0 <= int(vf_index) < len(replay.viewframes)
                else answer_box(replay.viewframes[int(vf_index)], str(a.get("landmark")))
            )
            if box is None:
                continue
            r0, c0, r1, c1 = box
            mins.append([c0, r0])
            sizes.append([c1 - c0 + 1, r1 - r0 + 1])
            verdict = _VERDICT[a.get("present")]
            labels.append(f"{a.get('landmark')} {verdict} {float(a.get('score', 0.0)):.2f} (V{vf_index})")
            colours.append(_VERDICT_COLOUR[verdict])
        rec.log(
            "camera/image/answers",
            rr.Boxes2D(mins=mins, sizes=sizes, labels=labels, colors=colours) if mins else rr.Clear(recursive=False),
        )
        chosen = body.get("viewframe")
        if chosen is not None and 0 <= int(chosen) < len(replay.viewframes):
            vf = replay.viewframes[int(chosen)]
            rec.log("viewframe/chosen", rr.Image(vf.image))
            rec.log("edges/chosen", rr.Image(_u8(replay.edges(vf.image))))
        else:
            rec.log("viewframe/chosen", rr.Clear(recursive=False))
            rec.log("edges/chosen", rr.Clear(recursive=False))
        truth = truth or (list(frame.truth) if frame is not None and frame.truth else None)
        true_vf = None
        if truth:
            true_vf = nearest_viewframe(truth[0], truth[1], self.route)  # a route point; shown: the viewframe on it
            rec.log("viewframe/true", rr.Image(replay.viewframes[view_on_point(true_vf, self.views_per_leg)].image))
            rec.log(
                "map/truth",
                rr.Points2D([self.px(truth[0], truth[1])], colors=[[0, 0, 0]], radii=2.5, labels=[f"truth {f}"]),
            )
        ranking = body.get("ranking") or []
        if ranking:
            rec.log("ranking", rr.BarChart([float(v) for _, v in ranking]))
            rec.log(
                "ranking/labels",
                rr.TextDocument("  ".join(f"#{i + 1} V{int(k)} {float(v):.4g}" for i, (k, v) in enumerate(ranking))),
            )
        position = body.get("position")
        if position is not None:
            p = self.px(float(position[0]), float(position[1]))
            self.track.append(p)
            ok = true_vf is not None and chosen is not None and int(self.route_points[int(chosen)]) == true_vf
            rec.log(
                "map/estimate",
                rr.Points2D([p], colors=[[40, 200, 60] if ok else [230, 40, 40]], radii=2.5, labels=[f"V{chosen}"]),
            )
            rec.log("map/track", rr.LineStrips2D([self.track], colors=[[30, 120, 255]]))
        if body:
            rec.log("scheduler/steps", rr.TextDocument(_steps_markdown(body), media_type="text/markdown"))
        self.frames_logged += 1


def log_run(rec, run: dict[str, Any], replay) -> int:
    """Log ``run`` (:func:`run_from_trace`) with the images of ``replay`` to the recording stream
    ``rec``; returns the number of frames logged."""
    logger = RerunLogger(rec, replay)
    for f in sorted(set(replay.frames) | set(run["positions"])):
        logger.frame(
            f,
            run["positions"].get(f, {}),
            answers=run["answers"].get(f, []),
            truth=run["truths"].get(f),
            run_time=run["times"].get(f),
        )
    return logger.frames_logged


def open_stream(target: str, *, recording_id: str):
    """A recording stream to ``target``: a ``.rrd`` path (saved), ``spawn`` (a new Rerun viewer)
    or a viewer's gRPC URL (``rerun+http://127.0.0.1:9876/proxy``)."""
    rr = require_rerun()
    rec = rr.RecordingStream("mapinterp", recording_id=recording_id)
    try:
        if target == "spawn":
            rec.spawn()
        elif target.endswith(".rrd"):
            Path(target).parent.mkdir(parents=True, exist_ok=True)
            rec.save(target)
        else:
            rec.connect_grpc(target)
    except Exception as exc:  # rerun raises plain RuntimeError/OSError for a viewer it cannot start or reach
        what = "start a Rerun viewer" if target == "spawn" else f"open {target}"
        raise RerunError(f"cannot {what} ({exc}); give --rerun FILE.rrd or a running viewer's URL") from None
    return rec


def export_trace(
    records: list[dict[str, Any]],
    out: str | Path,
    *,
    scenario_path: str | Path | None = None,
    trace_path: str | Path | None = None,
) -> Path:
    """Write the Rerun recording of a traced run to ``out`` (.rrd); images are rendered again from
    the run's scenario (``scenario_path``, default: the path the trace names)."""
    require_rerun()
    from knowledge_sources.replay import replay, scenario_path_of_trace
    from models.scenario import load_scenario

    scenario_path = scenario_path or scenario_path_of_trace(records)
    if scenario_path is None:
        raise InputError(trace_path, "the trace names no scenario file: give --scenario")
    run = run_from_trace(records)
    scene = replay(load_scenario(scenario_path))
    out = Path(out)
    rec = open_stream(str(out) if out.suffix == ".rrd" else str(out) + ".rrd", recording_id=str(run["run_id"]))
    n = log_run(rec, run, scene)
    rec.flush()
    rec.disconnect()
    log.info("rerun recording of %d frames written to %s", n, out)
    return out
