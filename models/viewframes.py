"""A-priori viewframes V = {F2D^Vi}: the views the camera should see along the mission route.

The camera at route point i stands at (x_i, y_i, F(x_i, y_i) + eye_height), heading towards
route point i+1 (counterclockwise from +x); the last point keeps the previous heading. A
scenario's viewframes are :attr:`models.world.World.viewframes`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from models.camera_emulator import CameraEmulator, Pose
from models.scenario import Scenario
from models.symbolic import SymbolicDescription, describe
from models.terrain import Terrain

__all__ = ["Viewframe", "without_landmark", "route_headings", "route_poses", "render_viewframes"]


@dataclass
class Viewframe:
    """A stored a-priori view: ``index`` is its viewframe index (the route point's number),
    image uint8 (H, W, 3) RGB, depth float32 (H, W) metres, mask int32 (H, W) landmark indices
    (-1 none), and its symbolic description.

    ``background`` uint8 (H, W, 3) is the same view rendered without any landmark (the terrain
    and sky behind them), or ``None`` when no landmark is in view: a landmark detector compares
    the camera image with the view with the landmark and without it (:meth:`without_landmark`).
    """

    index: int
    pose: Pose
    image: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    description: SymbolicDescription
    background: np.ndarray | None = None

    def without_landmark(self, landmark_index: int) -> np.ndarray:
        """The viewframe image with landmark ``landmark_index``'s pixels replaced by what lies
        behind them (see :func:`without_landmark`)."""
        return without_landmark(self.image, self.mask, landmark_index, background=self.background)


def without_landmark(
    image: np.ndarray, mask: np.ndarray, landmark_index: int, *, background: np.ndarray | None
) -> np.ndarray:
    """The view ``image`` (H, W, 3) as it would look if landmark ``landmark_index`` were not there:
    its pixels in ``mask`` (H, W; landmark indices, -1 none) replaced by ``background``'s (the
    view rendered without landmarks). Other landmarks stay. With ``background=None`` the image
    is returned unchanged when the landmark has no pixel, else ``ValueError``.
    """
    sil = np.asarray(mask) == int(landmark_index)
    if not sil.any():
        return image
    if background is None:
        raise ValueError(f"landmark {landmark_index} is in view but no background image was given")
    if background.shape != image.shape:
        raise ValueError(f"background shape {background.shape} must equal the image's {image.shape}")
    out = image.copy()
    out[sil] = background[sil]
    return out


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


def render_viewframes(
    emulator: CameraEmulator, poses: Sequence[Pose], *, progress: Callable[[int, int], None] | None = None
) -> list[Viewframe]:
    """Render and describe the viewframe at every pose (the route poses), numbered in order; where
    a landmark is in view, also the same view without landmarks (:attr:`Viewframe.background`).
    ``progress(done, total)`` is called after each."""
    env = emulator.environment
    frames = []
    for i, pose in enumerate(poses):
        view = emulator.render(pose)
        desc = describe(view.mask, view.depth, env.landmarks, pose=pose, emulator=emulator)
        background = emulator.render_background(pose) if (view.mask >= 0).any() else None
        frames.append(Viewframe(i, pose, view.image, view.depth, view.mask, desc, background))
        if progress is not None:
            progress(i + 1, len(poses))
    return frames
