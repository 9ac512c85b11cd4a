"""A coarse first ranking stage: a compact global descriptor per viewframe, compared with all, picks
a few hundred candidates for the full shift-searched comparison of :mod:`models.associative`.

The descriptor of an image is its edge image at ``size`` x ``size`` memory pixels, blurred, not
whitened (:func:`models.preprocess.preprocess` with ``whiten=False``): zero mean, unit energy,
(size * size,) float32. Two descriptors are compared by their cosine, maximised over circular
shifts of the query of up to ``max_shift`` columns (heading errors move the view sideways), so a
query costs one (H, size * size) x (size * size, 2 * max_shift + 1) product: a few million
multiply-adds at 10,000 viewframes, against the full ranking's (H, 2 N (N/2 + 1)) with its shift
search. This is a prototype beside :class:`~models.index.ViewframeIndex`, not yet wired into the
indexer agent.

    coarse = CoarseIndex()
    coarse.add(images, viewframes)
    candidates = coarse.candidates(camera_image, k=200)   # viewframe indices, best first
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from models.preprocess import preprocess

__all__ = ["CoarseIndex"]

#: descriptor side (memory pixels), blur and column shift search of the coarse stage
COARSE_SIZE = 32
COARSE_BLUR_SIGMA = 1.0
COARSE_MAX_SHIFT = 4


class CoarseIndex:
    """Descriptors of stored viewframes, and the candidates of a query (module docstring)."""

    def __init__(
        self,
        *,
        size: int = COARSE_SIZE,
        blur_sigma: float = COARSE_BLUR_SIGMA,
        max_shift: int = COARSE_MAX_SHIFT,
        edge: str = "sobel",
    ) -> None:
        if size < 4:
            raise ValueError(f"size must be >= 4, got {size}")
        if not 0 <= max_shift < size:
            raise ValueError(f"max_shift must be in 0..size-1, got {max_shift}")
        self.size, self.blur_sigma, self.max_shift, self.edge = int(size), float(blur_sigma), int(max_shift), edge
        self._rows: list[NDArray[np.float32]] = []
        self._ids: list[int] = []
        self._matrix: NDArray[np.float32] | None = None

    def __len__(self) -> int:
        return len(self._ids)

    def descriptor(self, image: ArrayLike) -> NDArray[np.float32]:
        """The (size, size) descriptor of an image (H, W[, 3]), zero mean, unit energy."""
        return preprocess(image, size=self.size, edge=self.edge, blur_sigma=self.blur_sigma, whiten=False)

    def add(self, images: Iterable[ArrayLike], viewframes: Iterable[int]) -> None:
        """Store the descriptors of viewframe images under their viewframe indices."""
        for image, vf in zip(images, viewframes, strict=True):
            self._rows.append(self.descriptor(image).ravel())
            self._ids.append(int(vf))
        self._matrix = None

    @property
    def nbytes(self) -> int:
        """Bytes of the stored descriptors."""
        return sum(r.nbytes for r in self._rows)

    def scores(self, image: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """(viewframes, cosine maximised over the column shifts), in storage order."""
        if self._matrix is None:
            self._matrix = np.stack(self._rows) if self._rows else np.zeros((0, self.size * self.size), np.float32)
        q = self.descriptor(image)
        shifts = np.stack([np.roll(q, s, axis=1).ravel() for s in range(-self.max_shift, self.max_shift + 1)], axis=1)
        c = (self._matrix @ shifts).max(axis=1) if len(self) else np.zeros(0, np.float32)
        return np.asarray(self._ids, dtype=np.int64), c.astype(np.float64)

    def candidates(self, image: ArrayLike, *, k: int) -> NDArray[np.int64]:
        """The ``k`` viewframes most like ``image`` (all of them when fewer), best first."""
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        ids, c = self.scores(image)
        k = min(k, ids.size)
        top = np.argpartition(-c, k - 1)[:k] if k < ids.size else np.arange(ids.size)
        return ids[top[np.argsort(-c[top], kind="stable")]]
