"""Drives ranked by every ranking source, without the blackboard: the data the tracker's
calibration (bench/tracking_calibrate.py) and benchmark (bench/tracking.py) read.

:func:`ranked_drive` renders a scenario's viewframes, stores them in the scenario's memory,
simulates (or reads) its camera frames and ranks each one, exactly as the agents do: the
associative memory (models.world.World, models.index.ViewframeIndex, the indexers' call) and,
when the scenario enables it, the skyline (models.skyline, the skyline ranker's call), and
with the verification on (the scenario's ``verify``) the verifier's correlations of the frames
the scheduler would have verified (models.verify, the verifier's call). It returns plain arrays: per frame each source's errors indexed by route point, the true position,
the time, and the true route point (nearest to the truth, the results' criterion).
:func:`observed` turns them into what the tracker observes: one source's errors, or the
sources fused by the scheduler's rule (knowledge_sources.fusion).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from models.index import ViewframeIndex  # noqa: E402
from models.scenario import Scenario, load_scenario  # noqa: E402
from models.tracking import ranking_vector  # noqa: E402
from models.world import World  # noqa: E402

__all__ = ["ranked_drive", "with_drive", "observed", "per_point", "views_per_leg", "OBSERVE"]

#: what the tracker may observe: the associative memory alone, or every ranking source fused
OBSERVE = ("associative", "fused")


def with_drive(scenario: Scenario, drive: dict[str, Any], *, seed: int, path: Path) -> Scenario:
    """``scenario`` with ``sensor.simulate.drive = drive`` and simulation seed ``seed``, as a file
    at ``path`` (so it can also run on the blackboard)."""
    import yaml

    data = scenario.model_dump(mode="json", exclude_none=True)
    sim = dict((data.get("sensor") or {}).get("simulate") or {})
    sim.update({"drive": drive, "seed": int(seed)})
    data["sensor"] = {"simulate": sim}
    data.pop("expect", None)
    path.write_text(yaml.safe_dump(data))
    return load_scenario(path)


def ranked_drive(
    scenario: Scenario | str | Path, *, transform: Callable[[np.ndarray, int], np.ndarray] | None = None
) -> dict[str, Any]:
    """Rank every camera frame of ``scenario`` against its viewframes (see the module docstring);
    ``transform(image, frame index)`` (optional) changes each camera image (H, W, 3) uint8 first
    (bench/perturb.py).

    Returns ``{"name", "route" (N, 2), "variances" (T, N) associative error variances,
    "skyline" (T, N) skyline errors (degrees) or None when the scenario has no skyline,
    "skyline_weight", "truth" (T, 3) x, y, heading, "times" (T,) or NaN, "true_point" (T,),
    "rank_ms" (T,), "camera_hw" (the camera images' height and width)}``.
    """
    from knowledge_sources.results import nearest_viewframe
    from models.skyline import match_skylines, skyline_from_image

    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    with World(sc) as world:
        vfs = world.viewframes
        frames = world.sensor_frames
        index = ViewframeIndex(sc.memory, seed=0)
        index.add([v.image for v in vfs], list(range(len(vfs))))
        n = len(vfs)
        sky = sc.skyline
        refs = np.stack([v.skyline for v in vfs]) if sky.enabled else None
        match = sky.match_options()
        variances, skyline, rank_ms, verified = [], [], [], []
        for i, f in enumerate(frames):
            image = f.image if transform is None else transform(f.image, i)
            t0 = time.perf_counter()
            r = index.rank(image)
            rank_ms.append((time.perf_counter() - t0) * 1e3)
            variances.append(ranking_vector(r.viewframes, r.variances, n))
            q = None
            if refs is not None:
                q = skyline_from_image(image, fov_y_deg=sc.camera.fov_y_deg, step_deg=sky.step_deg)
                m = match_skylines(q, refs, **match)
                skyline.append(ranking_vector([v.index for v in vfs], m.error, n))
            if sc.verify.enabled:
                verified.append(
                    _verified(sc, world, index, image, q, variances[-1], skyline[-1] if q is not None else None)
                )
    route = np.asarray(sc.route, dtype=np.float64)
    from models.route_views import view_route

    route_points = view_route(route, sc.views_per_leg)[2]
    truth = np.array([f.truth if f.truth is not None else (np.nan, np.nan, np.nan) for f in frames], float)
    true_point = np.array([nearest_viewframe(t[0], t[1], route) if np.isfinite(t[0]) else -1 for t in truth])
    return {
        "name": sc.name,
        "route": route,
        "variances": np.array(variances),
        "skyline": np.array(skyline) if refs is not None else None,
        "skyline_weight": float(sky.weight),
        "memory_weight": float(sc.memory.weight),
        "truth": truth,
        "times": np.array([np.nan if f.time is None else f.time for f in frames], float),
        "true_point": true_point,
        "rank_ms": np.array(rank_ms),
        "camera_hw": (int(sc.camera.height), int(sc.camera.width)),
        "route_points": route_points,
        "verified": np.array(verified) if sc.verify.enabled else None,
        "verify_weight": float(sc.verify.weight),
    }


def _verified(
    sc: Scenario,
    world: World,
    index: ViewframeIndex,
    image: np.ndarray,
    query_skyline: np.ndarray | None,
    variances: np.ndarray,
    skyline: np.ndarray | None,
) -> np.ndarray:
    """The verifier's correlations of one frame, (V,) NaN where not verified: as the scheduler
    asks (the fused ranking's first ``verify.candidates`` viewframes, when its second route point
    is within ``verify.margin`` nats of the first) and the verifier answers
    (:func:`models.verify.verify_candidates`, the viewframes' own views as its start views)."""
    from knowledge_sources.fusion import fuse_rankings
    from models.route_views import first_per_point, view_route
    from models.verify import verify_viewframes

    out = np.full(len(variances), np.nan)
    per, weights = {}, {}
    for src, errors, w in (("associative", variances, sc.memory.weight), ("skyline", skyline, sc.skyline.weight)):
        if errors is not None:
            e = np.asarray(errors, dtype=np.float64)
            ok = np.flatnonzero(np.isfinite(e))
            per[src], weights[src] = (ok.tolist(), e[ok].tolist()), w
    fused = fuse_rankings(per, weights=weights)
    points = first_per_point(fused, view_route(np.asarray(sc.route, float), sc.views_per_leg)[2])
    ver = sc.verify
    if len(points) < 2 or points[1][1] - points[0][1] >= ver.margin:
        return out
    chosen = [int(k) for k, _ in fused[: ver.candidates]]
    r = verify_viewframes(
        image,
        world.emulator,
        [world.viewframes[k] for k in chosen],
        sc,
        pattern=index.pattern,
        query_skyline=query_skyline,
    )
    out[chosen] = r.correlations
    return out


def views_per_leg(drive: dict[str, Any]) -> int:
    """Viewframes per leg of a :func:`ranked_drive` (1 when its viewframes are the route points)."""
    n = len(drive["route"])
    v = len(drive.get("route_points", range(n)))
    return max(1, (v - 1) // (n - 1)) if n > 1 else 1


def per_point(drive: dict[str, Any], scores: np.ndarray, *, nats: bool) -> np.ndarray:
    """Scores per viewframe ``(T, V)`` of a :func:`ranked_drive` as scores per route point ``(T, N)``
    by the tracker's rule (:func:`knowledge_sources.tracker.by_route_point`: ``nats``, a point's
    viewframes' total probability, else its best viewframe's); the same array when the
    viewframes are the route points."""
    from knowledge_sources.tracker import by_route_point

    rp = np.asarray(drive.get("route_points", np.arange(len(drive["route"]))))
    s = np.asarray(scores, dtype=np.float64)
    n = len(drive["route"])
    if s.shape[1] == n and (rp.size == n):
        return s
    out = np.full((s.shape[0], n), np.nan)
    for t in range(s.shape[0]):
        ok = np.flatnonzero(np.isfinite(s[t]))
        labels, values = by_route_point(ok.tolist(), s[t][ok].tolist(), rp, nats=nats)
        out[t] = ranking_vector(labels, values, n)
    return out


def observed(drive: dict[str, Any], observe: str, *, point: str = "total", verify: bool = True) -> np.ndarray:
    """What the tracker observes of each frame of a :func:`ranked_drive`, ``(T, N)`` indexed by
    route point (lower is better; viewframes between the route points reduced by :func:`per_point`): ``"associative"``, the memory's error variances; ``"fused"``,
    every ranking source of the drive fused by the scheduler's rule as the tracker takes it
    (:func:`knowledge_sources.fusion.fused_log_posterior` at the scenario's ``memory.weight``
    and ``skyline.weight``, the drive's ``memory_weight`` and ``skyline_weight``): the negative
    log posterior in nats, which orders the viewframes as the fused ranking does (for a drive
    without the skyline: the memory's weighted robust z-scores, an affine map of its errors).
    With viewframes between the route points, ``point`` says how a route point's fused value
    comes from its viewframes': ``"total"`` their total probability (the tracker's rule with
    ``tracking.evidence: points``), ``"best"`` its best viewframe's (the scene analysis's rule,
    knowledge_sources.scheduler); ``"view"``: per viewframe ``(T, V)``, not reduced (the
    tracker's observation with ``evidence: views``, the default). A drive ranked with the
    verification on (its ``verified`` correlations) is observed re-scored by it, as the tracker
    observes a verified frame (:func:`models.verify.verified_ranking` at the drive's
    ``verify_weight``); ``verify`` False: without it."""
    from knowledge_sources.fusion import fused_log_posterior
    from models.scenario import MemorySpec, SkylineSpec, VerifySpec
    from models.verify import verified_ranking

    if observe not in OBSERVE:
        raise ValueError(f"observe must be one of {OBSERVE}, not {observe!r}")
    if point not in ("total", "best", "view"):
        raise ValueError(f"point must be 'total', 'best' or 'view', not {point!r}")
    v = np.asarray(drive["variances"], dtype=np.float64)
    sky = drive.get("skyline")
    if observe == "associative":
        return v if point == "view" else per_point(drive, v, nats=False)
    n = v.shape[1]
    labels = np.arange(n)
    weights = {
        "associative": float(drive.get("memory_weight", MemorySpec().weight)),
        "skyline": float(drive.get("skyline_weight", SkylineSpec().weight)),
    }
    rows = [("associative", v)] + ([] if sky is None else [("skyline", np.asarray(sky, dtype=np.float64))])
    checked = drive.get("verified") if verify else None
    w_ver = float(drive.get("verify_weight", VerifySpec().weight))
    out = np.full(v.shape, np.nan)
    for t in range(v.shape[0]):
        per = {}
        for src, errors in rows:
            ok = np.isfinite(errors[t])
            per[src] = (labels[ok].tolist(), errors[t][ok].tolist())
        lab, log_p = fused_log_posterior(per, weights={s: weights[s] for s in per})
        scores = (-log_p).tolist()
        if checked is not None and np.isfinite(checked[t]).any():  # re-scored as the tracker does
            ver = np.flatnonzero(np.isfinite(checked[t]))
            got = verified_ranking(
                list(zip(lab.tolist(), scores)), ver.tolist(), checked[t][ver].tolist(), weight=w_ver
            )
            lab, scores = np.array([k for k, _ in got]), [e for _, e in got]
        out[t] = ranking_vector(lab.tolist(), scores, n)
    return out if point == "view" else per_point(drive, out, nats=point == "total")
