"""Preprocessing shared by stored viewframes and camera images.

With a scenario's memory settings it is :meth:`models.index.ViewframeIndex.pattern`.

The synthetic viewframes carry no trustworthy gray levels, so only edges are compared. The
pipeline, identical for both sides, is::

    image (H, W[, 3]) --gray--> resize to (size, size) --edges--> [whiten] --> gaussian blur --> normalise

* **resize first** (``cv2.INTER_AREA``, anti-aliased): the edge operator and ``blur_sigma``
  then work in *memory pixels*, whatever the camera resolution, and the cost does not grow
  with the camera size. The aspect ratio is not kept (both sides are squeezed the same way).
* **edges**: gradient magnitude (``"sobel"``, ``"scharr"``), absolute Laplacian
  (``"laplacian"``), binary Canny edges (``"canny"``, thresholds relative to the image's own
  gradients, see :func:`_canny`) or none (``"none"``, the gray levels themselves). Borders
  are reflected, so the image frame itself produces no edge.
* **whiten** (default on): the edge image's spectrum is set to unit magnitude (its phase is
  kept). Edge maps are non-negative lines whose energy sits in a few low frequencies, so
  without it a pattern has few effectively independent pixels (participation ratio of the
  power spectrum) and the holographic memory's crosstalk wins after a few stored patterns;
  whitened and then blurred, the spectrum is the gaussian envelope alone and
  N_eff = N**2 / (2 pi sigma**2) (measurements in BENCHMARKS.md). The blur is then applied
  in the frequency domain (circular, as the memory is).
* **blur**: a gaussian of ``blur_sigma`` memory pixels spreads each edge over its
  neighbourhood, which makes the comparison tolerant to shifts of about ``blur_sigma`` pixels
  (and lowers the number of effectively independent pixels, hence the memory's capacity).
* **normalise**: zero mean, unit energy (sum of squares = 1). A brightness gain or offset of
  the input therefore does not change the result. A featureless (constant) image has no
  energy to normalise: it comes back as all zeros, which every consumer treats as "no
  information" rather than as an error.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from models.scenario import MemorySpec

__all__ = ["EDGE_METHODS", "preprocess", "normalise"]

logger = logging.getLogger(__name__)

#: accepted values of ``edge``
EDGE_METHODS: tuple[str, ...] = ("sobel", "scharr", "laplacian", "canny", "none")
#: the defaults (size, edge, blur_sigma): the scenario schema's memory settings
_DEFAULTS = MemorySpec()


def _gray(image: NDArray) -> NDArray[np.float32]:
    if image.ndim == 3:
        if image.shape[2] == 4:
            image = image[:, :, :3]
        if image.shape[2] != 3:
            raise ValueError(f"image must have 1, 3 or 4 channels, got shape {image.shape}")
        # ITU-R 601 luma, RGB order (pyrender renders RGB)
        return (image[:, :, 0] * 0.299 + image[:, :, 1] * 0.587 + image[:, :, 2] * 0.114).astype(np.float32)
    return image.astype(np.float32, copy=False)


def _canny(gray: NDArray[np.float32]) -> NDArray[np.float32]:
    """Binary Canny edges (0/1) with thresholds relative to the image's own gradients.

    The high threshold is the 90th percentile of the Sobel gradient magnitude, the low one half
    of it, so a brightness gain does not change the result.
    """
    border = cv2.BORDER_REFLECT_101
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3, borderType=border)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3, borderType=border)
    mag = cv2.magnitude(gx, gy)
    peak = float(mag.max(initial=0.0))
    if peak == 0.0:
        return np.zeros_like(gray)
    scale = 32000.0 / peak  # int16 derivatives for cv2.Canny, full range
    hi = max(float(np.percentile(mag, 90)) * scale, 1.0)
    dx, dy = (np.round(g * scale).astype(np.int16) for g in (gx, gy))
    return (cv2.Canny(dx, dy, 0.5 * hi, hi, L2gradient=True) > 0).astype(np.float32)


def _whiten_blur(edges: np.ndarray, sigma: float) -> NDArray[np.float64]:
    """Unit spectral magnitude, then a circular gaussian blur of ``sigma`` pixels."""
    n_rows, n_cols = edges.shape
    f = np.fft.rfft2(edges.astype(np.float64))
    mag = np.abs(f)
    peak = float(mag.max(initial=0.0))
    if peak == 0.0:
        return np.zeros(edges.shape)
    f = np.where(mag > 1e-9 * peak, f / np.maximum(mag, 1e-300), 0.0)
    f[0, 0] = 0.0
    if sigma > 0:
        w2 = (2 * np.pi) ** 2 * (np.fft.fftfreq(n_rows)[:, None] ** 2 + np.fft.rfftfreq(n_cols)[None, :] ** 2)
        f *= np.exp(-0.5 * sigma * sigma * w2)
    return np.fft.irfft2(f, s=edges.shape)


def normalise(pattern: ArrayLike) -> NDArray[np.float32]:
    """Return ``pattern`` with zero mean and unit energy (sum of squares 1) as float32.

    A constant pattern comes back as zeros of the same shape.
    """
    p = np.asarray(pattern, dtype=np.float64)
    p = p - p.mean()
    energy = float(np.sqrt(np.sum(p * p)))
    if energy <= 1e-12 * max(1.0, float(np.abs(pattern).max(initial=0.0))):
        return np.zeros(p.shape, dtype=np.float32)
    return (p / energy).astype(np.float32)


def preprocess(
    image: ArrayLike,
    *,
    size: int = _DEFAULTS.size,
    edge: str = _DEFAULTS.edge,
    blur_sigma: float = _DEFAULTS.blur_sigma,
    whiten: bool = _DEFAULTS.whiten,
) -> NDArray[np.float32]:
    """Turn an image into a memory pattern.

    Parameters
    ----------
    image : array of shape (H, W) or (H, W, 3) (RGB) or (H, W, 4), uint8 or float
        Any size; rows are image rows (row, col).
    size : int
        Side N of the square output (the memory size), >= 8.
    edge : str
        One of :data:`EDGE_METHODS`.
    blur_sigma : float
        Gaussian sigma in output (memory) pixels, >= 0 (0: no blur).
    whiten : bool
        Flatten the edge image's spectrum before blurring (see the module docstring).

    Returns
    -------
    ndarray of shape (size, size), float32, zero mean and unit energy (or all zeros for a
    featureless image).
    """
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 8:
        raise ValueError(f"size must be an integer >= 8, got {size!r}")
    if edge not in EDGE_METHODS:
        raise ValueError(f"edge must be one of {', '.join(EDGE_METHODS)}, got {edge!r}")
    if not np.isfinite(blur_sigma) or blur_sigma < 0:
        raise ValueError(f"blur_sigma must be a finite number >= 0, got {blur_sigma!r}")
    img = np.asarray(image)
    if img.ndim not in (2, 3) or img.shape[0] < 2 or img.shape[1] < 2:
        raise ValueError(f"image must have shape (H, W) or (H, W, C) with H, W >= 2, got {img.shape}")
    if not (np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)):
        raise ValueError(f"image must be an integer or float array, got dtype {img.dtype}")
    if not np.all(np.isfinite(img)):
        raise ValueError("image must not contain NaN or infinite values")

    gray: np.ndarray = _gray(img)
    size = int(size)
    if gray.shape != (size, size):
        shrinking = gray.shape[0] >= size and gray.shape[1] >= size
        gray = cv2.resize(gray, (size, size), interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)

    border = cv2.BORDER_REFLECT_101
    edges: np.ndarray
    if edge in ("sobel", "scharr"):
        ksize = 3 if edge == "sobel" else cv2.FILTER_SCHARR
        gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=ksize, borderType=border)
        gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=ksize, borderType=border)
        edges = cv2.magnitude(gx, gy)
    elif edge == "canny":
        edges = _canny(gray)
    elif edge == "laplacian":
        edges = np.abs(cv2.Laplacian(gray, cv2.CV_32F, ksize=3, borderType=border))
    else:
        edges = gray

    if whiten:
        edges = _whiten_blur(edges, float(blur_sigma))
    elif blur_sigma > 0:
        edges = cv2.GaussianBlur(edges, (0, 0), sigmaX=float(blur_sigma), borderType=border)
    out = normalise(edges)
    if not out.any():
        logger.debug("preprocess: featureless image of shape %s gives a zero pattern", img.shape)
    return out
