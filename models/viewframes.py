"""A-priori viewframes V = {F2D^Vi}: the views the camera should see along the mission route.

The camera at route point i stands at (x_i, y_i, F(x_i, y_i) + eye_height), heading towards
route point i+1 (counterclockwise from +x); the last point keeps the previous heading. A
scenario's viewframes are :attr:`models.world.World.viewframes`.
"""

from __future__ import annotations

import math
import multiprocessing
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from models.camera_emulator import CameraEmulator, Pose
from models.errors import RenderError
from models.scenario import Scenario, SkylineSpec
from models.skyline import skyline_from_depth
from models.symbolic import SymbolicDescription, describe
from models.terrain import Terrain

if TYPE_CHECKING:
    from models.environment import EnvironmentModel
    from models.scenario import CameraSpec

__all__ = [
    "Viewframe",
    "without_landmark",
    "route_headings",
    "route_poses",
    "render_viewframes",
    "render_viewframes_parallel",
]

_SKYLINE = SkylineSpec()


@dataclass
class Viewframe:
    """A stored a-priori view: ``index`` is its viewframe index (the route point's number),
    image uint8 (H, W, 3) RGB, depth float32 (H, W) metres, mask int32 (H, W) landmark indices
    (-1 none), its symbolic description, and its skyline float32 (n,): the horizon's elevation
    per azimuth bin from the depth buffer, NaN where the column has no sky/terrain boundary
    (:mod:`models.skyline`).

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
    skyline: np.ndarray
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
    emulator: CameraEmulator,
    poses: Sequence[Pose],
    *,
    skyline_step_deg: float = _SKYLINE.step_deg,
    progress: Callable[[int, int], None] | None = None,
) -> list[Viewframe]:
    """Render and describe the viewframe at every pose (the route poses), numbered in order; each
    carries its skyline at ``skyline_step_deg`` degrees per bin (the scenario's ``skyline.step_deg``)
    and, where a landmark is in view, also the same view without landmarks
    (:attr:`Viewframe.background`). ``progress(done, total)`` is called after each."""
    return _render(emulator, poses, 0, skyline_step_deg=skyline_step_deg, progress=progress)


def _render(
    emulator: CameraEmulator,
    poses: Sequence[Pose],
    first: int,
    *,
    skyline_step_deg: float,
    progress: Callable[[int, int], None] | None = None,
) -> list[Viewframe]:
    """The viewframes of ``poses``, numbered from ``first``."""
    env = emulator.environment
    fov = float(emulator.camera.fov_y_deg)
    frames = []
    for i, pose in enumerate(poses):
        view = emulator.render(pose)
        desc = describe(view.mask, view.depth, env.landmarks, pose=pose, emulator=emulator)
        sky = skyline_from_depth(view.depth, fov_y_deg=fov, step_deg=skyline_step_deg)
        background = emulator.render_background(pose) if (view.mask >= 0).any() else None
        frames.append(Viewframe(first + i, pose, view.image, view.depth, view.mask, desc, sky, background))
        if progress is not None:
            progress(i + 1, len(poses))
    return frames


#: the worker process's camera emulator (made by :func:`_worker_start`)
_WORKER: dict[str, CameraEmulator] = {}


def _worker_start(environment: EnvironmentModel, camera: CameraSpec) -> None:
    _WORKER["emulator"] = CameraEmulator(environment, camera)


def _worker_render(poses: Sequence[Pose], first: int, skyline_step_deg: float) -> list[Viewframe]:
    return _render(_WORKER["emulator"], poses, first, skyline_step_deg=skyline_step_deg)


def render_viewframes_parallel(
    environment: EnvironmentModel,
    camera: CameraSpec,
    poses: Sequence[Pose],
    *,
    workers: int,
    skyline_step_deg: float = _SKYLINE.step_deg,
    chunk: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[Viewframe]:
    """:func:`render_viewframes` of ``environment`` seen by ``camera`` at ``poses``, rendered by
    ``workers`` processes (see the module docstring); equal to the serial result.

    The route is cut into contiguous chunks of ``chunk`` poses (default: enough for eight chunks
    per worker, so that a slow worker does not hold the others up and ``progress(done, total)``
    is called as chunks come back, in route order). A worker that fails or dies raises
    :class:`~models.errors.RenderError`.
    """
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    n = len(poses)
    if n == 0:
        return []
    size = max(1, chunk if chunk is not None else math.ceil(n / (8 * workers)))
    starts = list(range(0, n, size))
    frames: list[Viewframe] = []
    context = multiprocessing.get_context("spawn")  # never fork a process that may hold a GL context
    try:
        with ProcessPoolExecutor(
            max_workers=min(workers, len(starts)),
            mp_context=context,
            initializer=_worker_start,
            initargs=(environment, camera),
        ) as pool:
            chunks = pool.map(
                _worker_render,
                [poses[s : s + size] for s in starts],
                starts,
                [float(skyline_step_deg)] * len(starts),
            )
            for part in chunks:
                frames.extend(part)
                if progress is not None:
                    progress(len(frames), n)
    except BrokenProcessPool as exc:
        raise RenderError(f"a viewframe rendering worker process died: {exc}") from exc
    return frames
