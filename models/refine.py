"""Pose refinement: the camera's position between route points, its heading and pitch.

A decision names a route point; the vehicle rarely stands on it. :func:`refine_pose` searches
the ground around the chosen point by rendering views with the camera emulator and comparing
each with the camera image, coarse to fine:

1. **Heading and pitch** at the start point: the camera skyline is matched with the rendered
   view's skyline over heading and pitch shifts (:func:`models.skyline.match_skylines`), the
   best shift refined to a fraction of a bin by a parabola through its neighbours.
2. **Position**: a ``grid`` x ``grid`` pattern of points spanning ``+-along_m`` along the start
   heading and ``+-across_m`` across it; at each, a view is rendered at the current heading and
   pitch estimate and scored (below); the best point becomes the centre of the next level, whose
   pattern is half as wide (``levels`` levels). The start point itself is always scored, so the
   result is never worse than the start by the score.
3. **Score** of a view: ``skyline error (degrees, truncated L1 after the best heading/pitch
   shift) + edge_weight * (1 - NCC)``, NCC the best normalised cross-correlation of the two
   edge images (gradient magnitude, blurred by ``blur_px``) over the column shift the skyline
   and pitch offset the skyline found, and their neighbours (+-1 column, +-2 rows). The skyline fixes heading and far geometry, the edges the near
   ground and landmarks; each term is scale-free (degrees, a correlation).
4. **Uncertainty**: the spread of the last level's points weighted by ``exp(-(s - s_min) /
   tau)``, ``tau`` the median absolute deviation of the scores (floored by the last level's
   step), as standard deviations along and across (metres), and the heading's from the
   parabola's curvature (floored by a tenth of a bin).

Positions are world (x, y) metres; headings counterclockwise from +x, pitch up, degrees.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import NDArray

from models.scenario import RefineSpec
from models.skyline import (
    DEFAULT_MAX_HEADING_DEG,
    DEFAULT_MAX_PITCH_DEG,
    DEFAULT_STEP_DEG,
    DEFAULT_TRUNCATE_DEG,
    TRUST_DEG,
    SkylineMatch,
    match_skylines,
    skyline_from_depth,
    skyline_from_image,
)

if TYPE_CHECKING:
    from models.camera_emulator import CameraEmulator, Pose, View

__all__ = [
    "RefinedPose",
    "refine_pose",
    "edge_image",
]

log = logging.getLogger(__name__)

_DEFAULTS = RefineSpec()  # the defaults are the scenario schema's (models.scenario)
DEFAULT_ALONG_M = _DEFAULTS.along_m
DEFAULT_ACROSS_M = _DEFAULTS.across_m
DEFAULT_LEVELS = _DEFAULTS.levels
DEFAULT_GRID = _DEFAULTS.grid
DEFAULT_EDGE_WEIGHT = _DEFAULTS.edge_weight
DEFAULT_POSITION = _DEFAULTS.position
DEFAULT_RECHECK = _DEFAULTS.recheck
DEFAULT_MAX_ROLL_DEG = _DEFAULTS.max_roll_deg

_BLUR_PX = 1.5


@dataclass(frozen=True)
class RefinedPose:
    """A refined camera pose and its uncertainty (standard deviations).

    ``x, y`` world metres; ``heading_deg`` ccw from +x; ``pitch_deg`` up; ``sigma_along_m`` and
    ``sigma_across_m`` along and across the heading; ``sigma_heading_deg``; ``score`` the best
    view's score (lower is better, module docstring); ``start_score`` the start point's;
    ``renders`` views rendered.
    """

    x: float
    y: float
    heading_deg: float
    pitch_deg: float
    sigma_along_m: float
    sigma_across_m: float
    sigma_heading_deg: float
    score: float
    start_score: float
    renders: int

    def to_dict(self) -> dict[str, float | int]:
        """Plain data for msgpack/JSON."""
        return {k: (int(v) if k == "renders" else float(v)) for k, v in self.__dict__.items()}


def edge_image(image: NDArray, *, blur_px: float = _BLUR_PX) -> NDArray[np.float32]:
    """Gradient magnitude of the gray image (H, W[, 3]), blurred, zero mean and unit norm (H, W)."""
    img = np.asarray(image, dtype=np.float32)
    gray = img @ np.array([0.299, 0.587, 0.114], np.float32) if img.ndim == 3 else img
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    e = np.asarray(cv2.GaussianBlur(cv2.magnitude(gx, gy), (0, 0), blur_px), dtype=np.float32)
    e -= e.mean()
    n = float(np.linalg.norm(e))
    return (e / n if n > 0 else e).astype(np.float32)


def _ncc_shifted(a: NDArray[np.float32], b: NDArray[np.float32], rows: range, cols: range) -> float:
    """Best normalised correlation of ``a`` with ``b`` shifted by (row, col) offsets in
    ``rows`` x ``cols`` (a's pixel (r, c) against b's (r - dr, c - dc)), over the overlap."""
    h, w = a.shape
    best = -1.0
    for dr in rows:
        for dc in cols:
            if abs(dc) >= w // 2 or abs(dr) >= h // 2:
                continue
            aa = a[max(0, dr) : h + min(0, dr), max(0, dc) : w + min(0, dc)]
            bb = b[max(0, -dr) : h - max(0, dr), max(0, -dc) : w - max(0, dc)]
            aa = aa - aa.mean()
            bb = bb - bb.mean()
            den = float(np.linalg.norm(aa) * np.linalg.norm(bb))
            if den > 0:
                best = max(best, float((aa * bb).sum() / den))
    return best


def _subbin(m: SkylineMatch, errors_at: NDArray[np.float64], step: float) -> tuple[float, float]:
    """Parabolic refinement of the best shift from errors at shifts -1, 0, +1 bins around it;
    returns (offset in degrees, curvature-based sigma in degrees)."""
    em, e0, ep = errors_at
    den = em - 2 * e0 + ep
    if not (np.isfinite(den) and den > 1e-9):
        return 0.0, step
    off = float(np.clip(0.5 * (em - ep) / den, -0.5, 0.5)) * step
    sigma = max(0.1 * step, step * math.sqrt(max(e0, 1e-3) / den) * 0.5)
    return off, sigma


def _shifted(profile: NDArray, s: int) -> NDArray[np.float64]:
    """``out[i] = profile[i - s]``, NaN where that falls outside."""
    out = np.full(profile.shape, np.nan)
    n = profile.size
    if abs(s) < n:
        if s >= 0:
            out[s:] = profile[: n - s]
        else:
            out[:s] = profile[-s:]
    return out


@lru_cache(maxsize=16)
def _profile_bins(height: int, width: int, fov_y_deg: float, step_deg: float) -> int:
    """Bins of a skyline profile of a (height, width) view (the grid a given profile must be on)."""
    return skyline_from_depth(np.zeros((height, width), np.float32), fov_y_deg=fov_y_deg, step_deg=step_deg).size


class _Scorer:
    def __init__(
        self,
        image,
        emulator: CameraEmulator,
        *,
        step_deg,
        max_heading_deg,
        max_pitch_deg,
        truncate_deg,
        max_roll_deg,
        edge_weight,
        query_skyline=None,
    ) -> None:
        self.emulator = emulator
        self.fov = float(emulator.camera.fov_y_deg)
        self.step = step_deg
        self.kw = dict(
            step_deg=step_deg, max_pitch_deg=max_pitch_deg, truncate_deg=truncate_deg, max_roll_deg=max_roll_deg
        )
        self.max_heading = max_heading_deg
        h, w = emulator.height, emulator.width
        given = None if query_skyline is None else np.asarray(query_skyline, dtype=np.float32).ravel()
        if given is not None and given.size == _profile_bins(h, w, self.fov, step_deg):
            self.query = given
        else:  # none given, or on another grid (another field of view or step)
            self.query = skyline_from_image(image, fov_y_deg=self.fov, step_deg=step_deg)
        img = np.asarray(image)
        if img.shape[:2] != (h, w):
            img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
        self.edges = edge_image(img)
        self.edge_weight = edge_weight
        self.px_per_deg = emulator.intrinsics[0] * math.radians(1.0)
        self.renders = 0
        #: the last score's parts (skyline error, edge correlation) and the view it scored
        self.parts: tuple[float, float] = (math.inf, 0.0)
        self.view: View | None = None

    def score(
        self,
        x: float,
        y: float,
        heading: float,
        pitch: float,
        *,
        max_heading: float | None = None,
        view: View | None = None,
    ):
        """(score, heading, pitch, sigma_heading) of the view at (x, y) rendered at heading/pitch
        (``view``: that view, already rendered: not rendered again)."""
        if view is None:
            view = self.emulator.render(self.emulator.pose_at(x, y, heading, pitch_deg=pitch))
            self.renders += 1
        ref = skyline_from_depth(view.depth, fov_y_deg=self.fov, step_deg=self.step)
        mh = self.max_heading if max_heading is None else max_heading
        m = match_skylines(self.query, ref[None], max_heading_deg=mh, **self.kw)
        dh, dp = float(m.heading_deg[0]), float(m.pitch_deg[0])
        # the errors one bin either side of the best shift, for the sub-bin parabola
        around = [
            match_skylines(
                self.query, _shifted(ref, int(round(dh / self.step)) + k)[None], max_heading_deg=0.0, **self.kw
            ).error[0]
            for k in (-1, 0, 1)
        ]
        off, sig = _subbin(m, np.array(around), self.step)
        dh += off
        sky_err = float(m.error[0])
        # the edges are compared at the shift the skyline found, +-1 column and +-2 rows (the
        # skyline's pitch is only good to about a pixel)
        shift = int(round(dh * self.px_per_deg))
        lift = int(round(dp * self.px_per_deg))  # pitched up: the scene moves down the image
        ncc = _ncc_shifted(self.edges, edge_image(view.image), range(lift - 2, lift + 3), range(shift - 1, shift + 2))
        self.parts, self.view = (sky_err, ncc), view
        return sky_err + self.edge_weight * (1.0 - ncc), heading + dh, pitch + dp, sig


def _memory_turn(
    image: NDArray,
    view: View,
    start: Pose,
    emulator: CameraEmulator,
    pattern: Callable[[NDArray], NDArray],
    rolls_deg: Sequence[float],
    align_shift: tuple[int, int] | None,
) -> tuple[float, float, float]:
    """(heading, pitch, heading sigma) in degrees of the camera ``image`` against the ``view`` at
    ``start`` by the memory's alignment (:func:`refine_pose`'s ``pattern``)."""
    from models.derotate import rolled
    from models.scenario import MemorySpec
    from models.verify import memory_alignment, pixels_per_degree

    img = np.asarray(image)
    camera = {float(r): pattern(rolled(img, float(r))) for r in (rolls_deg or (0.0,))}
    rows_per_deg, cols_per_deg = pixels_per_degree(emulator, int(next(iter(camera.values())).shape[0]))
    window = MemorySpec().max_shift if align_shift is None else (int(align_shift[0]), int(align_shift[1]))
    al, _ = memory_alignment(
        camera, pattern(view.image), max_shift=window, rows_per_deg=rows_per_deg, cols_per_deg=cols_per_deg
    )
    return start.heading_deg + al.heading_deg, start.pitch_deg + al.pitch_deg, 1.0 / cols_per_deg


def refine_pose(
    image: NDArray,
    emulator: CameraEmulator,
    start: Pose,
    *,
    along_m: float = DEFAULT_ALONG_M,
    across_m: float = DEFAULT_ACROSS_M,
    levels: int = DEFAULT_LEVELS,
    grid: int = DEFAULT_GRID,
    edge_weight: float = DEFAULT_EDGE_WEIGHT,
    step_deg: float = DEFAULT_STEP_DEG,
    max_heading_deg: float = DEFAULT_MAX_HEADING_DEG,
    max_pitch_deg: float = DEFAULT_MAX_PITCH_DEG,
    truncate_deg: float = DEFAULT_TRUNCATE_DEG,
    max_roll_deg: float = DEFAULT_MAX_ROLL_DEG,
    position: bool = DEFAULT_POSITION,
    recheck: bool = DEFAULT_RECHECK,
    query_skyline: NDArray | None = None,
    start_view: View | None = None,
    pattern: Callable[[NDArray], NDArray] | None = None,
    rolls_deg: Sequence[float] = (0.0,),
    align_shift: tuple[int, int] | None = None,
    trust_deg: float = TRUST_DEG[0],
) -> RefinedPose:
    """Refine ``start`` (the chosen route point's pose) against the camera ``image`` (H, W, 3).

    See the module docstring for the search, the score and the uncertainty. Renders about
    ``2 + levels * grid**2`` views (fewer where the patterns of two levels overlap). With
    ``position=False`` only heading and pitch are refined (step 1, two views): the position
    stays the start's, its uncertainty that of a uniform spread over ``+-along_m`` and
    ``+-across_m``.

    ``query_skyline``: the image's skyline profile (:func:`models.skyline.skyline_from_image`
    with the emulator's field of view and ``step_deg``), when already extracted (the skyline
    ranker posts it); None, or a profile of another length: extracted here.

    ``start_view``: the view the emulator renders at ``start``, when already rendered (the chosen
    viewframe's image and depth from the viewframe cache entry of this emulator's map: the same
    renderer at the same pose gives the same pixels); used instead of rendering it, so step 1
    renders one view, not two. The caller vouches that it is that view.

    ``recheck`` False: step 1 ends with the first match (its heading, pitch, score and heading
    uncertainty), without the second view at the heading and pitch it found.

    ``pattern`` (the memory's pattern of an image, :meth:`models.index.ViewframeIndex.pattern`):
    when given and the skyline's match at the start is no better than ``trust_deg`` degrees (the
    horizon not found: clouds, haze, a gray or blocky image; :data:`models.skyline.TRUST_DEG`),
    the heading and pitch of step 1 come from the memory's alignment of the camera image with the
    start view instead (:func:`models.verify.memory_alignment`: its shift search over
    ``align_shift`` (rows, cols) pattern pixels, default the memory's ``max_shift``, and the
    camera image turned by each of ``rolls_deg``), their uncertainty a pattern pixel.
    """
    if levels < 1 or grid < 2:
        raise ValueError(f"levels must be >= 1 and grid >= 2, got levels={levels}, grid={grid}")
    if along_m < 0 or across_m < 0:
        raise ValueError(f"along_m and across_m must be >= 0, got {along_m}, {across_m}")
    sc = _Scorer(
        image,
        emulator,
        step_deg=step_deg,
        max_heading_deg=max_heading_deg,
        max_pitch_deg=max_pitch_deg,
        truncate_deg=truncate_deg,
        max_roll_deg=max_roll_deg,
        edge_weight=edge_weight,
        query_skyline=query_skyline,
    )
    # 1. heading and pitch at the start point, then score it again at that heading
    s0, heading, pitch, sig_h = sc.score(start.x, start.y, start.heading_deg, start.pitch_deg, view=start_view)
    if pattern is not None and not sc.parts[0] < trust_deg and sc.view is not None:
        heading, pitch, sig_h = _memory_turn(image, sc.view, start, emulator, pattern, rolls_deg, align_shift)
    elif recheck:
        s0, heading, pitch, sig_h = sc.score(start.x, start.y, heading, pitch, max_heading=2 * step_deg)
    th = math.radians(start.heading_deg)
    fwd, side = np.array([math.cos(th), math.sin(th)]), np.array([math.sin(th), -math.cos(th)])
    centre = np.zeros(2)  # (along, across) offsets from the start
    best = (s0, heading, pitch, sig_h)
    seen: dict[tuple[float, float], float] = {(0.0, 0.0): s0}
    ext = np.array([along_m, across_m], dtype=np.float64)
    last: list[tuple[float, float, float]] = []
    if not position:
        return RefinedPose(
            start.x,
            start.y,
            float(heading),
            float(pitch),
            along_m / math.sqrt(3),
            across_m / math.sqrt(3),
            float(sig_h),
            float(s0),
            float(s0),
            sc.renders,
        )
    for _ in range(levels):
        ticks = np.linspace(-1.0, 1.0, grid)
        last = []
        level_centre = centre.copy()
        for a in ticks:
            for c in ticks:
                off = level_centre + ext * (a, c)
                key = (round(float(off[0]), 3), round(float(off[1]), 3))
                if key in seen:
                    last.append((*off, seen[key]))
                    continue
                x, y = np.array([start.x, start.y]) + off[0] * fwd + off[1] * side
                got = sc.score(float(x), float(y), best[1], best[2], max_heading=4 * step_deg)
                seen[key] = got[0]
                last.append((*off, got[0]))
                if got[0] < best[0]:
                    best, centre = got, off
        ext = np.maximum(2 * ext / (grid - 1), 0.25)  # the next pattern spans one step either side
    pts = np.array(last)
    scores = pts[:, 2]
    tau = max(float(np.median(np.abs(scores - np.median(scores)))), 1e-3)
    w = np.exp(-(scores - scores.min()) / tau)
    w /= w.sum()
    mean = (w[:, None] * pts[:, :2]).sum(0)
    spread = np.sqrt((w[:, None] * (pts[:, :2] - mean) ** 2).sum(0))
    floor = ext
    sig_along, sig_across = np.maximum(spread, floor)
    x, y = np.array([start.x, start.y]) + centre[0] * fwd + centre[1] * side
    return RefinedPose(
        float(x),
        float(y),
        float(best[1]),
        float(best[2]),
        float(sig_along),
        float(sig_across),
        float(best[3]),
        float(best[0]),
        float(s0),
        sc.renders,
    )
