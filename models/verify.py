"""Render-and-compare verification of candidate places: how well a view rendered at each candidate,
turned as the camera was, matches the camera image, by the memory's own similarity.

For each candidate (a viewframe's pose), :func:`verify_candidates`

1. **aligns** the candidate's view with the camera image in two independent ways, each giving a
   heading, a pitch and a roll (:class:`Alignment`):

   * by the memory: the camera image's memory pattern, turned by each roll of ``rolls_deg``
     (:func:`models.derotate.rolled`), is correlated with the view's pattern over circular
     shifts up to ``align_shift`` (rows, cols) pattern pixels; the best shift, refined to a
     fraction of a pixel by a parabola through its neighbours, is the heading and pitch
     (:func:`memory_alignment`: pattern columns and rows per degree from the emulator's focal
     length);
   * by the skyline: the camera's skyline profile matched with the view's (from its depth)
     over heading, pitch and, up to ``max_roll_deg``, roll (:func:`skyline_alignment`);

2. **renders** the view at the candidate's place with each alignment's heading and pitch (one
   colour pass, :meth:`models.camera_emulator.CameraEmulator.render_image`; one render when the
   two alignments agree within a quarter of a degree), and
3. **scores** it by the correlation of the camera image's and the view's memory patterns (the
   whitened, blurred edge images the associative memory stores and compares,
   :meth:`models.index.ViewframeIndex.pattern`), the camera image turned by the alignment's
   roll and ``fine_roll_deg`` either side, best over circular shifts up to ``max_shift``
   (rows, cols) pattern pixels (:func:`pattern_correlation`). A candidate's correlation is the
   best of its alignments': a wrong alignment only lowers a correlation, and each way fails on
   its own frames (the skyline where the horizon was found wrongly, the memory's shift where
   near edges dominate).

A higher correlation: the camera more likely stands there. Rendering each candidate turned as
the camera was, rather than comparing the viewframe itself over shifts (the memory's ranking),
restores what a turn of several degrees moves out of the viewframe and the perspective of the
true heading and pitch. The correlations enter the decision as a likelihood
(:class:`models.scenario.VerifySpec`, calibrated on the evaluation set's tuning split).

Poses are world (x, y, z) metres, heading ccw from +x, pitch up (degrees); images (H, W, 3)
uint8 indexed (row, col); patterns (N, N) indexed (row, col).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from models.scenario import MemorySpec
from models.skyline import match_skylines, skyline_from_depth, skyline_from_image

if TYPE_CHECKING:
    from models.camera_emulator import CameraEmulator, Pose, View
    from models.scenario import Scenario
    from models.viewframes import Viewframe

__all__ = [
    "Alignment",
    "Verified",
    "pattern_correlation",
    "memory_alignment",
    "pixels_per_degree",
    "skyline_alignment",
    "verify_candidates",
    "verify_viewframes",
    "verified_ranking",
    "DEFAULT_MAX_SHIFT",
    "DEFAULT_FINE_ROLL_DEG",
]

#: (rows, cols) pattern pixels of the correlation's shift search (the view is aligned already)
DEFAULT_MAX_SHIFT = (2, 2)
#: the camera image is also compared turned this many degrees either side of an alignment's roll
DEFAULT_FINE_ROLL_DEG = 0.75
#: two alignments closer than this in heading and pitch (degrees), and in roll than the fine
#: roll step, are one: a single view is rendered
_SAME_DEG = 0.25


@dataclass(frozen=True)
class Alignment:
    """How the camera is turned against a candidate's view: ``heading_deg`` (ccw) and
    ``pitch_deg`` (up) to add to the view's pose, and ``roll_deg``, the turn of the camera image
    (:func:`models.derotate.rolled`'s convention) that levels it against the view."""

    heading_deg: float
    pitch_deg: float
    roll_deg: float


@dataclass(frozen=True)
class Verified:
    """The verification of candidates, in the order given: ``correlations`` (memory-pattern
    correlation of the camera image with each candidate's aligned view, in [-1, 1]),
    ``headings_deg``, ``pitches_deg`` and ``rolls_deg`` (the best-matching aligned view's heading
    and pitch, and the camera image's roll against it), ``renders`` (views rendered in all)."""

    correlations: list[float]
    headings_deg: list[float]
    pitches_deg: list[float]
    renders: int
    rolls_deg: list[float] | None = None


def _spectrum(pattern: NDArray) -> NDArray[np.complex128]:
    """The real 2-D spectrum of an (N, N) pattern (what the correlations below multiply)."""
    return np.fft.rfft2(np.asarray(pattern, dtype=np.float64))


def _feature_spectrum(pattern: NDArray) -> NDArray[np.complex128] | None:
    """:func:`_spectrum` of a pattern with features, None for a featureless (all-zero) one."""
    return _spectrum(pattern) if np.any(pattern) else None


def _correlation_map(a: NDArray[np.complex128], b: NDArray[np.complex128], shape: tuple[int, int]) -> NDArray:
    """Circular cross-correlation ``c[dr, dc] = sum a(r, c) b(r - dr, c - dc)`` of two patterns of
    ``shape`` given by their spectra (:func:`_spectrum`)."""
    return np.fft.irfft2(a * np.conj(b), s=shape)


def _window(c: NDArray[np.float64], max_shift: tuple[int, int]) -> tuple[NDArray, NDArray]:
    r, q = (int(max_shift[0]), int(max_shift[1]))
    return np.r_[0 : r + 1, -r:0] % c.shape[0], np.r_[0 : q + 1, -q:0] % c.shape[1]


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
    return _windowed_max(_correlation_map(_spectrum(a), _spectrum(b), a.shape), max_shift)


def _windowed_max(c: NDArray[np.float64], max_shift: tuple[int, int]) -> float:
    rows, cols = _window(c, max_shift)
    return float(c[np.ix_(rows, cols)].max())


def _peak_offset(minus: float, centre: float, plus: float) -> float:
    """Sub-pixel offset in [-0.5, 0.5] of a maximum at ``centre`` from its neighbours (parabola)."""
    den = minus - 2.0 * centre + plus
    return float(np.clip(0.5 * (minus - plus) / den, -0.5, 0.5)) if den < 0 else 0.0


def pixels_per_degree(emulator: CameraEmulator, n: int) -> tuple[float, float]:
    """(rows, cols) of an (n, n) memory pattern of the ``emulator``'s images per degree of pitch
    and of heading, at the image centre (square pixels; the pattern resizes the image)."""
    per_deg = emulator.intrinsics[0] * math.radians(1.0) * n
    return per_deg / emulator.height, per_deg / emulator.width


def memory_alignment(
    camera: Mapping[float, NDArray],
    view_pattern: NDArray,
    *,
    max_shift: tuple[int, int],
    rows_per_deg: float,
    cols_per_deg: float,
) -> tuple[Alignment, float]:
    """The memory's alignment of a view with the camera image (module docstring, step 1) and its
    correlation: ``camera`` maps a roll (degrees) to the camera image's pattern turned by it,
    ``view_pattern`` is the view's (N, N); the best circular shift over ``max_shift`` (rows, cols)
    pattern pixels and the rolls, refined to a fraction of a pixel, as degrees of heading (camera
    content moved right: the camera looks further left, ccw) and pitch (moved down: pitched up).
    A featureless view or camera: no turn, correlation 0."""
    b = np.asarray(view_pattern, dtype=np.float64)
    spectra = {float(r): _spectrum(a) for r, a in camera.items() if np.any(a)}
    return _align(spectra, _feature_spectrum(b), b.shape, max_shift, rows_per_deg, cols_per_deg)


def _align(
    camera: Mapping[float, NDArray[np.complex128]],
    view: NDArray[np.complex128] | None,
    shape: tuple[int, ...],
    max_shift: tuple[int, int],
    rows_per_deg: float,
    cols_per_deg: float,
) -> tuple[Alignment, float]:
    """:func:`memory_alignment` of spectra (featureless patterns left out of ``camera``, None for ``view``)."""
    best: tuple[float, float, float, float] = (-math.inf, 0.0, 0.0, 0.0)
    n_r, n_c = int(shape[0]), int(shape[1])
    if view is None:
        return Alignment(0.0, 0.0, 0.0), 0.0
    for roll, a in camera.items():
        c = _correlation_map(a, view, (n_r, n_c))
        rows, cols = _window(c, max_shift)
        sub = c[np.ix_(rows, cols)]
        i, j = np.unravel_index(int(np.argmax(sub)), sub.shape)
        if sub[i, j] <= best[0]:
            continue
        r0, c0 = int(rows[i]), int(cols[j])
        dr = (r0 if r0 <= n_r // 2 else r0 - n_r) + _peak_offset(
            c[(r0 - 1) % n_r, c0], c[r0, c0], c[(r0 + 1) % n_r, c0]
        )
        dc = (c0 if c0 <= n_c // 2 else c0 - n_c) + _peak_offset(
            c[r0, (c0 - 1) % n_c], c[r0, c0], c[r0, (c0 + 1) % n_c]
        )
        best = (float(sub[i, j]), float(dr), float(dc), float(roll))
    if not math.isfinite(best[0]):
        return Alignment(0.0, 0.0, 0.0), 0.0
    score, dr, dc, roll = best
    return Alignment(dc / cols_per_deg, dr / rows_per_deg, roll), score


def skyline_alignment(
    query_skyline: NDArray,
    depth: NDArray,
    *,
    fov_y_deg: float,
    step_deg: float,
    max_heading_deg: float,
    max_pitch_deg: float,
    truncate_deg: float,
    max_roll_deg: float,
) -> Alignment | None:
    """The skyline's alignment of a view (its ``depth``, (H, W) metres, 0 for sky) with the camera
    image's skyline profile ``query_skyline`` (module docstring, step 1); None when the camera
    profile holds no horizon or the match finds no overlap (no alignment to offer)."""
    q = np.asarray(query_skyline, dtype=np.float32).ravel()
    if not np.isfinite(q).any():
        return None
    ref = skyline_from_depth(depth, fov_y_deg=fov_y_deg, step_deg=step_deg)
    if ref.size != q.size:
        raise ValueError(f"the camera's skyline has {q.size} bins, the view's {ref.size}: not one grid")
    # the view's profile at every heading shift as rows of one match without a shift search: the
    # same result as match_skylines over the shifts (the overlap, pitch, roll and error of each
    # shift are those of its row; the first best in order of shift, as there), in one vectorised pass
    n = ref.size
    smax = min(int(round(max_heading_deg / step_deg)), n - 1)
    shifts = np.arange(-smax, smax + 1)
    shifted = np.full((shifts.size, n), np.nan, dtype=np.float64)
    for row, k in enumerate(shifts.tolist()):  # shifted[row, i] = ref[i - k]
        if k >= 0:
            shifted[row, k:] = ref[: n - k]
        else:
            shifted[row, :k] = ref[-k:]
    m = match_skylines(
        q,
        shifted,
        step_deg=step_deg,
        max_heading_deg=0.0,
        max_pitch_deg=max_pitch_deg,
        truncate_deg=truncate_deg,
        max_roll_deg=max_roll_deg,
        roll_candidates=None,
    )
    best = int(np.argmin(m.error))
    if not m.overlap[best] > 0:
        return None
    roll = 0.0 if m.roll_deg is None else float(m.roll_deg[best])
    return Alignment(float(shifts[best] * step_deg), float(m.pitch_deg[best]), roll)


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
    align_shift: tuple[int, int] | None = None,
    rolls_deg: Sequence[float] = (0.0,),
    max_roll_deg: float = 0.0,
    fine_roll_deg: float = DEFAULT_FINE_ROLL_DEG,
) -> Verified:
    """Verify each candidate pose of ``starts`` against the camera ``image`` (H, W, 3) (module
    docstring). ``pattern``: the memory's pattern of an image (the index's
    :meth:`~models.index.ViewframeIndex.pattern`); ``start_views``: each candidate's own view
    (its viewframe's image and depth) when at hand, else None (rendered); ``query_skyline``: the
    image's skyline profile when already extracted (else extracted here); ``step_deg``,
    ``max_heading_deg``, ``max_pitch_deg``, ``truncate_deg`` and ``max_roll_deg``: the skyline
    alignment's match (:func:`skyline_alignment`); ``align_shift``: the memory alignment's shift
    window (rows, cols) pattern pixels (default: the memory's, :class:`models.scenario.MemorySpec`'s
    ``max_shift``), ``rolls_deg`` its rolls (the memory's roll search);
    ``max_shift`` and ``fine_roll_deg``: the aligned view's correlation (step 3)."""
    from models.derotate import rolled

    if fine_roll_deg < 0:
        raise ValueError(f"fine_roll_deg must be >= 0, got {fine_roll_deg!r}")
    views = list(start_views) if start_views is not None else [None] * len(starts)
    if len(views) != len(starts):
        raise ValueError(f"{len(views)} start views for {len(starts)} candidates")
    img = np.asarray(image)
    turned: dict[float, NDArray[np.complex128] | None] = {}
    shape: tuple[int, int] = (0, 0)  # the patterns' (N, N), from the first one made

    def camera_spectrum(roll: float) -> NDArray[np.complex128] | None:
        """The spectrum of the camera image's pattern turned by ``roll`` (None: featureless), once."""
        nonlocal shape
        key = round(float(roll) * 64.0) / 64.0
        if key not in turned:
            p = np.asarray(pattern(rolled(img, key)))
            shape = (int(p.shape[0]), int(p.shape[1]))
            turned[key] = _feature_spectrum(p)
        return turned[key]

    # the camera's spectrum at each roll of the coarse search, those with features
    featured = {float(r): a for r in (rolls_deg or (0.0,)) if (a := camera_spectrum(r)) is not None}
    n = shape[0]
    window = (int(align_shift[0]), int(align_shift[1])) if align_shift is not None else MemorySpec().max_shift
    fov = float(emulator.camera.fov_y_deg)
    rows_per_deg, cols_per_deg = pixels_per_degree(emulator, n)
    sky = query_skyline
    if sky is None or not np.asarray(sky).size:
        sky = skyline_from_image(img, fov_y_deg=fov, step_deg=step_deg)
    out_c: list[float] = []
    out_h: list[float] = []
    out_p: list[float] = []
    out_r: list[float] = []
    renders = 0
    for start, view in zip(starts, views):
        if view is None:
            view = emulator.render(start)
            renders += 1
        found, _ = _align(
            featured,
            _feature_spectrum(pattern(view.image)),
            shape,
            window,
            rows_per_deg,
            cols_per_deg,
        )
        aligns = [found]
        by_sky = skyline_alignment(
            sky,
            view.depth,
            fov_y_deg=fov,
            step_deg=step_deg,
            max_heading_deg=max_heading_deg,
            max_pitch_deg=max_pitch_deg,
            truncate_deg=truncate_deg,
            max_roll_deg=max_roll_deg,
        )
        if by_sky is not None and not (
            abs(by_sky.heading_deg - found.heading_deg) < _SAME_DEG
            and abs(by_sky.pitch_deg - found.pitch_deg) < _SAME_DEG
            and abs(by_sky.roll_deg - found.roll_deg) <= fine_roll_deg
        ):
            aligns.append(by_sky)
        best = (-math.inf, start.heading_deg, start.pitch_deg, 0.0)
        for al in aligns:
            heading, pitch = start.heading_deg + al.heading_deg, start.pitch_deg + al.pitch_deg
            aligned = pattern(emulator.render_image(emulator.pose_at(start.x, start.y, heading, pitch_deg=pitch)))
            renders += 1
            spec = _feature_spectrum(aligned)
            for roll in sorted({al.roll_deg - fine_roll_deg, al.roll_deg, al.roll_deg + fine_roll_deg}):
                cam = camera_spectrum(roll)
                c = 0.0 if cam is None or spec is None else _windowed_max(_correlation_map(cam, spec, shape), max_shift)
                if c > best[0]:
                    best = (c, heading, pitch, roll)
        out_c.append(float(best[0]))
        out_h.append(float(best[1]))
        out_p.append(float(best[2]))
        out_r.append(float(best[3]))
    return Verified(out_c, out_h, out_p, renders, out_r)


def verify_viewframes(
    image: NDArray,
    emulator: CameraEmulator,
    viewframes: Sequence[Viewframe],
    scenario: Scenario,
    *,
    pattern: Callable[[NDArray], NDArray],
    query_skyline: NDArray | None = None,
) -> Verified:
    """:func:`verify_candidates` of rendered ``viewframes`` (each its own start view: no render)
    with a ``scenario``'s settings, as the verifier agent verifies them: the skyline block's
    match, the memory's shift window, the verification's rolls and roll bound (the offline
    benchmarks' call, bench/rerank.py and bench/tracking_data.py)."""
    from models.camera_emulator import View

    starts, views = [], []
    for v in viewframes:
        start = emulator.pose_at(v.pose.x, v.pose.y, v.pose.heading_deg, pitch_deg=v.pose.pitch_deg)
        starts.append(start)
        views.append(View(image=np.asarray(v.image), depth=np.asarray(v.depth), mask=np.asarray(v.mask), pose=start))
    sky, ver = scenario.skyline, scenario.verify
    return verify_candidates(
        image,
        emulator,
        starts,
        pattern=pattern,
        start_views=views,
        query_skyline=query_skyline,
        step_deg=sky.step_deg,
        max_heading_deg=sky.max_heading_deg,
        max_pitch_deg=sky.max_pitch_deg,
        truncate_deg=sky.truncate_deg,
        align_shift=scenario.memory.max_shift,
        rolls_deg=ver.roll_search_deg,
        max_roll_deg=ver.max_roll_deg,
    )


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
