"""A-priori viewframes V = {F2D^Vi}: the views the camera should see along the mission route.

The camera at route point i stands at (x_i, y_i, F(x_i, y_i) + eye_height), heading towards
route point i+1 (counterclockwise from +x); the last point keeps the previous heading. A
scenario's viewframes are :attr:`models.world.World.viewframes`.
"""

from __future__ import annotations

import collections
import math
import os
import pickle
import queue
import subprocess
import sys
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from subprocess import PIPE
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
#: the most poses of one share a rendering worker renders and sends back at once
MAX_SHARE = 64


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
    sink: Callable[[int, Viewframe], None] | None = None,
) -> list[Viewframe]:
    """Render and describe the viewframe at every pose (the route poses), numbered in order; each
    carries its skyline at ``skyline_step_deg`` degrees per bin (the scenario's ``skyline.step_deg``)
    and, where a landmark is in view, also the same view without landmarks
    (:attr:`Viewframe.background`). ``progress(done, total)`` is called after each.

    ``sink(position, viewframe)``, when given, takes each viewframe as it is rendered (``position``
    its place in ``poses``) and none is kept: the result is then empty."""
    return _render(emulator, poses, 0, skyline_step_deg=skyline_step_deg, progress=progress, sink=sink)


def _render(
    emulator: CameraEmulator,
    poses: Sequence[Pose],
    first: int,
    *,
    skyline_step_deg: float,
    progress: Callable[[int, int], None] | None = None,
    sink: Callable[[int, Viewframe], None] | None = None,
) -> list[Viewframe]:
    """The viewframes of ``poses``, numbered from ``first`` (each given to ``sink`` instead of
    kept, when given)."""
    env = emulator.environment
    fov = float(emulator.camera.fov_y_deg)
    frames = []
    for i, pose in enumerate(poses):
        view = emulator.render(pose)
        desc = describe(view.mask, view.depth, env.landmarks, pose=pose, emulator=emulator)
        sky = skyline_from_depth(view.depth, fov_y_deg=fov, step_deg=skyline_step_deg)
        background = emulator.render_background(pose) if (view.mask >= 0).any() else None
        vf = Viewframe(first + i, pose, view.image, view.depth, view.mask, desc, sky, background)
        if sink is not None:
            sink(i, vf)
        else:
            frames.append(vf)
        if progress is not None:
            progress(i + 1, len(poses))
    return frames


def render_viewframes_parallel(
    environment: EnvironmentModel,
    camera: CameraSpec,
    poses: Sequence[Pose],
    *,
    workers: int,
    skyline_step_deg: float = _SKYLINE.step_deg,
    chunk: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    sink: Callable[[int, Viewframe], None] | None = None,
) -> list[Viewframe]:
    """:func:`render_viewframes` of ``environment`` seen by ``camera`` at ``poses``, rendered by
    ``workers`` processes (see the module docstring); equal to the serial result.

    The route is cut into contiguous shares of ``chunk`` poses (default: enough for eight shares
    per worker, so that a slow worker does not hold the others up, and at most :data:`MAX_SHARE`,
    so that the shares in flight are a bounded amount of memory); each worker
    (:mod:`models.render_worker`, its own process and EGL context) takes the next share when it
    is done with one. ``progress(done, total)`` is called in this thread as shares come back. A
    worker that fails or dies raises :class:`~models.errors.RenderError` with its message.
    ``sink(position, viewframe)``, when given, takes each viewframe as its share comes back (in
    the order shares finish) and none is kept: the result is then empty.
    """
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    n = len(poses)
    if n == 0:
        return []
    size = max(1, chunk if chunk is not None else min(MAX_SHARE, math.ceil(n / (8 * workers))))
    shares = collections.deque((s, list(poses[s : s + size])) for s in range(0, n, size))
    setup = pickle.dumps((environment, camera, float(skyline_step_deg)), protocol=pickle.HIGHEST_PROTOCOL)
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join([root, *([env["PYTHONPATH"]] if env.get("PYTHONPATH") else [])])
    lock = threading.Lock()
    done: queue.Queue[tuple[int, list[Viewframe]] | None] = queue.Queue()
    errors: list[str] = []

    def drive(proc: subprocess.Popen[bytes]) -> None:
        assert proc.stdin is not None and proc.stdout is not None
        try:
            proc.stdin.write(setup)
            while True:
                with lock:
                    if errors or not shares:
                        break
                    first, share = shares.popleft()
                pickle.dump((first, share), proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
                proc.stdin.flush()
                status, payload = pickle.load(proc.stdout)
                if status != "ok":
                    with lock:
                        errors.append(str(payload))
                    break
                done.put((first, payload))
        except (EOFError, OSError, pickle.UnpicklingError) as exc:
            with lock:
                errors.append(f"a viewframe rendering worker process exited ({exc!r}; its messages are above)")
        finally:
            try:
                pickle.dump(None, proc.stdin)
                proc.stdin.close()
            except OSError:
                pass
            done.put(None)

    count = min(workers, len(shares))
    procs = [
        subprocess.Popen([sys.executable, "-m", "models.render_worker"], stdin=PIPE, stdout=PIPE, env=env)
        for _ in range(count)
    ]
    threads = [threading.Thread(target=drive, args=(p,), daemon=True) for p in procs]
    parts: dict[int, list[Viewframe]] = {}
    try:
        for t in threads:
            t.start()
        finished, rendered = 0, 0
        while finished < count:
            item = done.get()
            if item is None:
                finished += 1
                continue
            if sink is not None:
                for i, vf in enumerate(item[1]):
                    sink(item[0] + i, vf)
                parts[item[0]] = []
            else:
                parts[item[0]] = item[1]
            rendered += len(item[1])
            item = None  # the share is not held while waiting for the next
            if progress is not None:
                progress(rendered, n)
    finally:
        for t in threads:
            t.join(timeout=60)
        for p in procs:
            try:
                p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
            if p.stdout is not None:
                p.stdout.close()
    if errors:
        raise RenderError(f"rendering viewframes in worker processes failed: {errors[0]}")
    if sink is not None:
        if rendered != n:
            raise RenderError(f"rendering viewframes in worker processes: {rendered} of {n} came back")
        return []
    frames = [vf for first in sorted(parts) for vf in parts[first]]
    if len(frames) != n:
        raise RenderError(f"rendering viewframes in worker processes: {len(frames)} of {n} came back")
    return frames
