"""The results file of ``mapinterp run``: a contract other tools read.

::

    {"scenario": str, "strategy": str, "scenario_path": str,
     "frames": [{"frame": i, "viewframe": k | null, "view": v | null, "position": [x, y] | null,
                 "heading_deg": h | null, "confidence": c, "queries": q, "backtracks": b,
                 "latency_ms": t, "ranking": [[k, variance], ...first 5],
                 "truth_viewframe": k | null, "correct": bool | null, "reason": str,
                 "truth": [x, y, heading_deg] | null, "error_m": e | null,
                 "route_position": [x, y] | null, "route_heading_deg": h | null,
                 "heading_error_deg": d | null, "pose": {pitch_deg, sigma_along_m, ...} | null}],
     "summary": {"frames": n, "top1": a | null, "mean_queries": q, "mean_error_m": e | null,
                 "median_error_m": e | null, "median_heading_error_deg": d | null,
                 "latency_ms_p50": t}}

Tracking (on by default, ``mapinterp run --no-track`` turns it off): each frame's top-level
``viewframe``, ``position``, ``heading_deg`` and ``confidence`` are the system's final answer,
the tracker's when it ran; the single-frame decision of the scene analysis is kept beside them
as ``frame_only: {viewframe, position, heading_deg, confidence, correct, error_m}``, and
``state`` says whether the tracker was ``"tracking"`` or ``"lost"`` (null: no track), with
``arc_m`` (the track's arc length along the route) and ``belief`` (posterior probability of
each route point). The summary adds ``top1_frame_only``, ``median_error_m`` and
``mean_error_m_frame_only``. Without tracking, the top level is the single-frame decision and
``frame_only`` repeats it.

On a georeferenced map the file also has ``"crs"`` (the map CRS, e.g. ``EPSG:32617``) and
``"map_frame"``, and each frame ``position_map`` / ``truth_map`` ([x, y] in the map CRS) and
``position_lonlat`` / ``truth_lonlat`` ([lon, lat] WGS84 degrees); ``position`` and ``truth``
stay in local metres (:mod:`models.georef`).

A frame is *correct* when its ``viewframe`` is the route point nearest its truth position;
``mean_error_m`` is the mean distance in metres between the estimated and the true ``(x, y)``.
``position`` and ``heading_deg`` are the refined pose's when the refiner posted one
(``route_position``, ``route_heading_deg``: the chosen viewframe's place and heading).
A frame that could not be localized has ``viewframe: null`` and says why in ``reason``.
``view`` is the viewframe the single-frame decision chose: the route point itself, unless the map
has viewframes between the route points (``render.views_per_leg`` > 1), when ``viewframe`` (and
the ``ranking``) name the route point nearest that view and ``position`` is the view's.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from models.errors import InputError

if TYPE_CHECKING:
    from knowledge_sources.levels import Pose as PoseMessage
    from knowledge_sources.levels import Position, Truth

__all__ = [
    "add_map_coordinates",
    "frame_record",
    "load_results",
    "nearest_viewframe",
    "summarize",
    "with_track",
    "write_results",
    "finite_json",
    "check_writable",
]


def nearest_viewframe(x: float, y: float, route_xy: Sequence[Sequence[float]]) -> int:
    """Index of the route point nearest the world point ``(x, y)``."""
    pts = np.asarray(route_xy, dtype=np.float64)
    return int(np.argmin(np.hypot(pts[:, 0] - x, pts[:, 1] - y)))


def frame_record(
    position: Position | None,
    *,
    frame: int,
    truth: Truth | None,
    route_xy: Sequence[Sequence[float]],
    missing: str = "no position was posted",
    pose: PoseMessage | None = None,
    route_points: Sequence[int] | None = None,
) -> dict[str, Any]:
    """One frame's entry of the results file, from the frame's ``position`` message (None: none was
    posted, the entry says ``missing`` as its reason), its ``truth`` message (None: unknown) and its
    refined ``pose`` (None: not refined). With a pose, ``position`` and ``heading_deg`` are the
    refined ones and ``route_position``/``route_heading_deg`` the chosen viewframe's; ``pose``
    holds the refinement (pitch, uncertainty). ``route_points``: the route point of each
    viewframe when the map has viewframes between the route points (``render.views_per_leg``):
    ``viewframe`` and the ``ranking`` are then route points (the ranking's first viewframe of
    each), ``view`` the chosen viewframe itself. The one function that turns a decision into a
    results entry."""
    t = None if truth is None else [float(v) for v in truth.pose]
    truth_vf = None if t is None else nearest_viewframe(t[0], t[1], route_xy)
    if position is None:
        viewframe, xy, heading, confidence, queries, backtracks = None, None, None, 0.0, 0, 0
        latency, ranking, reason = None, [], missing
    else:
        viewframe, xy, heading = position.viewframe, position.position, position.heading_deg
        confidence, queries, backtracks = position.confidence, position.queries, position.backtracks
        latency, ranking, reason = position.latency_ms, position.ranking, position.reason
    view = viewframe
    if route_points is not None:
        viewframe = None if viewframe is None else int(route_points[int(viewframe)])
        ranking = _by_point(ranking, route_points)
    route_xy_, route_heading = xy, heading
    if pose is not None and position is not None:
        xy, heading = [pose.x, pose.y], pose.heading_deg
    error = None
    if t is not None and xy is not None:
        error = math.hypot(xy[0] - t[0], xy[1] - t[1])
    record: dict[str, Any] = {
        "frame": int(frame),
        "viewframe": None if viewframe is None else int(viewframe),
        "view": None if view is None else int(view),
        "position": None if xy is None else [float(xy[0]), float(xy[1])],
        "heading_deg": None if heading is None else float(heading),
        "confidence": float(confidence),
        "queries": int(queries),
        "backtracks": int(backtracks),
        "latency_ms": None if latency is None else float(latency),
        "ranking": [[int(k), float(v)] for k, v in list(ranking)[:5]],
        "truth": t,
        "truth_viewframe": truth_vf,
        "correct": None if truth_vf is None else (viewframe is not None and int(viewframe) == truth_vf),
        "error_m": error,
        "reason": reason,
    }
    record["route_position"] = None if route_xy_ is None else [float(route_xy_[0]), float(route_xy_[1])]
    record["route_heading_deg"] = None if route_heading is None else float(route_heading)
    record["heading_error_deg"] = (
        None if t is None or heading is None else abs((float(heading) - t[2] + 180.0) % 360.0 - 180.0)
    )
    record["pose"] = (
        None
        if pose is None
        else {
            "pitch_deg": pose.pitch_deg,
            "sigma_along_m": pose.sigma_along_m,
            "sigma_across_m": pose.sigma_across_m,
            "sigma_heading_deg": pose.sigma_heading_deg,
            "score": pose.score,
            "start_score": pose.start_score,
            "renders": pose.renders,
        }
    )
    if position is not None:
        record["degraded"] = list(position.degraded)
        record["steps"] = list(position.steps)
    return record


def _by_point(ranking: Sequence[Sequence[float]], route_points: Sequence[int]) -> list[list[float]]:
    """A ranking ``[[viewframe, score], ...]`` as route points: each point once, at its first viewframe's place."""
    from models.route_views import first_per_point

    return [[int(route_points[k]), v] for k, v in first_per_point(ranking, route_points)]


def with_track(record: dict[str, Any], track: dict[str, Any] | None) -> dict[str, Any]:
    """``record`` (a single-frame :func:`frame_record`) with its decision moved to ``frame_only``
    and, when ``track`` (the tracker's estimate: ``route_point``, ``position``, ``heading_deg``,
    ``confidence``, ``state``, ``arc_m``, ``belief``) is given, the track as the final answer.

    The final heading is the frame's refined heading (``heading_deg`` of ``record``, when the pose
    was refined) when the track's route point is the frame's own or a neighbour of it: the
    camera's own heading, measured against a view a route spacing from the camera at most, whose
    far terrain barely moves over that distance (a camera looks a few degrees off the road, and
    at a bend the road's direction at the track's place is not the viewframe's). Otherwise (no
    refinement, or the frame chose another place) it is the track's, the route's direction at
    its place."""
    out = dict(record)
    out["frame_only"] = {
        k: record[k] for k in ("viewframe", "position", "heading_deg", "confidence", "correct", "error_m")
    }
    out["state"] = None
    if track is None:
        return out
    truth = record["truth"]
    vf = int(track["route_point"])
    pos = [float(track["position"][0]), float(track["position"][1])]
    heading = float(track["heading_deg"])
    own = record.get("viewframe")
    if record.get("pose") is not None and record.get("heading_deg") is not None and own is not None:
        if abs(int(own) - vf) <= 1:
            heading = float(record["heading_deg"])
    out.update(
        {
            "viewframe": vf,
            "position": pos,
            "heading_deg": heading,
            "heading_error_deg": None if truth is None else abs((heading - truth[2] + 180.0) % 360.0 - 180.0),
            "confidence": float(track["confidence"]),
            "state": str(track["state"]),
            "arc_m": float(track["arc_m"]),
            "belief": [round(float(p), 5) for p in track.get("belief", [])],
            "correct": None if record["truth_viewframe"] is None else vf == record["truth_viewframe"],
            "error_m": None if truth is None else math.hypot(pos[0] - truth[0], pos[1] - truth[1]),
        }
    )
    return out


def summarize(frames: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The ``summary`` block of a results file."""
    judged = [f for f in frames if f["correct"] is not None]
    errors = [f["error_m"] for f in frames if f.get("error_m") is not None]
    headings = [f["heading_error_deg"] for f in frames if f.get("heading_error_deg") is not None]
    lat = [f["latency_ms"] for f in frames if f["latency_ms"] is not None]
    only = [f["frame_only"] for f in frames if f.get("frame_only") is not None]
    only_judged = [f for f in only if f["correct"] is not None]
    only_errors = [f["error_m"] for f in only if f.get("error_m") is not None]
    return {
        "frames": len(frames),
        "localized": sum(f["viewframe"] is not None for f in frames),
        "top1": (sum(bool(f["correct"]) for f in judged) / len(judged)) if judged else None,
        "mean_queries": float(np.mean([f["queries"] for f in frames])) if frames else 0.0,
        "mean_backtracks": float(np.mean([f["backtracks"] for f in frames])) if frames else 0.0,
        "mean_error_m": float(np.mean(errors)) if errors else None,
        "median_error_m": float(np.median(errors)) if errors else None,
        "median_heading_error_deg": float(np.median(headings)) if headings else None,
        "latency_ms_p50": float(np.percentile(lat, 50)) if lat else 0.0,
        "latency_ms_p99": float(np.percentile(lat, 99)) if lat else 0.0,
        "top1_frame_only": (sum(bool(f["correct"]) for f in only_judged) / len(only_judged)) if only_judged else None,
        "mean_error_m_frame_only": float(np.mean(only_errors)) if only_errors else None,
        "tracking": sum(f.get("state") == "tracking" for f in frames),
        "lost": sum(f.get("state") == "lost" for f in frames),
    }


def add_map_coordinates(results: dict[str, Any], frame: Any) -> dict[str, Any]:
    """Add the map-CRS and lon/lat coordinates of a georeferenced run to ``results`` (in place).

    ``frame`` is the scenario's :class:`~models.georef.MapFrame`; returns ``results``.
    """
    results["crs"] = frame.name
    results["map_frame"] = frame.describe()
    for rec in results["frames"]:
        for key in ("position", "truth"):
            xy = rec.get(key)
            if xy is None:
                rec[f"{key}_map"] = rec[f"{key}_lonlat"] = None
                continue
            mx, my = frame.to_map(xy[0], xy[1])
            lon, lat = frame.to_lonlat(xy[0], xy[1])
            rec[f"{key}_map"] = [float(mx), float(my)]
            rec[f"{key}_lonlat"] = [float(lon), float(lat)]
        only = rec.get("frame_only")
        if isinstance(only, dict):  # the single-frame decision beside the track, in map coordinates too
            xy = only.get("position")
            only["position_map"] = None if xy is None else [float(v) for v in frame.to_map(xy[0], xy[1])]
            only["position_lonlat"] = None if xy is None else [float(v) for v in frame.to_lonlat(xy[0], xy[1])]
    return results


def finite_json(value: Any) -> Any:
    """``value`` with every non-finite float (inf, NaN) replaced by None: strict JSON."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    if isinstance(value, np.generic):
        return finite_json(value.item())
    return value


def check_writable(path: str | Path, what: str) -> Path:
    """Refuse, before a run, an output path that cannot be written: a folder, a special or
    read-only file, a folder that cannot be created. Creates nothing."""
    path = Path(path)
    if path.is_dir():
        raise InputError(path, f"{what}: is a folder, not a file")
    if path.exists():
        if not path.is_file():
            raise InputError(path, f"{what}: not a regular file")
        if not os.access(path, os.W_OK):
            raise InputError(path, f"{what}: not writable")
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(path, f"{what}: {parent} is not a folder")
    try:  # the only sure test (root may write anywhere, but not into /proc): a file made and removed
        with tempfile.NamedTemporaryFile(dir=parent, prefix=".mapinterp-check-"):
            pass
    except OSError as err:
        raise InputError(path, f"{what}: cannot create files in {parent} ({err.strerror or err})") from None
    return path


def write_results(path: str | Path, results: dict[str, Any]) -> Path:
    """Write a results dict as indented strict JSON (no Infinity, no NaN: those become null),
    creating the folder; returns the path. Raises :class:`InputError` when it cannot be written."""
    path = Path(path)
    tmp = path.with_suffix(path.suffix + ".tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(json.dumps(finite_json(results), indent=1, allow_nan=False) + "\n")
        tmp.replace(path)
    except OSError as err:
        raise InputError(path, f"cannot write the results: {err.strerror or err}") from None
    return path


class _Frame(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    frame: int = Field(ge=0)
    viewframe: int | None = Field(ge=0)
    position: tuple[float, float] | None
    heading_deg: float | None = None
    confidence: float = 0.0
    queries: int = Field(default=0, ge=0)
    backtracks: int = Field(default=0, ge=0)
    latency_ms: float | None = None
    ranking: list[tuple[int, float]] = []
    truth: tuple[float, float, float] | None = None
    truth_viewframe: int | None = Field(default=None, ge=0)
    correct: bool | None = None
    error_m: float | None = None
    reason: str = ""


class _Summary(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    frames: int = Field(ge=0)
    top1: float | None = None
    mean_queries: float = 0.0
    mean_error_m: float | None = None
    latency_ms_p50: float = 0.0


class _Results(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    scenario: str
    strategy: str
    scenario_path: str | None = None
    frames: list[_Frame]
    summary: _Summary


def load_results(path: str | Path) -> dict[str, Any]:
    """Read and validate a results file; :class:`~models.errors.InputError` names the file,
    the field and the problem (``r.json: frames[3].viewframe: must be an integer``)."""
    from models.scenario import validation_problem

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "results file not found")
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(path, f"not a JSON results file ({err})") from None
    for key in ("scenario", "strategy", "frames", "summary"):
        if not isinstance(data, dict) or key not in data:
            raise InputError(path, f"missing field {key!r}: not a mapinterp results file")
    try:
        checked = _Results.model_validate(data)
    except ValidationError as exc:
        field, message = validation_problem(exc)
        raise InputError(path, f"{field}: {message}" if field else message) from None
    return checked.model_dump(mode="json")  # the values as validated ("3" read as 3), unknown fields kept
