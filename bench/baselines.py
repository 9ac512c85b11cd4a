"""Baselines for the associative indexer, with the same inputs and output as the memory.

Every index takes raw images (``(H, W)`` or ``(H, W, 3)`` uint8) with integer labels through
``store(images, labels)`` and answers ``rank(image) -> ndarray (H,) int64`` of labels, best
first. ``HolographicIndex`` wraps :class:`models.associative.BankedMemory` the same way.

* :class:`NCCIndex`: direct normalised cross-correlation (zero lag) of the *preprocessed*
  images (same :func:`models.preprocess.preprocess` as the memory) against every prototype; the
  patterns are zero mean and unit energy, so NCC is one float32 matrix-vector product.
* :class:`OrbBowIndex`: ORB features (OpenCV) on the gray image, a visual vocabulary by
  k-means over a seeded sample of the stored descriptors (k-means on the 256 bits as 0/1
  floats; Hamming k-medoids would be the textbook choice, k-means on bits is the usual cheap
  stand-in), tf-idf weighted, L2-normalised word histograms, ranked by cosine.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from models.associative import BankedMemory
from models.preprocess import preprocess
from models.scenario import MemorySpec

__all__ = ["HolographicIndex", "NCCIndex", "OrbBowIndex"]

logger = logging.getLogger(__name__)

#: the shipped memory and preprocessing defaults
_DEFAULTS = MemorySpec()


def _gray_u8(image: NDArray) -> NDArray[np.uint8]:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img[:, :, :3].astype(np.uint8), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(img, dtype=np.uint8)


class HolographicIndex:
    """The holographic memory behind the baselines' interface."""

    name = "memory"

    def __init__(
        self,
        size: int = _DEFAULTS.size,
        *,
        blur_sigma: float = _DEFAULTS.blur_sigma,
        bank_size: int = _DEFAULTS.bank_size,
        max_shift: tuple[int, int] = _DEFAULTS.max_shift,
        seed: int = 0,
    ) -> None:
        self.size, self.blur_sigma = size, blur_sigma
        self.memory = BankedMemory(size, bank_size=bank_size, seed=seed, max_shift=max_shift)

    def pattern(self, image: NDArray) -> NDArray[np.float32]:
        return preprocess(image, size=self.size, blur_sigma=self.blur_sigma)

    def store(self, images: Sequence[NDArray], labels: Sequence[int]) -> None:
        self.memory.write_many([self.pattern(im) for im in images], labels)

    def rank_pattern(self, pattern: NDArray[np.float32]) -> NDArray[np.int64]:
        return self.memory.rank(pattern).viewframes

    def rank(self, image: NDArray) -> NDArray[np.int64]:
        return self.rank_pattern(self.pattern(image))


class NCCIndex:
    """Zero-lag normalised cross-correlation of preprocessed images."""

    name = "ncc"

    def __init__(self, size: int = _DEFAULTS.size, *, blur_sigma: float = _DEFAULTS.blur_sigma) -> None:
        self.size, self.blur_sigma = size, blur_sigma
        self.matrix = np.zeros((0, size * size), np.float32)
        self.labels = np.zeros(0, np.int64)

    def pattern(self, image: NDArray) -> NDArray[np.float32]:
        return preprocess(image, size=self.size, blur_sigma=self.blur_sigma)

    def store(self, images: Sequence[NDArray], labels: Sequence[int]) -> None:
        self.matrix = np.ascontiguousarray(np.stack([self.pattern(im).reshape(-1) for im in images]))
        self.labels = np.asarray(labels, dtype=np.int64)

    def rank_pattern(self, pattern: NDArray[np.float32]) -> NDArray[np.int64]:
        scores = self.matrix @ pattern.reshape(-1)
        return self.labels[np.argsort(-scores, kind="stable")]

    def rank(self, image: NDArray) -> NDArray[np.int64]:
        return self.rank_pattern(self.pattern(image))


class OrbBowIndex:
    """ORB bag of visual words with tf-idf and cosine ranking."""

    name = "orb-bovw"

    def __init__(self, *, words: int = 256, features: int = 300, sample: int = 20000, seed: int = 0) -> None:
        self.words, self.sample, self.seed = words, sample, seed
        self.orb = cv2.ORB_create(nfeatures=features, edgeThreshold=15, patchSize=15, fastThreshold=10)
        self.centres = np.zeros((0, 256), np.float32)
        self.idf = np.zeros(0, np.float32)
        self.hists = np.zeros((0, 0), np.float32)
        self.labels = np.zeros(0, np.int64)

    def _descriptors(self, image: NDArray) -> NDArray[np.float32]:
        _, desc = self.orb.detectAndCompute(_gray_u8(image), None)
        if desc is None:
            return np.zeros((0, 256), np.float32)
        return np.unpackbits(desc, axis=1).astype(np.float32)

    def _words(self, bits: NDArray[np.float32]) -> NDArray[np.int64]:
        # nearest centre by squared distance: |c|^2 - 2 b.c (|b|^2 is constant per row)
        d = (self.centres * self.centres).sum(1)[None, :] - 2.0 * bits @ self.centres.T
        return np.argmin(d, axis=1)

    def _hist(self, bits: NDArray[np.float32]) -> NDArray[np.float32]:
        h = (
            np.bincount(self._words(bits), minlength=self.words).astype(np.float32)
            if len(bits)
            else np.zeros(self.words, np.float32)
        )
        return h

    def store(self, images: Sequence[NDArray], labels: Sequence[int]) -> None:
        descs = [self._descriptors(im) for im in images]
        allbits = np.concatenate([d for d in descs if len(d)] or [np.zeros((0, 256), np.float32)])
        if len(allbits) < self.words:
            raise ValueError(f"images: only {len(allbits)} ORB descriptors, need >= words={self.words}")
        rng = np.random.default_rng(self.seed)
        sample = allbits[rng.choice(len(allbits), size=min(self.sample, len(allbits)), replace=False)]
        cv2.setRNGSeed(self.seed)
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 15, 0.5)
        _, _, centres = cv2.kmeans(sample, self.words, None, criteria, 1, cv2.KMEANS_PP_CENTERS)
        self.centres = centres.astype(np.float32)
        tf = np.stack([self._hist(d) for d in descs])
        df = (tf > 0).sum(0)
        self.idf = np.log((1.0 + len(descs)) / (1.0 + df)).astype(np.float32) + 1.0
        w = tf * self.idf
        self.hists = np.ascontiguousarray(w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-12))
        self.labels = np.asarray(labels, dtype=np.int64)

    def rank(self, image: NDArray) -> NDArray[np.int64]:
        w = self._hist(self._descriptors(image)) * self.idf
        w /= max(float(np.linalg.norm(w)), 1e-12)
        return self.labels[np.argsort(-(self.hists @ w), kind="stable")]
