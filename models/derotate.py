"""Levelling a camera image by the roll (and pitch) its skyline match found, before the memory matches it.

The associative memory compares edge patterns over image shifts only (:mod:`models.associative`):
a camera rolled by a few degrees against the level viewframes tilts every edge, which no shift
undoes (3 degrees move the image's side columns by about 3 rows of a 128-row pattern against
its centre, more than the 1-pixel blur tolerates). The skyline ranker fits that roll, and the
horizon's vertical offset (the pitch), for every viewframe it matches
(:func:`models.skyline.match_skylines`). :func:`level_image` takes the roll and pitch of the
best skyline matches and turns the camera image back to a level view: a rotation about the
principal point by the roll, and optionally a vertical shift by the pitch.

Levelling by the skyline is not in the pipeline (the memory searches fixed rolls instead,
:func:`rolled` with ``MemorySpec.roll_search_deg``): on the evaluation set's tuning split it
lifted the memory's own ranking under the larger pose errors (top-1 0.525 -> 0.595 with the
pitch too) but lowered it under the standard ones (0.695 -> 0.655), and the fused ranking not at
all (0.610 -> 0.600 large, 0.735 -> 0.730 standard; on 640 frames with the extra tuning drives
0.589 -> 0.608 and 0.702 -> 0.705, against 0.636 and 0.705 for the roll search; BENCHMARKS.md,
"Larger pose errors, component by component"; ``bench/pose_ablation.py --derotate`` /
``--rolls``).

Conventions (those of :mod:`models.skyline` and :mod:`models.camera_emulator`): images are
indexed (row, col), row 0 at the top, principal point at the image centre
``((W - 1) / 2, (H - 1) / 2)`` in (x, y) = (col, row) pixels; ``f = (H / 2) / tan(fov_y / 2)``.
A match's ``roll_deg`` is positive when the camera's horizon falls to the right against the
reference's (the camera rolled clockwise as seen in the image); ``pitch_deg`` positive when the
camera is pitched up from the reference (its horizon lower in the image). The viewframes are
rendered level (roll 0, the scenario camera's pitch), so the best matches' roll and pitch are
the camera's own against a level camera.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from models.skyline import SkylineMatch

__all__ = ["LEVEL_CANDIDATES", "LEVEL_MAX_ERROR_DEG", "rolled", "level_pose", "level_image"]

#: the skyline matches whose roll and pitch are taken (their median): the best five
LEVEL_CANDIDATES = 5
#: a best skyline error above this many degrees says nothing of the roll (the horizon was not found):
#: the fusion's skyline trust reaches zero there too (:data:`knowledge_sources.fusion.ABSOLUTE_TRUST`)
LEVEL_MAX_ERROR_DEG = 1.0


def rolled(image: NDArray, roll_deg: float, *, dy: float = 0.0) -> NDArray:
    """``image`` (H, W[, C]) turned by ``roll_deg`` degrees counter-clockwise as seen (OpenCV's
    positive angle; rows down) about the principal point ``((W - 1) / 2, (H - 1) / 2)`` in (x, y) =
    (col, row) pixels, then moved down by ``dy`` rows; same shape and dtype. Pixels brought in
    from outside the frame repeat its border (no edge is made there). ``roll_deg`` 0 and ``dy``
    0: the image itself. The memory's roll search (:class:`models.scenario.MemorySpec`'s
    ``roll_search_deg``) matches the camera image turned so."""
    img = np.asarray(image)
    if img.ndim not in (2, 3) or min(img.shape[:2]) < 2:
        raise ValueError(f"image must have shape (H, W) or (H, W, C), not {img.shape}")
    if roll_deg == 0.0 and dy == 0.0:
        return img
    h, w = img.shape[:2]
    m = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), float(roll_deg), 1.0)
    m[1, 2] += dy
    return cv2.warpAffine(img, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def level_pose(
    match: SkylineMatch, *, candidates: int = LEVEL_CANDIDATES, max_error_deg: float = LEVEL_MAX_ERROR_DEG
) -> tuple[float, float] | None:
    """The camera's ``(roll_deg, pitch_deg)`` against a level view from a skyline match of every
    viewframe: the medians over the ``candidates`` best-matching viewframes (lowest error; a
    median, so that one wrong neighbour does not decide), or None when the best error exceeds
    ``max_error_deg`` (the horizon was not found well enough to say) or nothing was matched."""
    if candidates < 1:
        raise ValueError(f"candidates must be >= 1, got {candidates}")
    err = np.asarray(match.error, dtype=np.float64)
    if err.size == 0 or not float(err.min()) <= max_error_deg:
        return None
    best = np.argsort(err, kind="stable")[:candidates]
    roll = 0.0 if match.roll_deg is None else float(np.median(np.asarray(match.roll_deg)[best]))
    pitch = float(np.median(np.asarray(match.pitch_deg)[best]))
    return roll, pitch


def level_image(
    image: NDArray,
    match: SkylineMatch | None = None,
    *,
    fov_y_deg: float,
    roll_deg: float | None = None,
    pitch_deg: float | None = None,
    candidates: int = LEVEL_CANDIDATES,
    max_error_deg: float = LEVEL_MAX_ERROR_DEG,
    pitch: bool = False,
) -> NDArray:
    """``image`` (H, W[, C]) turned back to a level view (module docstring), same shape and dtype.

    The roll and pitch come from ``match`` (:func:`level_pose`) or are given (``roll_deg``,
    ``pitch_deg``: the camera's, degrees, the conventions of the module docstring); with neither,
    or when the match cannot say, the image is returned unchanged. ``pitch``: also shift the
    image vertically by the pitch (else the roll alone: the memory's row search absorbs the
    pitch). Pixels brought in from outside the frame repeat its border (no edge is made there).
    """
    img = np.asarray(image)
    if img.ndim not in (2, 3) or min(img.shape[:2]) < 2:
        raise ValueError(f"image must have shape (H, W) or (H, W, C), not {img.shape}")
    if not 0 < fov_y_deg < 180:
        raise ValueError(f"fov_y_deg must be in (0, 180), not {fov_y_deg}")
    if roll_deg is None and pitch_deg is None:
        pose = None if match is None else level_pose(match, candidates=candidates, max_error_deg=max_error_deg)
        if pose is None:
            return img
        roll_deg, pitch_deg = pose
    roll = float(roll_deg or 0.0)
    dy = 0.0
    h, w = img.shape[:2]
    if pitch and pitch_deg:
        f = (h / 2) / math.tan(math.radians(fov_y_deg) / 2)
        dy = -f * math.tan(math.radians(float(pitch_deg)))  # pitched up: the scene moves up by dy < 0
    # a horizon falling to the right (roll > 0) is levelled by a counter-clockwise turn as seen
    # in the image: OpenCV's positive angle (origin at the top-left, rows down)
    return rolled(img, roll, dy=dy)
