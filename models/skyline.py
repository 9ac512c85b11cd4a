"""The skyline: the sky/terrain boundary of a view, as an angular profile, and its matching.

A *skyline* is the elevation angle of the sky/terrain boundary at each azimuth of the view,
sampled on a fixed angular grid so that views of other resolutions (and other fields of view)
compare bin by bin. Conventions (the pinhole of :mod:`models.camera_emulator`): a pixel (row, col) sees
the camera-frame ray ``(xc, yc, 1)`` with ``xc = (col - cx) / f``, ``yc = (cy - row) / f``; its
**azimuth** is ``atan(xc)`` (degrees, positive to the right of the optical axis) and its
**elevation** ``atan2(yc, sqrt(1 + xc**2))`` (degrees, positive above the optical axis). Bin i
of a profile of ``n`` bins at ``step_deg`` sits at azimuth ``(i - (n - 1) / 2) * step_deg``;
``n = 2 * floor(half_fov_x / step_deg) + 1``, so bin ``(n - 1) / 2`` is the optical axis.
An invalid bin (no boundary in the image there: terrain up to the top edge, or sky down to the
bottom edge) is NaN.

**From a depth buffer** (viewframes, :func:`skyline_from_depth`): sky is where the renderer
found no geometry (depth 0); the boundary of a column is its first geometry row from the top.

**From a camera image** (:func:`skyline_from_image`): a two-class (sky, terrain) labelling with
one boundary per column, solved exactly by dynamic programming over the columns (a chain MRF):

    E(b) = sum_c [ sum_{r < b_c} u_sky(r, c) + sum_{r >= b_c} u_ter(r, c) - lam_edge * g(b_c, c) ]
         + sum_c lam_smooth * min(|b_c - b_{c-1}|, jump)

``b_c`` (0..H) is the number of sky pixels at the top of column c. The unaries are negative
log-likelihoods under per-image Gaussian colour-and-texture models of the two classes (CIE Lab
plus the log local variance of L), their difference capped at ``cap`` nats so that a few odd
pixels cannot decide a column. The sky is a smooth field (a smoothing spline in the row that
goes on linearly below the rows it was fitted on, linear in the column: a sky gradient; a
quadratic in the row until session 15) plus Gaussian residuals; the terrain a mixture of
Gaussian clusters plus a uniform outlier component, so a pixel that fits neither (a hazy far
ridge, a landmark) counts as terrain: the sky is the simple class. The models start from the top
rows (mostly sky; the sky model's first fit is trimmed of the tenth of them that fit it worst,
twice, so that a little snow or rock beside the sky does not make it broad enough to take a
snowfield for sky) and the bottom rows (always terrain for a ground camera) and are refitted
from the labelling, an EM of hard labels, until the boundary settles (at most 2 % of the columns moved by more than
a row; at most 12 rounds). Each round the sky model reaches a little further down: under a
gradient sky, a hazy band above the horizon or clouds, whose lower sky the first rounds' model
(fitted on the top rows) calls terrain, the boundary comes down a few rows a round, and three
fixed rounds (sessions 3-13) left it in the sky on most such frames (the evaluation set's
``tuning-sky`` split: 56 % of its frames more than 1 degree off with three rounds, 2-6 % when
the EM runs until it settles, in 6 rounds on average; 4 on the tuning split's frames). ``g`` is the vertical contrast across the boundary (the Lab distance between
the two rows' neighbourhoods, over its image median), which pins the boundary to the edge that
haze leaves between far hills and sky. The truncated-linear smoothness lets silhouettes
(towers, steep slopes) jump at a bounded price. Images are first reduced to at most
:data:`WORK_ROWS` rows, so the cost does not grow with the resolution and the constants mean
the same at every size; gain and gamma do not matter (the class models are per image).

**Matching** (:func:`match_skylines`): the camera profile ``q`` against reference profiles
``r`` over heading shifts ``delta`` (whole bins), a pitch offset and a roll. With the camera
turned by ``delta`` (ccw, as headings), pitched by ``pi`` and rolled by ``rho`` relative to the
reference, ``q(a) = r(a - delta) - pi - tan(rho) * a`` near the horizon (a roll tilts the
profile: at azimuth ``a`` a point of the horizon moves by about ``rho * a`` in elevation, about
0.9 degrees at the border of a 55-degree view for a roll of 2 degrees). For each shift the tilt is
fitted robustly first: the median of ``r - q`` over the left half of the bins valid in both and
over the right half, the line through them at the halves' median azimuths (a two-group
median line, robust as a median), its slope clipped to ``tan(max_roll_deg)``
(``max_roll_deg`` 0: no roll, the profile is only shifted); then the pitch offset is the median
of the detilted ``r - q``, clipped to ``max_pitch_deg``, and the error is the mean of the
residuals truncated at ``truncate_deg`` (a truncated L1: an occluder or a wrong column costs at
most ``truncate_deg``). Overlaps under ``min_overlap`` of the bins score ``truncate_deg``. The
best shift of each reference is returned: error (degrees), heading offset, pitch offset, roll.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from models.scenario import SkylineSpec

__all__ = [
    "WORK_ROWS",
    "TRUST_DEG",
    "SkylineMatch",
    "profile_bins",
    "profile_azimuths",
    "boundary_to_profile",
    "skyline_from_depth",
    "skyline_from_image",
    "image_boundary",
    "match_skylines",
]

log = logging.getLogger(__name__)

_DEFAULTS = SkylineSpec()  # the defaults are the scenario schema's (models.scenario)
DEFAULT_STEP_DEG = _DEFAULTS.step_deg
DEFAULT_MAX_HEADING_DEG = _DEFAULTS.max_heading_deg
DEFAULT_MAX_PITCH_DEG = _DEFAULTS.max_pitch_deg
DEFAULT_TRUNCATE_DEG = _DEFAULTS.truncate_deg
DEFAULT_MAX_ROLL_DEG = _DEFAULTS.max_roll_deg
DEFAULT_ROLL_CANDIDATES = _DEFAULTS.roll_candidates
#: images are reduced to at most this many rows before the boundary search
WORK_ROWS = 128
#: how far a match's best error (degrees) says the camera's horizon was found: fully trusted up to
#: the first, not at all from the second (a horizon found wrongly: JPEG blocks, a gray image,
#: clouds). The fusion's skyline trust (:data:`knowledge_sources.fusion.ABSOLUTE_TRUST`, chosen on
#: the evaluation set's tuning split) and the pose refiner's heading (:func:`models.refine.refine_pose`)
TRUST_DEG: tuple[float, float] = (0.5, 1.0)

_CAP = 4.0  # nats: cap of a pixel's class cost
_LAM_EDGE = 3.0  # nats per unit of normalised contrast at the boundary
_LAM_SMOOTH = 0.6  # nats per row of boundary jump between neighbouring columns
_JUMP = 8  # rows: jumps beyond cost no more
#: the EM of the class models runs at most this many rounds (a labelling and a refit each) ...
_ROUNDS = 12
#: ... and stops once no more than this share of the columns moved their boundary by more than a row
_SETTLED = 0.02
#: the first round's sky model (fitted on the top rows, the seed) is fitted again this many times
#: without the share of its pixels that fit it worst (session 15: snow or pale rock in the top
#: rows beside the sky made the seed's model broad enough to take the snow for sky) ...
_SEED_TRIM_ROUNDS = 2
#: ... this share
_SEED_TRIM_SHARE = 0.1
#: the sky field along the rows: "spline" (session 15: a smoothing spline, :func:`_sky_design`) or
#: "quadratic" (sessions 3-14; it followed a cloudy sky's gradient less well: BENCHMARKS.md, "The
#: sky model's field"; neither follows a sky that pales steeply to a flat haze band)
_SKY_FIELD = "spline"
#: the fields :data:`_SKY_FIELD` may name
_SKY_FIELDS: tuple[str, ...] = ("spline", "quadratic")
#: the spline's knots over the working image's rows ...
_SKY_KNOTS = 8
#: ... and the weight of its second differences (per knot, against the fitted pixels)
_SKY_SMOOTH = 1.0
_MIN_OVERLAP = 0.5


def _fov_x_half(width: int, height: int, fov_y_deg: float) -> float:
    return math.degrees(math.atan(math.tan(math.radians(fov_y_deg) / 2) * width / height))


def profile_bins(width: int, height: int, *, fov_y_deg: float, step_deg: float = DEFAULT_STEP_DEG) -> int:
    """Number of bins of the profile of a (height, width) view with vertical field ``fov_y_deg``."""
    if width < 2 or height < 2:
        raise ValueError(f"image must be at least 2 x 2 pixels, not {height} x {width}")
    if not 0 < fov_y_deg < 180:
        raise ValueError(f"fov_y_deg must be in (0, 180), not {fov_y_deg}")
    if not step_deg > 0:
        raise ValueError(f"step_deg must be > 0, not {step_deg}")
    return 2 * int(math.floor(_fov_x_half(width, height, fov_y_deg) / step_deg)) + 1


def profile_azimuths(n: int, *, step_deg: float = DEFAULT_STEP_DEG) -> NDArray[np.float64]:
    """Azimuth in degrees (positive right of the optical axis) of each of ``n`` bins, shape (n,)."""
    return (np.arange(n, dtype=np.float64) - (n - 1) / 2) * float(step_deg)


def boundary_to_profile(
    boundary: NDArray,
    height: int,
    *,
    fov_y_deg: float,
    step_deg: float = DEFAULT_STEP_DEG,
) -> NDArray[np.float32]:
    """Per-column boundary rows -> angular profile.

    Parameters
    ----------
    boundary : ndarray of shape (W,)
        Number of sky pixels at the top of each column (0..height, fractional allowed); the
        boundary lies between rows ``b - 1`` and ``b``. Columns with ``b <= 0`` (terrain up to the
        top), ``b >= height`` (no terrain) or NaN are invalid.
    height : int
        Rows of the image the boundary was found in.

    Returns
    -------
    ndarray of shape (n,), float32
        Elevation in degrees per bin (module docstring), NaN where invalid.
    """
    b = np.asarray(boundary, dtype=np.float64).ravel()
    width = b.size
    n = profile_bins(width, height, fov_y_deg=fov_y_deg, step_deg=step_deg)
    f = (height / 2) / math.tan(math.radians(fov_y_deg) / 2)
    cx, cy = (width - 1) / 2, (height - 1) / 2
    xc = (np.arange(width) - cx) / f
    yc = (cy - (b - 0.5)) / f
    azimuth = np.degrees(np.arctan(xc))
    elevation = np.degrees(np.arctan2(yc, np.sqrt(1 + xc**2)))
    valid = np.isfinite(b) & (b > 0) & (b < height)
    grid = profile_azimuths(n, step_deg=step_deg)
    out = np.interp(grid, azimuth, np.where(valid, elevation, 0.0))
    # a bin is valid when both columns it is interpolated from are
    right = np.clip(np.searchsorted(azimuth, grid), 0, width - 1)
    left = np.clip(right - 1, 0, width - 1)
    ok = valid[left] & valid[right]
    out[~ok] = np.nan
    return out.astype(np.float32)


def skyline_from_depth(depth: NDArray, *, fov_y_deg: float, step_deg: float = DEFAULT_STEP_DEG) -> NDArray[np.float32]:
    """The profile of a rendered view from its depth buffer (H, W) (0 = sky), shape (n,)."""
    d = np.asarray(depth)
    if d.ndim != 2:
        raise ValueError(f"depth must have shape (H, W), not {d.shape}")
    geometry = d > 0
    first = np.argmax(geometry, axis=0).astype(np.float64)
    first[~geometry.any(axis=0)] = d.shape[0]
    return boundary_to_profile(first, d.shape[0], fov_y_deg=fov_y_deg, step_deg=step_deg)


def _features(rgb: NDArray[np.float32]) -> NDArray[np.float32]:
    """(H, W, 4) per-pixel features: CIE Lab and log local variance of L (over 5 pixels of the row)."""
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2Lab)
    L = lab[..., 0]
    # along the row only: a window straddling the boundary would make the last sky row look textured
    mean = cv2.blur(L, (5, 1))
    var = np.maximum(cv2.blur(L * L, (5, 1)) - mean * mean, 0.0)
    tex = np.log(var + 1.0)
    return np.concatenate([lab, tex[..., None]], axis=2)


_FLOOR = np.diag([1.0, 0.5, 0.5, 0.05])  # covariance floors: noise-free renders
_LOG_VOLUME = math.log(100.0 * 256.0 * 256.0 * 10.0)  # the feature box (L, a, b, log variance)
_OUTLIER = 0.05  # prior weight of "none of the terrain clusters": terrain is everything not sky
_CLUSTERS = 3


def _row_sums(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """``p.sum(1)`` of an (n, d) array, bit for bit (numpy adds a C array's short rows left to
    right, ((p0 + p1) + p2) + ...), by whole columns: a reduction over rows of 4 costs more than
    the arithmetic."""
    s = p[:, 0] + p[:, 1]
    for j in range(2, p.shape[1]):
        s += p[:, j]
    return s


def _gauss_nll(x: NDArray[np.float64], mu: NDArray[np.float64] | None, cov: NDArray[np.float64]) -> NDArray[np.float64]:
    """Negative log density of each row of ``x`` (n, d) under N(mu, cov) (None: zero mean), shape (n,)."""
    d = x if mu is None else x - mu
    inv = np.linalg.inv(cov)
    _, logdet = np.linalg.slogdet(cov)
    return 0.5 * (_row_sums((d @ inv) * d) + logdet + x.shape[1] * math.log(2 * math.pi))


class _Pixels:
    """One working image's per-pixel quantities that every EM round uses: the features as (H*W, 4)
    float64 and the sky field's design matrix (a row per pixel, :func:`_sky_design`) with its
    penalty rows, computed once per image."""

    def __init__(self, feat: NDArray[np.float32]) -> None:
        h, w = feat.shape[:2]
        self.shape = (h, w)
        self.x = feat.reshape(-1, feat.shape[-1]).astype(np.float64)
        self.design, self.penalty = _sky_design(h, w)


def _sky_design(h: int, w: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The sky field's design, (H*W, K + 1), and its roughness penalty, (P, K + 1), of an (h, w)
    working image (pixel (r, c) is row ``r * w + c``).

    :data:`_SKY_FIELD` ``"spline"``: piecewise linear in the row between :data:`_SKY_KNOTS` knots
    spread evenly over the rows (hat functions), linear in the column; the penalty is the knots'
    second differences, so that the field is a smoothing spline that goes on linearly below the
    rows it was fitted on. ``"quadratic"`` (sessions 3-14): (1, row, row**2, column), no penalty."""
    r, c = np.mgrid[0:h, 0:w]
    cc = (c / w).ravel() - 0.5
    if _SKY_FIELD == "quadratic":
        rr = (r / h).ravel()
        return np.stack([np.ones_like(rr), rr, rr * rr, cc], axis=1), np.zeros((0, 4))
    knots = np.linspace(0.0, 1.0, _SKY_KNOTS)
    step = knots[1] - knots[0]
    rows = ((r + 0.5) / h).ravel()
    hats = np.maximum(0.0, 1.0 - np.abs(rows[:, None] - knots[None, :]) / step)
    second = np.diff(np.eye(_SKY_KNOTS), n=2, axis=0)
    return np.concatenate([hats, cc[:, None]], axis=1), np.concatenate([second, np.zeros((len(second), 1))], axis=1)


def _sky_cost(px: _Pixels, sel: NDArray[np.bool_], *, trim_rounds: int = 0) -> NDArray[np.float64]:
    """Sky: a smooth field (:func:`_sky_design`: a smoothing spline in the row, linear in the
    column: the sky's gradient) plus Gaussian residuals, fitted to the pixels in ``sel`` (H, W);
    negative log density per pixel, (H, W).

    ``trim_rounds``: that many times, the fit is done again without the :data:`_SEED_TRIM_SHARE`
    of its pixels that fit it worst (Mahalanobis distance of the residual): a trimmed fit, for
    the seed, where the top rows may hold a little snow or rock beside the sky."""
    h, w = px.shape
    x, design = px.x, px.design
    m = sel.ravel()
    if m.sum() < 16:
        m = np.zeros_like(m)
        m[: max(16, w)] = True
    idx = np.flatnonzero(m)
    for left in range(trim_rounds, -1, -1):
        # the penalty rows weigh as much per knot as the fitted pixels do
        pen = px.penalty * math.sqrt(_SKY_SMOOTH * len(idx) / max(1, px.design.shape[1] - 1))
        a = np.concatenate([design[idx], pen])
        y = np.concatenate([x[idx], np.zeros((len(pen), x.shape[1]))])
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        res = x - design @ coef
        cov = np.cov(res[idx], rowvar=False) + _FLOOR
        if left == 0:
            break
        r = res[idx]
        d2 = _row_sums((r @ np.linalg.inv(cov)) * r)
        keep = d2 <= np.quantile(d2, 1.0 - _SEED_TRIM_SHARE)
        if np.count_nonzero(keep) < 16:
            break
        idx = idx[keep]
    return _gauss_nll(res, None, cov).reshape(h, w)


def _terrain_cost(px: _Pixels, sel: NDArray[np.bool_], rng: np.random.Generator) -> NDArray[np.float64]:
    """Terrain: a mixture of Gaussian clusters fitted to the pixels in ``sel`` (H, W) plus a uniform
    outlier component over the feature box; negative log density per pixel, (H, W)."""
    x = px.x
    s = x[sel.ravel()]
    if len(s) < 8 * _CLUSTERS:
        s = x
    if len(s) > 4000:
        s = s[rng.choice(len(s), 4000, replace=False)]
    k = min(_CLUSTERS, len(s) // 8)
    # k-means++ seeds from OpenCV's global generator: seeded, so that a frame's horizon does not
    # depend on how many k-means ran before it in this process
    cv2.setRNGSeed(int(rng.integers(2**31)))
    _, lab, _ = cv2.kmeans(  # bestLabels: an output (no KMEANS_USE_INITIAL_LABELS), given so that
        s.astype(np.float32),  # OpenCV 5.0's and 5.1's type stubs both accept the call
        k,
        np.zeros((len(s), 1), np.int32),
        (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 10, 0.5),
        1,
        cv2.KMEANS_PP_CENTERS,
    )
    lab = lab.ravel()
    # log of the mixture density, accumulated term by term as np.logaddexp.reduce over the stacked terms does
    total = np.full(len(x), math.log(_OUTLIER) - _LOG_VOLUME)
    for j in range(k):
        part = s[lab == j]
        if len(part) < 8:
            continue
        cov = np.cov(part, rowvar=False) + _FLOOR
        prior = (1 - _OUTLIER) * len(part) / len(s)
        np.logaddexp(total, math.log(prior) - _gauss_nll(x, part.mean(0), cov), out=total)
    return -total.reshape(px.shape)


def _contrast(feat: NDArray[np.float32]) -> NDArray[np.float64]:
    """(H + 1, W) normalised vertical contrast at each boundary position (0 and H: none)."""
    lab = feat[..., :3].astype(np.float64)
    h = lab.shape[0]
    above = cv2.blur(lab, (3, 1))  # horizontal smoothing against noise
    g = np.zeros((h + 1, lab.shape[1]))
    # two rows above vs two rows below the boundary between rows b-1 and b
    up = (above[:-1] + np.vstack([above[:1], above[:-2]])) / 2
    down = (above[1:] + np.vstack([above[2:], above[-1:]])) / 2
    diff = down - up
    sq = diff * diff  # the Euclidean norm over the channels, as np.linalg.norm adds them: left to right
    g[1:h] = np.sqrt(sq[..., 0] + sq[..., 1] + sq[..., 2])
    scale = float(np.median(g[1:h])) + 1e-6
    return np.minimum(g / (4 * scale), 3.0)


def _viterbi(unary: NDArray[np.float64], *, lam: float, jump: int) -> NDArray[np.int64]:
    """Minimise sum_c unary[b_c, c] + lam * min(|b_c - b_{c-1}|, jump); unary (S, W) -> b (W,).

    Per column the pairwise minimum is taken over the 2 * jump + 1 nearby states and the global
    minimum (plus the truncated cost ``lam * jump``): O(S * jump) instead of O(S**2). The forward
    pass keeps each column's costs (padded by ``jump`` infinite states on both sides, so that the
    nearby states of every state are one strided window); the predecessor of a state is found
    again on the way back, for the states of the path only (ties: the lowest state, the global
    minimum only when strictly cheaper)."""
    s, w = unary.shape
    offsets = np.arange(-jump, jump + 1)
    pen = lam * np.abs(offsets)
    far_pen = lam * jump
    costs = np.full((w, s + 2 * jump), np.inf)  # column c's costs in [jump, jump + s)
    inner = costs[:, jump : jump + s]
    step = costs.strides[1]
    # windows[c, i, k]: cost of state i + offsets[k] of column c (inf outside the states)
    windows = np.lib.stride_tricks.as_strided(
        costs, (w, s, 2 * jump + 1), (costs.strides[0], step, step), writeable=False
    )
    # the same, offsets first: the minimum over the offsets is then one of whole rows (a reduction over short rows is slow)
    by_offset = windows.transpose(0, 2, 1)
    cols = np.ascontiguousarray(unary.T)
    inner[0] = cols[0]
    near = np.empty((2 * jump + 1, s))
    best = np.empty(s)
    pen_col = pen[:, None]
    for c in range(1, w):
        np.add(by_offset[c - 1], pen_col, out=near)
        np.minimum.reduce(near, axis=0, out=best)
        np.minimum(best, inner[c - 1].min() + far_pen, out=best)
        np.add(best, cols[c], out=inner[c])
    glob = inner.argmin(axis=1)
    far = inner[np.arange(w), glob] + far_pen
    b = np.zeros(w, dtype=np.int64)
    b[-1] = int(inner[-1].argmin())
    for c in range(w - 1, 0, -1):
        state = int(b[c])
        vals = windows[c - 1, state] + pen
        k = int(vals.argmin())
        b[c - 1] = glob[c - 1] if far[c - 1] < vals[k] else state + offsets[k]
    return b


def image_boundary(image: NDArray) -> tuple[NDArray[np.float64], int]:
    """Sky/terrain boundary of a camera image by the chain-MRF of the module docstring.

    Parameters
    ----------
    image : ndarray of shape (H, W, 3) uint8 RGB, or (H, W) gray

    Returns
    -------
    boundary : ndarray of shape (W',)
        Sky pixels at the top of each column of the working image (0..H').
    rows : int
        H', the working image's rows (``min(H, WORK_ROWS)``); W' keeps the aspect ratio.
    """
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] != 3 or min(img.shape[:2]) < 2:
        raise ValueError(f"image must have shape (H, W, 3) or (H, W), not {np.asarray(image).shape}")
    rgb = img.astype(np.float32) / (255.0 if img.dtype == np.uint8 else max(float(img.max()), 1e-6))
    h, w = rgb.shape[:2]
    if h > WORK_ROWS:
        w2 = max(2, int(round(w * WORK_ROWS / h)))
        rgb = np.asarray(cv2.resize(rgb, (w2, WORK_ROWS), interpolation=cv2.INTER_AREA), dtype=np.float32)
        h, w = rgb.shape[:2]
    feat = _features(np.ascontiguousarray(rgb))
    px = _Pixels(feat)
    edge = _LAM_EDGE * _contrast(feat)
    rows = np.arange(h)[:, None]
    sky_sel = np.zeros((h, w), bool)
    sky_sel[: max(1, h // 12)] = True
    ter_sel = rows >= h - max(1, h // 4)
    ter_sel = np.broadcast_to(ter_sel, (h, w))
    b = np.zeros(w, dtype=np.int64)
    rng = np.random.default_rng(0)
    sums = np.zeros((h + 1, w))  # row 0: no sky pixel
    for k in range(_ROUNDS):
        cs = _sky_cost(px, sky_sel, trim_rounds=_SEED_TRIM_ROUNDS if k == 0 else 0)
        ct = _terrain_cost(px, ter_sel, rng)
        llr = np.clip(cs - ct, -_CAP, _CAP)  # > 0: looks like terrain
        # E(b) = sum_{r<b} llr(r) + const: cumulative sums, b = 0..h
        np.cumsum(llr, axis=0, out=sums[1:])
        unary = sums - edge
        before, b = b, _viterbi(unary, lam=_LAM_SMOOTH, jump=_JUMP)
        sky_sel = rows < b[None, :]
        ter_sel = ~sky_sel
        if sky_sel.sum() < 8 or ter_sel.sum() < 8 or _settled(b, before):
            break
    return b.astype(np.float64), h


def _settled(b: NDArray[np.int64], before: NDArray[np.int64]) -> bool:
    """The EM's boundary has settled: at most :data:`_SETTLED` of the columns moved by more than a
    row since the round before (the first round's ``before`` is all zeros: it has moved)."""
    return bool(np.count_nonzero(np.abs(b - before) > 1) <= _SETTLED * b.size)


def skyline_from_image(
    image: NDArray,
    *,
    fov_y_deg: float,
    step_deg: float = DEFAULT_STEP_DEG,
    columns: tuple[int, int] | list[int] | None = None,
) -> NDArray[np.float32]:
    """The profile (n,) of a camera image (H, W, 3) uint8 RGB (module docstring).

    ``columns``: the [first, last) image columns that hold the scene (a narrower camera frame
    padded to the camera's width, :func:`models.sensor.fit_to_camera`); the bins outside them
    are NaN (no horizon seen there), None: every column.
    """
    if columns is None:
        b, rows = image_boundary(image)
        return boundary_to_profile(b, rows, fov_y_deg=fov_y_deg, step_deg=step_deg)
    img = np.asarray(image)
    height, width = img.shape[:2]
    first, last = max(0, int(columns[0])), min(width, int(columns[1]))
    if last - first < 2:
        raise ValueError(f"columns must hold at least 2 of the image's {width} columns, not {list(columns)}")
    # the horizon of the columns that see the scene alone (the padding would shape the class models)
    b, rows = image_boundary(img[:, first:last])
    cols = np.arange(last - first, dtype=np.float64)
    inner = np.interp((cols + 0.5) * b.size / (last - first) - 0.5, np.arange(b.size, dtype=np.float64), b)
    full = np.full(width, np.nan)
    full[first:last] = inner * height / rows
    return boundary_to_profile(full, height, fov_y_deg=fov_y_deg, step_deg=step_deg)


def _row_nanmedian(d: NDArray[np.float64], cnt: NDArray[np.int64]) -> NDArray[np.float64]:
    """Median of the finite entries of each row (``cnt`` of them, >= 1): NaNs sort last.

    Rows without a NaN (most, where both profiles are valid throughout the overlap) take their
    two middle values from a partition (and, for an even ``m``, the maximum below the upper one),
    O(m) instead of a sort's O(m log m); the same values."""
    m = d.shape[1]
    full = cnt == m
    out = np.empty(len(d))
    if full.any():
        lo, hi = (m - 1) // 2, m // 2
        part = np.partition(d[full], hi, axis=1)
        # an even count's lower middle value is the largest of those before the upper one: a maximum
        # costs less than a second partition index (the same value)
        low = part[:, lo] if lo == hi else part[:, :hi].max(axis=1)
        out[full] = 0.5 * (low + part[:, hi])
    rest = ~full
    if rest.any():
        srt = np.sort(d[rest], axis=1)
        c = cnt[rest]
        rows = np.arange(len(srt))
        out[rest] = 0.5 * (srt[rows, (c - 1) // 2] + srt[rows, c // 2])
    return out


#: references matched at once (their per-shift temporaries, about 1 MB, stay in the CPU's cache)
_BLOCK = 256


@dataclass(frozen=True)
class SkylineMatch:
    """Best shift of a query profile against each of V references.

    ``error`` (V,) mean truncated residual in degrees (lower is better); ``heading_deg`` (V,)
    how far the camera is turned ccw from the reference; ``pitch_deg`` (V,) how far it is
    pitched up from the reference; ``overlap`` (V,) fraction of bins compared; ``roll_deg`` (V,)
    the fitted tilt, ``atan`` of the slope of ``r - q`` against azimuth (degrees; positive: the
    camera's horizon falls to the right relative to the reference's; zeros without roll).
    """

    error: NDArray[np.float64]
    heading_deg: NDArray[np.float64]
    pitch_deg: NDArray[np.float64]
    overlap: NDArray[np.float64]
    roll_deg: NDArray[np.float64] | None = None


_MATCH_FIELDS = ("error", "heading_deg", "pitch_deg", "overlap", "roll_deg")


def match_skylines(
    query: NDArray,
    references: NDArray,
    *,
    step_deg: float = DEFAULT_STEP_DEG,
    max_heading_deg: float = DEFAULT_MAX_HEADING_DEG,
    max_pitch_deg: float = DEFAULT_MAX_PITCH_DEG,
    truncate_deg: float = DEFAULT_TRUNCATE_DEG,
    max_roll_deg: float = DEFAULT_MAX_ROLL_DEG,
    roll_candidates: int | None = DEFAULT_ROLL_CANDIDATES,
    min_overlap: float = _MIN_OVERLAP,
) -> SkylineMatch:
    """Match the camera profile ``query`` (n,) with ``references`` (V, n) over heading shifts.

    Both must be on the same grid (``step_deg``, same n). See the module docstring for the
    model and the robust error. A reference without enough overlap at any shift scores
    ``truncate_deg`` with zero offsets.

    Two stages when the roll is fitted (``max_roll_deg`` > 0) and ``roll_candidates`` is less
    than V: every reference is matched without roll (the roll fit is most of a match's cost),
    then the ``roll_candidates`` best of that pass (ties: the first reference) are matched again
    with the roll; their results are those of a one-stage match, the others' the roll-free ones.
    None: the roll is fitted for every reference.
    """
    q = np.asarray(query, dtype=np.float64).ravel()
    r = np.asarray(references, dtype=np.float64)
    if r.ndim == 1:
        r = r[None]
    if r.ndim != 2 or r.shape[1] != q.size:
        raise ValueError(f"references must have shape (V, {q.size}) like the query, not {r.shape}")
    if not truncate_deg > 0 or max_heading_deg < 0 or max_pitch_deg < 0 or not 0 <= max_roll_deg < 45:
        raise ValueError("truncate_deg must be > 0, max_heading_deg and max_pitch_deg >= 0, max_roll_deg in [0, 45)")
    if roll_candidates is not None and roll_candidates < 1:
        raise ValueError(f"roll_candidates must be >= 1 or None, got {roll_candidates}")
    kw = {
        "step_deg": step_deg,
        "max_heading_deg": max_heading_deg,
        "max_pitch_deg": max_pitch_deg,
        "truncate_deg": truncate_deg,
        "min_overlap": min_overlap,
    }
    if max_roll_deg > 0 and roll_candidates is not None and roll_candidates < len(r):
        flat = match_skylines(q, r, max_roll_deg=0.0, roll_candidates=None, **kw)
        best = np.argsort(flat.error, kind="stable")[:roll_candidates]
        rolled = match_skylines(q, r[best], max_roll_deg=max_roll_deg, roll_candidates=None, **kw)
        out = {f: np.array(getattr(flat, f), dtype=np.float64) for f in _MATCH_FIELDS}
        for f in _MATCH_FIELDS:
            out[f][best] = getattr(rolled, f)
        return SkylineMatch(**out)
    if len(r) > _BLOCK:  # rows are matched independently: in blocks whose temporaries stay in cache
        parts = [
            match_skylines(q, r[i : i + _BLOCK], max_roll_deg=max_roll_deg, roll_candidates=None, **kw)
            for i in range(0, len(r), _BLOCK)
        ]
        return SkylineMatch(**{f: np.concatenate([getattr(m, f) for m in parts]) for f in _MATCH_FIELDS})
    v, n = r.shape
    smax = min(int(round(max_heading_deg / step_deg)), n - 1)
    shifts = np.arange(-smax, smax + 1)
    best_e = np.full(v, float(truncate_deg))
    best_h = np.zeros(v)
    best_p = np.zeros(v)
    best_o = np.zeros(v)
    best_r = np.zeros(v)
    qn = np.isfinite(q).sum()
    if qn == 0 or v == 0:
        return SkylineMatch(best_e, best_h, best_p, best_o, best_r)
    need = max(3, int(math.ceil(min_overlap * qn)))
    az = profile_azimuths(n, step_deg=step_deg)
    slope_max = math.tan(math.radians(max_roll_deg))
    for s in shifts:
        # q(i) against r(i - s)
        lo, hi = max(0, s), min(n, n + s)
        d = r[:, lo - s : hi - s] - q[None, lo:hi]  # r - q = pitch offset (+ tilt) where they agree
        ok = np.isfinite(d)
        cnt = ok.sum(1)
        use = cnt >= need
        if not use.any():
            continue
        du, oku, cu = d[use], ok[use], cnt[use]
        slope = np.zeros(len(du))
        if slope_max > 0:
            slope = np.clip(_tilt(du, oku, cu, az[lo:hi]), -slope_max, slope_max)
            du = du - slope[:, None] * az[None, lo:hi]
        pitch = np.clip(_row_nanmedian(du, cu), -max_pitch_deg, max_pitch_deg)
        res = np.minimum(np.abs(du - pitch[:, None]), truncate_deg)
        # bins of the query the reference does not cover count as truncated residuals
        err = (np.where(oku, res, 0.0).sum(1) + truncate_deg * (qn - cu)) / qn
        rows = np.nonzero(use)[0]
        better = err < best_e[rows]
        rows = rows[better]
        best_e[rows] = err[better]
        best_h[rows] = s * step_deg
        best_p[rows] = pitch[better]
        best_o[rows] = cu[better] / qn
        best_r[rows] = np.degrees(np.arctan(slope[better]))
    return SkylineMatch(best_e, best_h, best_p, best_o, best_r)


def _tilt(d: NDArray[np.float64], ok: NDArray[np.bool_], cnt: NDArray[np.int64], az: NDArray[np.float64]) -> NDArray:
    """Robust slope (degrees of elevation per degree of azimuth) of each row of ``d`` (R, m), finite
    where ``ok``, against the azimuths ``az`` (m,): the line through the medians of the left and
    the right half of each row's finite bins, at the halves' median azimuths (module docstring)."""
    rows = np.arange(len(d))
    col = np.arange(d.shape[1])[None, :]
    # the finite bins of each row in azimuth order (a stable sort by validity keeps the order)
    order = np.argsort(~ok, axis=1, kind="stable")
    ds = np.take_along_axis(d, order, axis=1)
    azs = az[order]
    nl = cnt // 2
    nr = cnt - nl
    left = np.sort(np.where(col < nl[:, None], ds, np.inf), axis=1)
    right = np.sort(np.where((col >= nl[:, None]) & (col < cnt[:, None]), ds, np.inf), axis=1)
    m_l = 0.5 * (left[rows, (nl - 1) // 2] + left[rows, nl // 2])
    m_r = 0.5 * (right[rows, (nr - 1) // 2] + right[rows, nr // 2])
    a_l = 0.5 * (azs[rows, (nl - 1) // 2] + azs[rows, nl // 2])
    a_r = 0.5 * (azs[rows, nl + (nr - 1) // 2] + azs[rows, nl + nr // 2])
    return (m_r - m_l) / np.maximum(a_r - a_l, 1e-9)
