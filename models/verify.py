"""Render-and-compare verification of candidate places: how well a view rendered at each candidate
matches the camera image, by the memory's own similarity.

For each candidate (a viewframe's pose), :func:`verify_candidates`

1. finds the camera's heading and pitch against the candidate's view by the skyline shift
   (:func:`models.refine.refine_pose` with ``position=False``: its step 1; the candidate's own
   viewframe, when given, is that view, so no render),
2. renders the view at the candidate's place with that heading and pitch (one render), and
3. scores it by the correlation of the camera image's and the view's memory patterns (the
   whitened, blurred edge images the associative memory stores and compares,
   :meth:`models.index.ViewframeIndex.pattern`), best over circular shifts up to
   ``max_shift`` (rows, cols) pattern pixels (:func:`pattern_correlation`): the memory's
   similarity, without its shift search (the heading and pitch are already aligned) and without
   the crosstalk of a holographic recall.

A higher correlation: the camera more likely stands there. The correlations enter the decision
as a likelihood (:class:`models.scenario.VerifySpec`, calibrated on the evaluation set's tuning
split by ``bench/rerank.py``). Poses are world (x, y, z) metres, heading ccw from +x, pitch up
(degrees); images (H, W, 3) uint8 indexed (row, col).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from models.refine import refine_pose

if TYPE_CHECKING:
    from models.camera_emulator import CameraEmulator, Pose, View

__all__ = ["Verified", "pattern_correlation", "verify_candidates", "verified_ranking", "DEFAULT_MAX_SHIFT"]

#: (rows, cols) pattern pixels of the correlation's shift search (the view is aligned already)
DEFAULT_MAX_SHIFT = (2, 2)


@dataclass(frozen=True)
class Verified:
    """The verification of candidates, in the order given: ``correlations`` (memory-pattern
    correlation of the camera image with each candidate's aligned view, in [-1, 1]),
    ``headings_deg`` and ``pitches_deg`` (the aligned views' heading and pitch), ``renders``
    (views rendered in all)."""

    correlations: list[float]
    headings_deg: list[float]
    pitches_deg: list[float]
    renders: int


def pattern_correlation(a: NDArray, b: NDArray, *, max_shift: tuple[int, int] = DEFAULT_MAX_SHIFT) -> float:
    """Best circular correlation of two memory patterns ``a`` and ``b`` ((N, N), zero mean, unit
    energy) over shifts of up to ``max_shift`` (rows, cols) pixels either way; 0 when either has
    no energy (a featureless image)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(f"patterns must be two (N, N) arrays of one shape, got {a.shape} and {b.shape}")
    if not (np.any(a) and np.any(b)):
        return 0.0
    c = np.real(np.fft.ifft2(np.fft.fft2(a) * np.conj(np.fft.fft2(b))))
    r, q = (int(max_shift[0]), int(max_shift[1]))
    rows = np.r_[0 : r + 1, -r:0] % c.shape[0]
    cols = np.r_[0 : q + 1, -q:0] % c.shape[1]
    return float(c[np.ix_(rows, cols)].max())


def verify_candidates(
    image: NDArray,
    emulator: CameraEmulator,
    starts: Sequence[Pose],
    *,
    pattern: Callable[[NDArray], NDArray],
    start_views: Sequence[View | None] | None = None,
    query_skyline: NDArray | None = None,
    step_deg: float,
    max_heading_deg: float,
    max_pitch_deg: float,
    truncate_deg: float,
    max_shift: tuple[int, int] = DEFAULT_MAX_SHIFT,
    rolls_deg: Sequence[float] = (0.0,),
    max_roll_deg: float = 0.0,
) -> Verified:
    """Verify each candidate pose of ``starts`` against the camera ``image`` (H, W, 3) (module
    docstring). ``pattern``: the memory's pattern of an image (the index's
    :meth:`~models.index.ViewframeIndex.pattern`); ``start_views``: each candidate's own view
    (its viewframe's image and depth) when at hand, else None (rendered); ``query_skyline``: the
    image's skyline profile when already extracted; the skyline matching options are the
    refiner's (:func:`models.refine.refine_pose`). ``rolls_deg``: the camera image is also
    compared turned by each of these rolls about its centre (:func:`models.derotate.rolled`, as
    the memory's roll search does), each candidate keeping its best correlation; ``max_roll_deg``
    the skyline match's roll bound when it finds the heading and pitch (0: no roll fitted)."""
    from models.derotate import rolled

    views = list(start_views) if start_views is not None else [None] * len(starts)
    if len(views) != len(starts):
        raise ValueError(f"{len(views)} start views for {len(starts)} candidates")
    cameras = [pattern(rolled(np.asarray(image), float(a))) for a in (rolls_deg or (0.0,))]
    out_c, out_h, out_p, renders = [], [], [], 0
    for start, view in zip(starts, views):
        r = refine_pose(
            image,
            emulator,
            start,
            position=False,
            recheck=False,
            query_skyline=query_skyline,
            start_view=view,
            step_deg=step_deg,
            max_heading_deg=max_heading_deg,
            max_pitch_deg=max_pitch_deg,
            truncate_deg=truncate_deg,
            max_roll_deg=max_roll_deg,
        )
        aligned = emulator.render(emulator.pose_at(start.x, start.y, r.heading_deg, pitch_deg=r.pitch_deg))
        renders += r.renders + 1
        view_pattern = pattern(aligned.image)
        out_c.append(max(pattern_correlation(c, view_pattern, max_shift=max_shift) for c in cameras))
        out_h.append(float(r.heading_deg))
        out_p.append(float(r.pitch_deg))
    return Verified(out_c, out_h, out_p, renders)


def verified_ranking(
    ranking: Sequence[tuple[int, float]],
    viewframes: Sequence[int],
    correlations: Sequence[float],
    *,
    weight: float,
) -> list[tuple[int, float]]:
    """A best-first ranking ``[(viewframe, F), ...]`` (F the fused score, nats, lower is better)
    with the verified candidates' scores raised by ``weight * (max_j c_j - c_k)`` (``c`` their
    correlations, :func:`verify_candidates`; the best-matching candidate keeps its score) and
    sorted again (ties keep the ranking's order). Viewframes not verified keep their scores; a
    verified viewframe missing from ``ranking`` is ignored."""
    if len(viewframes) != len(correlations):
        raise ValueError(f"{len(viewframes)} viewframes but {len(correlations)} correlations")
    c = {int(v): float(x) for v, x in zip(viewframes, correlations) if np.isfinite(x)}
    if not c:
        return [(int(k), float(f)) for k, f in ranking]
    top = max(c.values())
    scored = [(int(k), float(f) + (weight * (top - c[int(k)]) if int(k) in c else 0.0)) for k, f in ranking]
    order = sorted(range(len(scored)), key=lambda i: (scored[i][1], i))
    return [scored[i] for i in order]
