"""The horizon extraction of :mod:`models.skyline` as it was before it was made faster (main at
session 11; its EM rounds until the boundary settles since session 14): the straightforward per-image code, kept as the reference the faster one must equal
bit for bit (tests/models/test_skyline_reference.py), and the coarse stage's comparison
(:func:`models.skyline_coarse.coarse_errors`) as it was. Same constants, same features and block
helpers (imported); only the arithmetic's arrangement differs."""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from models.skyline import (
    _CAP,
    _CLUSTERS,
    _FLOOR,
    _JUMP,
    _LAM_EDGE,
    _LAM_SMOOTH,
    _LOG_VOLUME,
    _OUTLIER,
    _ROUNDS,
    _SEED_TRIM_ROUNDS,
    _SEED_TRIM_SHARE,
    _SETTLED,
    _SKY_FIELD,
    _SKY_KNOTS,
    _SKY_SMOOTH,
    WORK_ROWS,
    _features,
)
from models.skyline_coarse import _BLOCK as _COARSE_BLOCK
from models.skyline_coarse import _DEFAULTS, _MIN_OVERLAP, COARSE_STRIDE, CoarseSkylines, _median, _query_blocks

__all__ = ["image_boundary", "coarse_errors"]  # and the full match's _row_nanmedian


def _gauss_nll(x: NDArray[np.float64], mu: NDArray[np.float64], cov: NDArray[np.float64]) -> NDArray[np.float64]:
    """Negative log density of each row of ``x`` (n, d) under N(mu, cov), shape (n,)."""
    d = x - mu
    inv = np.linalg.inv(cov)
    _, logdet = np.linalg.slogdet(cov)
    return 0.5 * (((d @ inv) * d).sum(1) + logdet + x.shape[1] * math.log(2 * math.pi))


def _sky_cost(feat: NDArray[np.float32], sel: NDArray[np.bool_], trim_rounds: int = 0) -> NDArray[np.float64]:
    """Sky: a smooth field (a smoothing spline in the row: hat functions at _SKY_KNOTS knots, their
    second differences penalised; linear in column: the sky's gradient) plus Gaussian residuals,
    fitted to the pixels in ``sel``; negative log density per pixel, (H, W)."""
    h, w = feat.shape[:2]
    r, c = np.mgrid[0:h, 0:w]
    cc = (c / w).ravel() - 0.5
    if _SKY_FIELD == "quadratic":
        rr = (r / h).ravel()
        design = np.stack([np.ones_like(rr), rr, rr * rr, cc], axis=1)
        penalty = np.zeros((0, 4))
    else:
        knots = np.linspace(0.0, 1.0, _SKY_KNOTS)
        rows = ((r + 0.5) / h).ravel()
        columns = [np.maximum(0.0, 1.0 - np.abs(rows - k) / (knots[1] - knots[0])) for k in knots]
        design = np.stack([*columns, cc], axis=1)
        penalty = np.zeros((_SKY_KNOTS - 2, _SKY_KNOTS + 1))
        for i in range(_SKY_KNOTS - 2):  # second differences of the knots' values
            penalty[i, i : i + 3] = (1.0, -2.0, 1.0)
    x = feat.reshape(-1, feat.shape[-1]).astype(np.float64)
    m = sel.ravel()
    if m.sum() < 16:
        m = np.zeros_like(m)
        m[: max(16, w)] = True

    def fit(m: NDArray[np.bool_]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        pen = penalty * math.sqrt(_SKY_SMOOTH * m.sum() / max(1, design.shape[1] - 1))
        coef, *_ = np.linalg.lstsq(
            np.concatenate([design[m], pen]), np.concatenate([x[m], np.zeros((len(pen), x.shape[1]))]), rcond=None
        )
        res = x - design @ coef
        return res, np.cov(res[m], rowvar=False) + _FLOOR

    res, cov = fit(m)
    for _ in range(trim_rounds):  # fitted again without the seed's worst-fitting pixels
        d2 = np.full(len(x), np.inf)
        d2[m] = ((res[m] @ np.linalg.inv(cov)) * res[m]).sum(1)
        keep = m & (d2 <= np.quantile(d2[m], 1.0 - _SEED_TRIM_SHARE))
        if keep.sum() < 16:
            break
        m = keep
        res, cov = fit(m)
    return _gauss_nll(res, np.zeros(x.shape[1]), cov).reshape(h, w)


def _terrain_cost(feat: NDArray[np.float32], sel: NDArray[np.bool_], rng: np.random.Generator) -> NDArray[np.float64]:
    """Terrain: a mixture of Gaussian clusters fitted to the pixels in ``sel`` plus a uniform
    outlier component over the feature box; negative log density per pixel, (H, W)."""
    x = feat.reshape(-1, feat.shape[-1]).astype(np.float64)
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
    terms = [np.full(len(x), math.log(_OUTLIER) - _LOG_VOLUME)]
    for j in range(k):
        part = s[lab == j]
        if len(part) < 8:
            continue
        cov = np.cov(part, rowvar=False) + _FLOOR
        prior = (1 - _OUTLIER) * len(part) / len(s)
        terms.append(math.log(prior) - _gauss_nll(x, part.mean(0), cov))
    return -np.logaddexp.reduce(np.stack(terms), axis=0).reshape(feat.shape[:2])


def _contrast(feat: NDArray[np.float32]) -> NDArray[np.float64]:
    """(H + 1, W) normalised vertical contrast at each boundary position (0 and H: none)."""
    lab = feat[..., :3].astype(np.float64)
    h = lab.shape[0]
    above = cv2.blur(lab, (3, 1))  # horizontal smoothing against noise
    g = np.zeros((h + 1, lab.shape[1]))
    # two rows above vs two rows below the boundary between rows b-1 and b
    up = (above[:-1] + np.vstack([above[:1], above[:-2]])) / 2
    down = (above[1:] + np.vstack([above[2:], above[-1:]])) / 2
    g[1:h] = np.linalg.norm(down - up, axis=2)
    scale = float(np.median(g[1:h])) + 1e-6
    return np.minimum(g / (4 * scale), 3.0)


def _viterbi(unary: NDArray[np.float64], *, lam: float, jump: int) -> NDArray[np.int64]:
    """Minimise sum_c unary[b_c, c] + lam * min(|b_c - b_{c-1}|, jump); unary (S, W) -> b (W,).

    Per column the pairwise minimum is taken over the 2 * jump + 1 nearby states and the global
    minimum (plus the truncated cost ``lam * jump``): O(S * jump) instead of O(S**2)."""
    s, w = unary.shape
    idx = np.arange(s)
    offsets = np.arange(-jump, jump + 1)
    src = np.clip(idx[None, :] + offsets[:, None], 0, s - 1)  # (2J+1, S) predecessor states
    pen = lam * np.abs(offsets)[:, None] + np.where(src - idx[None, :] == offsets[:, None], 0.0, np.inf)
    cost = unary[:, 0].copy()
    back = np.zeros((w, s), dtype=np.int64)
    for c in range(1, w):
        near = cost[src] + pen  # (2J+1, S)
        k = np.argmin(near, axis=0)
        best_near = near[k, idx]
        g = int(np.argmin(cost))
        far = cost[g] + lam * jump
        use_far = far < best_near
        back[c] = np.where(use_far, g, src[k, idx])
        cost = np.where(use_far, far, best_near) + unary[:, c]
    b = np.zeros(w, dtype=np.int64)
    b[-1] = int(np.argmin(cost))
    for c in range(w - 1, 0, -1):
        b[c - 1] = back[c, b[c]]
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
    g = _contrast(feat)
    rows = np.arange(h)[:, None]
    sky_sel = np.zeros((h, w), bool)
    sky_sel[: max(1, h // 12)] = True
    ter_sel = rows >= h - max(1, h // 4)
    ter_sel = np.broadcast_to(ter_sel, (h, w))
    b = np.zeros(w, dtype=np.int64)
    rng = np.random.default_rng(0)
    for k in range(_ROUNDS):
        cs = _sky_cost(feat, sky_sel, _SEED_TRIM_ROUNDS if k == 0 else 0)
        ct = _terrain_cost(feat, ter_sel, rng)
        llr = np.clip(cs - ct, -_CAP, _CAP)  # > 0: looks like terrain
        # E(b) = sum_{r<b} llr(r) + const: cumulative sums, b = 0..h
        unary = np.vstack([np.zeros((1, w)), np.cumsum(llr, axis=0)]) - _LAM_EDGE * g
        before = b
        b = _viterbi(unary, lam=_LAM_SMOOTH, jump=_JUMP)
        sky_sel = rows < b[None, :]
        ter_sel = ~sky_sel
        if sky_sel.sum() < 8 or ter_sel.sum() < 8:
            break
        # settled: few columns moved by more than a row since the round before
        if (np.abs(b - before) > 1).sum() <= _SETTLED * w:
            break
    return b.astype(np.float64), h


def coarse_errors(
    query: NDArray,
    coarse: CoarseSkylines,
    *,
    step_deg: float = _DEFAULTS.step_deg,
    max_heading_deg: float = _DEFAULTS.max_heading_deg,
    max_pitch_deg: float = _DEFAULTS.max_pitch_deg,
    truncate_deg: float = _DEFAULTS.truncate_deg,
    min_overlap: float = _MIN_OVERLAP,
    stride: int = COARSE_STRIDE,
) -> NDArray[np.float64]:
    """The coarse error (degrees, lower is better; module docstring) of the camera profile
    ``query`` (n,) against each prepared reference, shape (V,)."""
    q = np.asarray(query, dtype=np.float64).ravel()
    if q.size != coarse.bins:
        raise ValueError(f"query has {q.size} bins, the references {coarse.bins}")
    if not truncate_deg > 0 or max_heading_deg < 0 or max_pitch_deg < 0:
        raise ValueError("truncate_deg must be > 0, max_heading_deg and max_pitch_deg >= 0")
    if int(stride) < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    v = len(coarse)
    trunc = np.float32(truncate_deg)
    qn = float(np.isfinite(q).sum()) / coarse.factor  # the camera profile's valid bins, in blocks
    out = np.full(v, float(truncate_deg))
    if v == 0 or qn <= 0:
        return out
    smax = min(int(round(max_heading_deg / step_deg)), coarse.bins - 1)
    shifts = np.arange(-smax, smax + 1)
    shifts = shifts[shifts % int(stride) == 0]
    qb, qok = _query_blocks(q, coarse, shifts)
    need = max(2.0, min_overlap * qn)
    for i in range(0, v, _COARSE_BLOCK):
        d = coarse.values[i : i + _COARSE_BLOCK, None, :] - qb[None]  # (R, S, B)
        both = coarse.valid[i : i + _COARSE_BLOCK, None, :] & qok[None]
        m = both.sum(axis=2)
        d -= np.clip(_median(d, both), -max_pitch_deg, max_pitch_deg)[..., None]
        np.abs(d, out=d)
        np.minimum(d, trunc, out=d)
        d[~both] = 0.0
        err = (d.sum(axis=2) + trunc * np.maximum(np.float32(qn) - m, 0.0)) / np.float32(qn)
        err[m < need] = trunc
        out[i : i + _COARSE_BLOCK] = np.minimum(err.min(axis=1), trunc)
    return out


def _row_nanmedian(d: NDArray[np.float64], cnt: NDArray[np.int64]) -> NDArray[np.float64]:
    """Median of the finite entries of each row (``cnt`` of them, >= 1): NaNs sort last.

    Rows without a NaN (most, where both profiles are valid throughout the overlap) take their
    two middle values from a partition, O(m) instead of a sort's O(m log m); the same values."""
    m = d.shape[1]
    full = cnt == m
    out = np.empty(len(d))
    if full.any():
        lo, hi = (m - 1) // 2, m // 2
        part = np.partition(d[full], (lo, hi) if lo != hi else lo, axis=1)
        out[full] = 0.5 * (part[:, lo] + part[:, hi])
    rest = ~full
    if rest.any():
        srt = np.sort(d[rest], axis=1)
        c = cnt[rest]
        rows = np.arange(len(srt))
        out[rest] = 0.5 * (srt[rows, (c - 1) // 2] + srt[rows, c // 2])
    return out
