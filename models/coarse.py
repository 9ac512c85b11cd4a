"""Coarse first ranking stages: a compact comparison with every viewframe picks the candidates the
full shift-searched comparison of :mod:`models.associative` ranks.

:class:`MemoryCoarse` (wired into the associative indexer, ``memory.coarse_candidates``) is the
memory's own comparison at low resolution and over shifts: the similarity of the low-passed recall
with every prototype, on the few spectral bins the low-pass leaves, at a grid of lags over the
memory's shift window. Row h of a bank's ranking matrix is ``w FP_h conj(FM)``
(:mod:`models.associative`), and the similarity of a query of key spectrum FK at the lag d is
``Re sum_k row_h(k) FK(k) e^(2 pi i k.d / N)``; with the gaussian low-pass G of :data:`COARSE_SIGMA`
memory pixels::

    s_h(d) = Re sum_{|k_r|, k_c <= R} G(k) row_h(k) FK(k) e^(2 pi i k.d / N) / ||R_b(h)||

over the bins where G is above :data:`TRUNCATE` (R = 19 at N = 128 and sigma 4: 780 of the 8,320
bins, so a viewframe's coarse row is 6.2 KB against the ranking row's 66.5 KB), at the lags d of a
grid every :data:`COARSE_SHIFT_STEP` memory pixels over the memory's ``max_shift`` window (65 lags
at the default (8, 24)). The coarse score of a viewframe is the largest over the grid, its
candidates the ``k`` best. The full ranking's own preselection for its shift search (the best at
zero lag, sharp and low-passed) misses a frame's viewframe when the frame is a few pixels off it;
the grid does not, so among its candidates the shift search finds the truth more often than the
full ranking does (``bench/coarse.py``; BENCHMARKS.md, "Associative coarse stage").

:class:`CoarseIndex` is an earlier prototype (an unwhitened edge descriptor), kept for
``bench/coarse.py``'s comparison; on the evaluation set's held-out sweeps it kept the truth among
a third of the route for 89 % of the frames only.

The prototype's descriptor of an image is its edge image at ``size`` x ``size`` memory pixels,
blurred, not whitened (:func:`models.preprocess.preprocess` with ``whiten=False``): zero mean, unit energy,
(size * size,) float32. Two descriptors are compared by their cosine, maximised over circular
shifts of the query of up to ``max_shift`` columns (heading errors move the view sideways), so a
query costs one (H, size * size) x (size * size, 2 * max_shift + 1) product: a few million
multiply-adds at 10,000 viewframes, against the full ranking's (H, 2 N (N/2 + 1)) with its shift
search. The prototype is not wired into the indexer agent.

    coarse = CoarseIndex()
    coarse.add(images, viewframes)
    candidates = coarse.candidates(camera_image, k=200)   # viewframe indices, best first
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from models.associative import BankedMemory
from models.preprocess import preprocess

__all__ = ["CoarseIndex", "MemoryCoarse", "TRUNCATE", "COARSE_SIGMA", "COARSE_SHIFT_STEP"]

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


#: spectral bins whose low-pass gain is below this are left out of the coarse rows
TRUNCATE = 1e-3
#: the coarse stage's low-pass (memory pixels) and shift grid (every this many memory pixels,
#: rows and cols, within the memory's max_shift): chosen on the evaluation set's tuning split
#: (``bench/coarse.py --memory tuning``; BENCHMARKS.md, "Associative coarse stage")
COARSE_SIGMA = 4.0
COARSE_SHIFT_STEP = (4, 4)


def _grid(limit: int, step: int) -> NDArray[np.int64]:
    """Lags -limit..limit every ``step`` from 0, with the two ends (sorted)."""
    half = np.arange(0, limit + 1, max(1, step))
    return np.unique(np.concatenate([half, -half, [limit, -limit]]))


class MemoryCoarse:
    """The coarse stage of a :class:`~models.associative.BankedMemory`'s ranking (module
    docstring): its rows are made once from the memory's ranking rows (a stored index's are read
    once, memory-mapped, ``block`` rows at a time); :meth:`candidates` gives a query's ``k`` best.

    ``sigma``: the low-pass (memory pixels); ``step``: the shift grid's spacing (rows, cols).
    Scores are comparable across the memory's banks (each row divided by its bank's recall
    energy), not across memories. A query's similarities at the grid's lags are two small
    complex products (separable: the row lags over the kept rows of the spectrum, then the column
    lags over its columns), about 3 million multiply-adds at 512 viewframes.
    """

    def __init__(
        self,
        memory: BankedMemory,
        *,
        sigma: float = COARSE_SIGMA,
        step: tuple[int, int] = COARSE_SHIFT_STEP,
        block: int = 512,
    ) -> None:
        if not sigma > 0:
            raise ValueError(f"sigma must be > 0, got {sigma}")
        if min(step) < 1:
            raise ValueError(f"step must be >= 1, got {step}")
        n = memory.size
        half = n // 2 + 1
        radius = int(np.ceil(n * np.sqrt(np.log(1.0 / TRUNCATE) / 2.0) / (np.pi * sigma)))
        radius = max(1, min(radius, n // 2 - 1))
        kr = np.r_[np.arange(n - radius, n), np.arange(0, radius + 1)]  # signed -R..R, as bins mod N
        kc = np.arange(0, min(radius, half - 1) + 1)
        signed_r = np.where(kr > n // 2, kr - n, kr)
        self.size, self.sigma, self.step = n, float(sigma), (int(step[0]), int(step[1]))
        self.radius = radius
        rows_lag, cols_lag = _grid(memory.max_shift[0], step[0]), _grid(memory.max_shift[1], step[1])
        lag_r, lag_c = np.meshgrid(rows_lag, cols_lag, indexing="ij")
        #: (S, 2) the grid's lags (rows, cols), row lag major
        self.lags = np.stack([lag_r.ravel(), lag_c.ravel()], axis=1)
        # e^(2 pi i k d / N), separately for the rows' and the columns' frequencies and lags
        self._er = np.exp(2j * np.pi * signed_r[:, None] * rows_lag[None, :] / n).astype(np.complex64)  # (nr, Lr)
        self._ec = np.exp(2j * np.pi * kc[:, None] * cols_lag[None, :] / n).astype(np.complex64)  # (nc, Lc)
        f2 = (signed_r[None, :] / n) ** 2 + (kc[:, None] / n) ** 2  # (nc, nr)
        gain = np.exp(-2.0 * np.pi**2 * sigma * sigma * f2)
        self._bins = (kr[None, :] * half + kc[:, None]).ravel()  # (nc * nr,) column-major: kc, then kr
        matrix = memory.ranking_matrix
        #: (H,) viewframes in storage order, as the ranking matrix's rows
        self.viewframes = memory.row_viewframes
        if memory.compact:
            energy = np.asarray(memory._bank_energy, dtype=np.float64)
        else:  # |FK| is flat but at DC: the recall energy is proportional to sqrt(sum w |FM_b|^2)
            energy = np.sqrt(np.maximum(np.asarray(memory._bank_power, dtype=np.float64).sum(axis=1), 0.0))
        inv = np.where(energy > 1e-12, 1.0 / np.maximum(energy, 1e-300), 0.0)
        row_scale = inv[memory._row_bank] if memory._row_bank is not None else np.zeros(0)
        h = len(self.viewframes)
        rows = np.empty((h, kc.size, kr.size), dtype=np.complex64)
        for i in range(0, h, max(1, block)):
            part = np.asarray(matrix[i : i + block]).view(np.complex64)[:, self._bins]
            rows[i : i + block] = (part * row_scale[i : i + block, None]).reshape(-1, kc.size, kr.size) * gain[None]
        self._rows = rows

    def __len__(self) -> int:
        return int(self.viewframes.size)

    @property
    def nbytes(self) -> int:
        """Bytes of the coarse rows."""
        return int(self._rows.nbytes)

    def scores(self, key: NDArray[np.complexfloating]) -> NDArray[np.float64]:
        """(H,) each viewframe's coarse score (storage order) for a query of key spectrum ``key``
        (:meth:`models.associative.HolographicMemory.query_key`, (N, N // 2 + 1)): the low-passed
        similarity at the best lag of the grid, up to a factor common to all rows."""
        h, nc, nr = self._rows.shape
        if not h:
            return np.zeros(0, np.float64)
        q = np.asarray(key).reshape(-1)[self._bins].astype(np.complex64).reshape(nc, nr)
        a = (self._rows * q[None]).reshape(h * nc, nr) @ self._er  # (H nc, Lr): the row lags
        lr = self._er.shape[1]
        b = np.ascontiguousarray(a.reshape(h, nc, lr).transpose(0, 2, 1)).reshape(h * lr, nc) @ self._ec  # (H Lr, Lc)
        return b.real.reshape(h, -1).max(axis=1).astype(np.float64)

    def candidates(self, key: NDArray[np.complexfloating], *, k: int) -> NDArray[np.int64]:
        """The viewframes of the ``k`` best coarse scores (all when fewer), best first (ties: storage order)."""
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        c = self.scores(key)
        top = np.arange(c.size) if k >= c.size else np.argpartition(-c, k - 1)[:k]
        return self.viewframes[top[np.lexsort((top, -c[top]))]]
