"""Where a landmark appears in an image, as angles, and how well an observed place fits a prediction.

A landmark's *placement* in an image is ``(elevation_deg, azimuth_deg, size_deg)``: the angles of
its silhouette's centroid from the optical axis (elevation positive up, azimuth positive to the
right) and its angular size, ``sqrt(pixels) / f`` in degrees. Angles, not pixels, so that a
camera frame and a viewframe of other image sizes (same field of view) compare directly. The
pinhole is :mod:`models.camera_emulator`'s: ``f = (H / 2) / tan(fov_y / 2)``, ``cx = (W - 1) / 2``,
``cy = (H - 1) / 2``, image (row, col) with pixel centres at integers.

The position evidence (used by :mod:`knowledge_sources.scene_analysis`): the detector reports
where it found landmark L in the camera frame (:meth:`models.detectors.EdgeTemplateDetector.match`);
each candidate viewframe V' that shows L predicts a placement, carried into the camera frame by
the camera's turn and tilt against V' (the skyline's alignment, when it is known: a heading error
moves every landmark alike). The residual ``(d_el, d_az, d_log_size)`` between observed and
predicted is scored by :func:`position_log_likelihood`: independent Student-t terms of ``dof``
degrees of freedom and scales ``spread`` (a robust model: a wrong match, a look-alike or the
viewframe's border gives a large residual that must not weigh like a Gaussian's tail).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["focal_px", "placement", "found_placement", "position_log_likelihood"]


def focal_px(height: int, fov_y_deg: float) -> float:
    """Focal length in pixels of a camera of ``height`` rows and vertical field of view ``fov_y_deg``."""
    if height < 1 or not 0 < fov_y_deg < 180:
        raise ValueError("height must be >= 1 and fov_y_deg in (0, 180)")
    return (height / 2) / math.tan(math.radians(fov_y_deg) / 2)


def placement(
    row: float, col: float, pixels: float, *, shape: Sequence[int], fov_y_deg: float
) -> tuple[float, float, float]:
    """``(elevation_deg, azimuth_deg, size_deg)`` of a silhouette of ``pixels`` pixels whose centroid
    is at ``(row, col)`` of an image of ``shape`` ``(H, W, ...)`` (module docstring)."""
    if pixels <= 0:
        raise ValueError("pixels must be > 0")
    h, w = int(shape[0]), int(shape[1])
    f = focal_px(h, fov_y_deg)
    elevation = math.degrees(math.atan(((h - 1) / 2 - float(row)) / f))
    azimuth = math.degrees(math.atan((float(col) - (w - 1) / 2) / f))
    return elevation, azimuth, math.degrees(math.sqrt(float(pixels)) / f)


def position_log_likelihood(residual: Sequence[float | None], *, spread: Sequence[float], dof: float) -> float:
    """Log of the Student-t likelihood of ``residual`` (``(d_elevation_deg, d_azimuth_deg,
    d_log_size)``; a ``None`` term is left out) with scales ``spread`` and ``dof`` degrees of
    freedom, relative to a zero residual (so 0 at the prediction, negative elsewhere)::

        sum_i -(dof + 1) / 2 * log(1 + (r_i / spread_i)**2 / dof)
    """
    if len(residual) != len(spread):
        raise ValueError(f"residual has {len(residual)} terms, spread {len(spread)}")
    if not dof > 0 or not all(s > 0 for s in spread):
        raise ValueError("dof and every spread must be > 0")
    total = 0.0
    for r, s in zip(residual, spread):
        if r is None:
            continue
        total -= (dof + 1) / 2 * math.log1p((float(r) / s) ** 2 / dof)
    return total


def found_placement(
    where: Sequence[float], *, pixels: float, shape: Sequence[int], fov_y_deg: float
) -> tuple[float, float, float]:
    """The placement of a detector's found match (:attr:`models.detectors.Detection.where`:
    ``(row, col, scale)`` in a camera image of ``shape``, the scale relative to the viewframe's
    silhouette of ``pixels`` pixels)."""
    row, col, scale = (float(v) for v in where)
    return placement(row, col, scale * scale * float(pixels), shape=shape, fov_y_deg=fov_y_deg)
