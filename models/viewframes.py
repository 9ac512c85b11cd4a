"""A-priori viewframes V = {F2D^Vi}: the views the camera should see along the mission route.

The camera at route point i stands at (x_i, y_i, F(x_i, y_i) + eye_height), heading towards
route point i+1 (counterclockwise from +x); the last point keeps the previous heading.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from models.camera import CameraEmulator, Pose
from models.environment import build_environment
from models.scenario import Scenario
from models.symbolic import SymbolicDescription, describe
from models.terrain import Terrain

__all__ = ["Viewframe", "route_headings", "route_poses", "build_viewframes"]

log = logging.getLogger(__name__)


@dataclass
class Viewframe:
    """A stored a-priori view: image uint8 (H, W, 3) RGB, depth float32 (H, W) metres,
    mask int32 (H, W) landmark indices (-1 none), and its symbolic description."""

    index: int
    pose: Pose
    image: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    description: SymbolicDescription


def route_headings(route) -> list[float]:
    """Heading in degrees (ccw from +x) at each route point: towards the next one."""
    pts = np.asarray(route, dtype=np.float64)
    d = np.diff(pts, axis=0)
    heads = [math.degrees(math.atan2(dy, dx)) for dx, dy in d]
    return heads + heads[-1:]


def route_poses(scenario: Scenario, terrain: Terrain) -> list[Pose]:
    """Camera pose at each route point (see the module docstring)."""
    cam = scenario.camera
    return [
        Pose(float(x), float(y), float(terrain.height_at(x, y)) + cam.eye_height, h, cam.pitch_deg)
        for (x, y), h in zip(scenario.route, route_headings(scenario.route))
    ]


def build_viewframes(scenario: Scenario, *, emulator: CameraEmulator | None = None) -> list[Viewframe]:
    """Render and describe the viewframe at every route point.

    Uses ``emulator`` (and its environment) when given; otherwise builds the environment and a
    camera emulator for the scenario and closes it afterwards.
    """
    own = emulator is None
    if emulator is None:
        emulator = CameraEmulator(build_environment(scenario), scenario.camera)
    try:
        env = emulator.environment
        frames = []
        for i, pose in enumerate(route_poses(scenario, env.terrain)):
            view = emulator.render(pose)
            desc = describe(view.mask, view.depth, env.landmarks, pose=pose, emulator=emulator)
            frames.append(Viewframe(i, pose, view.image, view.depth, view.mask, desc))
        log.info("rendered %d viewframes of %s", len(frames), scenario.name)
        return frames
    finally:
        if own:
            emulator.close()
