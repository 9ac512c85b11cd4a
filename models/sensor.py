"""Sensor input: camera frames taken during the mission, from files or simulated.

A real camera's image differs from the synthetic viewframe of the nearest route point in pose
(the vehicle is between route points and off the exact heading) and in photometry (lighting,
surface texture, haze, gain, gamma, sensor noise, optical blur). :func:`simulate_frames`
produces such frames with the same camera emulator that renders the viewframes, then degrades
them; everything is drawn from one seeded generator, so a scenario always yields the same frames.
A scenario's frames (from files or simulated) are :attr:`models.world.World.sensor_frames`.

Images are ``(H, W, 3)`` uint8 RGB arrays indexed ``(row, col)``; poses are in world
``(x, y, z)`` metres with heading counterclockwise from +x.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from models.errors import InputError, ScenarioError
from models.scenario import MIN_IMAGE_PX, DriveSpec, Scenario, SimulateSpec

__all__ = [
    "SensorFrame",
    "DrivePose",
    "drive_poses",
    "load_frame_image",
    "frames_from_files",
    "degrade",
    "simulate_frames",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SensorFrame:
    """One camera frame of the mission.

    Attributes
    ----------
    index : int
        Frame number, in mission order.
    image : ndarray of shape (H, W, 3), uint8
        RGB image at the scenario camera's size.
    truth : tuple (x, y, heading_deg) or None
        The true pose when known (world metres, degrees); never used to localize.
    source : str
        The image file, or ``"simulated"``.
    time : float or None
        Seconds (any origin) when the frame was taken, when known; increasing with ``index``.
    """

    index: int
    image: np.ndarray
    truth: tuple[float, float, float] | None
    source: str
    time: float | None = None


@dataclass(frozen=True)
class DrivePose:
    """One frame's pose on a simulated drive: ``time`` (s), ``x``, ``y`` (m), ``heading_deg``,
    ``arc_m`` (arc length of its foot point on the route), ``kidnapped`` (the frame of a jump)."""

    time: float
    x: float
    y: float
    heading_deg: float
    arc_m: float
    kidnapped: bool = False


def drive_poses(
    route: Sequence[Sequence[float]], spec: DriveSpec, *, rng: np.random.Generator | int | None = None
) -> list[DrivePose]:
    """Poses of a drive along ``route`` (N, 2), in time order (see :class:`~models.scenario.DriveSpec`).

    The vehicle starts at arc fraction ``spec.start`` and moves forward by ``speed * interval_s``
    per frame, the speed a bounded random walk in ``spec.speed_mps``, with stops; its position
    is the route polyline point at its arc length, moved perpendicular by the lateral offset,
    and its heading the route's direction plus the heading error (both AR(1) processes, so they
    vary slowly). Between route points, as a real drive is.
    """
    rng = np.random.default_rng(rng)
    pts = np.asarray(route, dtype=np.float64)
    legs = np.hypot(*np.diff(pts, axis=0).T)
    arc = np.concatenate([[0.0], np.cumsum(legs)])
    total = float(arc[-1])
    lo, hi = spec.speed_mps
    speed = rng.uniform(lo, hi)
    s = spec.start * total
    lateral = rng.normal(0.0, spec.lateral_m)
    head_err = rng.normal(0.0, spec.heading_deg)
    stop_left = 0
    out: list[DrivePose] = []
    t = 0.0
    rho = 0.8  # AR(1) persistence of the lateral and heading errors
    while True:
        kidnapped = spec.kidnap_at is not None and len(out) == spec.kidnap_at
        if kidnapped:
            if spec.kidnap_to is not None:
                s = spec.kidnap_to * total
            else:
                away = rng.uniform(0.25, 0.75) * total
                s = (s + away) % total
        seg = int(np.clip(np.searchsorted(arc, s, side="right") - 1, 0, len(pts) - 2))
        d = (pts[seg + 1] - pts[seg]) / legs[seg]
        foot = pts[seg] + (s - arc[seg]) * d
        normal = np.array([-d[1], d[0]])
        x, y = foot + lateral * normal
        heading = math.degrees(math.atan2(d[1], d[0])) + head_err
        out.append(DrivePose(t, float(x), float(y), float(heading), float(s), kidnapped))
        if spec.frames is not None and len(out) >= spec.frames:
            break
        # the next frame
        t += spec.interval_s
        if stop_left > 0:
            stop_left -= 1
        elif rng.random() < spec.p_stop:
            stop_left = int(rng.integers(1, spec.stop_frames + 1)) - 1
        else:
            speed = float(np.clip(speed + spec.speed_change * (hi - lo) * rng.normal(), lo, hi))
            s += speed * spec.interval_s
        if s > total:
            if spec.frames is None:
                break
            s = total
        lateral = rho * lateral + math.sqrt(1 - rho**2) * rng.normal(0.0, spec.lateral_m)
        head_err = rho * head_err + math.sqrt(1 - rho**2) * rng.normal(0.0, spec.heading_deg)
    return out


def load_frame_image(path: str | Path, *, width: int, height: int) -> np.ndarray:
    """Read a PNG/JPEG camera image, gray or colour, any size, as ``(height, width, 3)`` uint8 RGB.

    Raises :class:`~models.errors.InputError` naming the file when it is missing or unreadable.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "camera image not found")
    data = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if data is None or data.size == 0:
        raise InputError(path, "not a readable image (PNG or JPEG expected)")
    if min(data.shape[:2]) < MIN_IMAGE_PX:
        raise InputError(
            path, f"image is {data.shape[1]}x{data.shape[0]} pixels; at least {MIN_IMAGE_PX}x{MIN_IMAGE_PX} needed"
        )
    if data.dtype != np.uint8:
        data = cv2.normalize(data, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)  # type: ignore[call-overload]
    if data.ndim == 2:
        rgb = cv2.cvtColor(data, cv2.COLOR_GRAY2RGB)
    elif data.shape[2] == 4:
        rgb = cv2.cvtColor(data, cv2.COLOR_BGRA2RGB)
    else:
        rgb = cv2.cvtColor(data, cv2.COLOR_BGR2RGB)
    if rgb.shape[:2] != (height, width):
        shrinking = rgb.shape[0] > height
        rgb = cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
    return np.ascontiguousarray(rgb)


def frames_from_files(scenario: Scenario) -> list[SensorFrame]:
    """The scenario's ``sensor.frames``, read and resized to the camera size.

    Raises :class:`~models.errors.ScenarioError` naming the scenario, the field and the file."""
    cam = scenario.camera
    frames = []
    for i, spec in enumerate((scenario.sensor.frames if scenario.sensor else None) or []):
        try:
            image = load_frame_image(spec.image, width=cam.width, height=cam.height)
        except InputError as err:  # name the scenario and the field too (as the pre-run check does)
            raise ScenarioError(scenario.path, f"sensor.frames[{i}].image", str(err)) from None
        truth = None if spec.truth is None else (spec.truth.x, spec.truth.y, spec.truth.heading_deg)
        frames.append(SensorFrame(i, image, truth, str(spec.image), spec.time))
    return frames


def degrade(
    image: np.ndarray,
    *,
    depth: np.ndarray | None = None,
    spec: SimulateSpec,
    rng: np.random.Generator | int | None = None,
) -> np.ndarray:
    """Apply a real camera's photometric differences to a rendered image.

    Parameters
    ----------
    image : ndarray of shape (H, W, 3), uint8
    depth : ndarray of shape (H, W), optional
        Metres along the view axis, 0 for sky; haze grows with it. Without it, haze is uniform.
    spec : SimulateSpec
        Strengths: ``texture`` (fine multiplicative albedo noise on surfaces, not on the sky), ``haze`` (blend to a
        bright gray with distance), ``gain`` and ``gamma`` (drawn in ``1 ± strength`` and
        ``exp(± strength)``), ``blur`` (Gaussian sigma, pixels), ``noise`` (gray levels sigma).
    rng : Generator, int or None

    Returns
    -------
    ndarray of shape (H, W, 3), uint8
    """
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must have shape (H, W, 3), not {image.shape}")
    rng = np.random.default_rng(rng)
    h, w = image.shape[:2]
    img: np.ndarray = image.astype(np.float32) / 255.0
    if spec.texture > 0:
        # surface albedo variation (grass, soil, walls): fine-grained, on surfaces only, not the sky
        field: np.ndarray = rng.standard_normal((max(2, h // 4), max(2, w // 4))).astype(np.float32)
        field = cv2.resize(field, (w, h), interpolation=cv2.INTER_CUBIC)
        field = cv2.GaussianBlur(field, (0, 0), 1.0)
        field = field / max(float(field.std()), 1e-6)
        surface = np.ones((h, w), np.float32) if depth is None else (np.asarray(depth) > 0).astype(np.float32)
        img *= np.clip(1.0 + spec.texture * 0.25 * field * surface, 0.5, 1.5)[..., None]
    if spec.haze > 0:
        amount: np.ndarray
        if depth is None:
            amount = np.full((h, w), spec.haze, np.float32)
        else:
            d = np.asarray(depth, np.float32)
            amount = spec.haze * np.where(d > 0, 1.0 - np.exp(-d / 800.0), 1.0)
        veil = np.float32(0.8 + 0.1 * rng.uniform(-1, 1))
        img = img * (1.0 - amount[..., None]) + veil * amount[..., None]
    gain = 1.0 + spec.gain * rng.uniform(-1, 1)
    gamma = math.exp(spec.gamma * rng.uniform(-1, 1))
    img = np.clip(img * gain, 0.0, 1.0) ** gamma
    if spec.blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), spec.blur)
    out = img * 255.0
    if spec.noise > 0:
        out = out + rng.normal(0.0, spec.noise, out.shape).astype(np.float32)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def simulate_frames(
    scenario: Scenario,
    emulator,
    poses: Sequence,
    *,
    spec: SimulateSpec | None = None,
    rng: np.random.Generator | int | None = None,
) -> list[SensorFrame]:
    """Simulated camera frames along the route.

    For every ``spec.stride``-th route point ``i`` (pose ``poses[i]``), ``spec.per_point`` frames are taken at a
    position advanced by a uniform fraction in ``[0, spec.advance)`` of the leg towards point
    ``i + 1`` (the last point advances along its heading by the previous leg's length), displaced
    by Gaussian jitter of ``spec.jitter_m`` metres per axis, with the heading off by Gaussian
    ``spec.jitter_deg`` degrees; the emulator renders it under varied lighting, then
    :func:`degrade` applies the photometric differences. ``truth`` holds the pose.

    With ``spec.drive``, the frames are a drive instead (:func:`drive_poses`), in time order
    with their ``time``.
    """
    spec = spec or (scenario.sensor.simulate if scenario.sensor else None)
    if spec is None:
        raise ValueError("spec must be given when the scenario has no sensor.simulate block")
    if rng is None:
        rng = spec.seed if spec.seed is not None else scenario.seed
    rng = np.random.default_rng(rng)
    if spec.drive is not None:
        route = [(p.x, p.y) for p in poses]
        drive = [
            _render_frame(emulator, k, dp.x, dp.y, dp.heading_deg, spec, rng, dp.time)
            for k, dp in enumerate(drive_poses(route, spec.drive, rng=rng))
        ]
        log.info("simulated a drive of %d camera frames for scenario %s", len(drive), scenario.name)
        return drive
    frames: list[SensorFrame] = []
    n = len(poses)
    for i, pose in enumerate(poses):
        if i % spec.stride:
            continue
        if i + 1 < n:
            leg = np.array([poses[i + 1].x - pose.x, poses[i + 1].y - pose.y])
        else:
            back = math.hypot(pose.x - poses[i - 1].x, pose.y - poses[i - 1].y) if n > 1 else 0.0
            th = math.radians(pose.heading_deg)
            leg = back * np.array([math.cos(th), math.sin(th)])
        for _ in range(spec.per_point):
            u = rng.uniform(0.0, spec.advance) if spec.advance > 0 else 0.0
            x, y = np.array([pose.x, pose.y]) + u * leg + rng.normal(0.0, spec.jitter_m, 2)
            heading = pose.heading_deg + rng.normal(0.0, spec.jitter_deg)
            frames.append(_render_frame(emulator, len(frames), float(x), float(y), float(heading), spec, rng))
    log.info("simulated %d camera frames for scenario %s", len(frames), scenario.name)
    return frames


def _render_frame(
    emulator,
    index: int,
    x: float,
    y: float,
    heading: float,
    spec: SimulateSpec,
    rng: np.random.Generator,
    time: float | None = None,
) -> SensorFrame:
    """Render the camera at ``(x, y, heading)`` under drawn lighting and degrade it."""
    true_pose = emulator.pose_at(x, y, heading)
    intensity = 1.0 + spec.lighting * rng.uniform(-1, 1)
    az = rng.uniform(0, 2 * math.pi)
    el = math.radians(35.0 + 20.0 * spec.lighting * rng.uniform(-1, 1))
    direction = (math.cos(az) * math.cos(el), math.sin(az) * math.cos(el), -math.sin(el))
    view = emulator.render(true_pose, light_intensity=intensity, light_direction=direction)
    image = degrade(view.image, depth=view.depth, spec=spec, rng=rng)
    return SensorFrame(index, image, (x, y, heading), "simulated", time)
