"""The viewframe index: preprocessing, K-GEN keys, storage and ranking with one memory setting.

Every place that stores viewframes and ranks camera images against them (the associative indexer
agent, ``mapinterp table``, the report's edge images, ``bench/`` and ``bench/tuning/``) goes
through a :class:`ViewframeIndex`, built from a scenario's ``memory`` settings
(:class:`models.scenario.MemorySpec`, or the same settings as plain data, as the ``map``
hypothesis carries them). So the viewframes and the camera images of a mission are always
preprocessed alike, and the memory always has the scenario's size, bank size, key method and
shift search::

    image (H, W[, 3]) --preprocess(size, edge, blur_sigma, whiten)--> pattern (N, N)
    pattern --K-GEN(key)--> key;  M_b := M_b + K * P   (banks of bank_size viewframes)
    camera image --same preprocessing--> ranking of every stored viewframe by error variance

The pipeline's parts are :mod:`models.preprocess`, :mod:`models.memory_keys` and
:mod:`models.associative`; this module only puts them together, once. Images are indexed
(row, col); viewframes are identified by their viewframe index (the route point's number).
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Hashable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import ValidationError

from models.associative import BankedMemory, Ranking, merge_rankings, reliability
from models.errors import AssociativeMemoryError
from models.preprocess import preprocess
from models.scenario import MemorySpec

__all__ = [
    "WINDOW_TAIL",
    "track_window",
    "widen_window",
    "TrackWindows",
    "ViewframeIndex",
    "best_of_rankings",
    "memory_settings",
]

log = logging.getLogger(__name__)


def memory_settings(memory: MemorySpec | Mapping[str, Any] | None) -> MemorySpec:
    """``memory`` as a validated :class:`MemorySpec`: a spec, plain data (``MemorySpec.model_dump()``,
    the ``map`` hypothesis' ``memory``; missing fields take the defaults), or None for the defaults.

    Raises :class:`AssociativeMemoryError` naming the field of malformed settings.
    """
    if isinstance(memory, MemorySpec):
        return memory
    if memory is None:
        return MemorySpec()
    try:
        return MemorySpec.model_validate(dict(memory))
    except (TypeError, ValueError, ValidationError) as err:
        if isinstance(err, ValidationError):
            first = err.errors()[0]
            where = ".".join(str(p) for p in first["loc"]) or "memory"
            raise AssociativeMemoryError(f"memory settings: {where}: {first['msg']}") from None
        raise AssociativeMemoryError(f"memory settings: malformed: {err}") from None


#: the predicted probability a track window may leave out (half at each end)
WINDOW_TAIL = 1e-3


def track_window(
    prior: ArrayLike, *, margin: int, tail: float = WINDOW_TAIL, widest: float = 0.5
) -> tuple[int, int] | None:
    """The route points ``(first, last)`` (inclusive) to rank for a frame given the tracker's
    predicted probability of each route point ``prior`` (N,): the interval holding all but
    ``tail`` of the mass (``tail / 2`` left out at each end), widened by ``margin`` points on
    each side and clipped to the route; None (rank everything) when that covers ``widest`` of
    the route or more (default half), or when ``prior`` has no mass. The tracker computes it
    from its prediction without the kidnap part (:class:`knowledge_sources.levels.Track`'s
    ``window_next``): the kidnap probability, even over the route, would widen any window to
    nearly the whole route.
    """
    p = np.asarray(prior, dtype=np.float64).ravel()
    if margin < 0:
        raise ValueError(f"margin must be >= 0, got {margin}")
    if not 0 <= tail < 1:
        raise ValueError(f"tail must be in [0, 1), got {tail}")
    p = np.where(np.isfinite(p) & (p > 0), p, 0.0)
    total = float(p.sum())
    if p.size == 0 or total <= 0:
        return None
    cdf = np.cumsum(p) / total
    first = int(np.searchsorted(cdf, tail / 2, side="right"))
    last = int(np.searchsorted(cdf, 1.0 - tail / 2, side="left"))
    first, last = max(0, first - margin), min(p.size - 1, max(first, last) + margin)
    if last - first + 1 >= widest * p.size:
        return None
    return first, last


def widen_window(window: Sequence[int] | None, *, margin: int, points: int) -> tuple[int, int] | None:
    """A window ``(first, last)`` widened by ``margin`` points on each side and clipped to a route
    of ``points``; None (rank everything) when it is None or covers half the route or more."""
    if window is None:
        return None
    first, last = max(0, int(window[0]) - margin), min(points - 1, int(window[1]) + margin)
    if last < first or 2 * (last - first + 1) >= points:
        return None
    return first, last


class TrackWindows:
    """The track window rule of :class:`~models.scenario.MemorySpec` for one ranking agent: keeps
    the latest tracks as they are posted and says which route points to rank for each frame.

    ``settings``: the memory settings (``window_route_points``, ``window_margin``,
    ``window_full_every``); ``viewframes``: the route's points; ``tracked``: a tracker runs.
    Without a tracker, or on a route shorter than ``window_route_points``, every frame ranks
    everything. The associative indexers and the skyline ranker use the same rule, so for a
    frame they rank the same route points.
    """

    #: tracks older than this many frames before the newest are dropped
    KEEP = 8

    def __init__(self, settings: MemorySpec, *, viewframes: int, tracked: bool) -> None:
        self.enabled = bool(
            tracked and settings.window_route_points is not None and viewframes >= settings.window_route_points
        )
        self.points = int(viewframes)
        self.margin = settings.window_margin
        self.full_every = settings.window_full_every
        self._tracks: dict[int, tuple[str, tuple[int, int] | None]] = {}

    def add(self, frame: int, state: str, window_next: Sequence[int] | None) -> None:
        """The track of ``frame``: its ``state`` and the route points ``[first, last]`` its motion
        predicts for the next frame (the Track's ``window_next``; None: no such window)."""
        self._tracks[frame] = (state, None if window_next is None else (int(window_next[0]), int(window_next[1])))
        for old in [f for f in self._tracks if f < frame - self.KEEP]:
            del self._tracks[old]  # only the latest tracks can still be the previous frame's

    def has(self, frame: int) -> bool:
        """The track of ``frame`` is held (in any state)."""
        return frame in self._tracks

    def window(self, frame: int) -> tuple[int, int] | None:
        """The route points ``(first, last)`` to rank for ``frame``, or None: all of them (frame 0,
        every ``full_every``-th frame, no track of the frame before yet, that track lost or without
        a window, the window with its margin half the route or more)."""
        if not self.enabled or frame <= 0 or frame % self.full_every == 0:
            return None
        track = self._tracks.get(frame - 1)
        if track is None or track[0] != "tracking":
            return None
        return widen_window(track[1], margin=self.margin, points=self.points)


def best_of_rankings(rankings: Sequence[Ranking]) -> Ranking:
    """One ranking of the same viewframes ranked several times (the roll search's queries): each
    viewframe's smallest variance of them, best first; the reliability recomputed over those
    (:func:`models.associative.reliability`). A viewframe ranked in only some of them keeps the
    smallest of those."""
    if not rankings:
        return merge_rankings([])
    vf = np.concatenate([r.viewframes for r in rankings])
    var = np.concatenate([r.variances for r in rankings])
    order = np.lexsort((var, vf))  # by viewframe, then variance: the first of each viewframe is its best
    vf, var = vf[order], var[order]
    first = np.ones(vf.size, dtype=bool)
    first[1:] = vf[1:] != vf[:-1]
    vf, var = vf[first], var[first]
    best = np.lexsort((vf, var))  # the merged ranking's order: variance, then viewframe
    return Ranking(vf[best], var[best], reliability(var))


class ViewframeIndex:
    """Viewframes stored in a banked holographic memory, ranked for camera images.

    Parameters
    ----------
    memory : MemorySpec, mapping or None
        The memory settings (see :func:`memory_settings`); None: the defaults.
    seed : int
        Seed of the keys' random phase (:func:`models.memory_keys.make_key`).
    compact : bool
        Banks keep only their ranking rows (:class:`~models.associative.BankedMemory`'s
        ``compact``: a third of the bytes, the same rankings); False keeps the whole memory
        (recall, prototypes, state). Default True.

    Example::

        index = ViewframeIndex(scenario.memory)
        index.add([vf.image for vf in viewframes], [vf.index for vf in viewframes])
        ranking = index.rank(frame.image)   # Ranking.viewframes, best first
    """

    def __init__(
        self, memory: MemorySpec | Mapping[str, Any] | None = None, *, seed: int = 0, compact: bool = True
    ) -> None:
        self.settings = memory_settings(memory)
        s = self.settings
        self.memory = BankedMemory(
            s.size, bank_size=s.bank_size, seed=seed, key_method=s.key, max_shift=s.max_shift, compact=compact
        )
        #: viewframes not stored because their pattern is featureless (a constant image: e.g. a
        #: camera inside a landmark, or facing the sky): they have nothing to match, so they are
        #: left out of every ranking rather than failing the index
        self.featureless: list[int] = []
        self._viewframes: NDArray[np.int64] | None = None  # storage order, made on demand (reset by a write)

    def __len__(self) -> int:
        return len(self.memory)

    @property
    def viewframes(self) -> NDArray[np.int64]:
        """Viewframe indices in storage order, shape (H,) (read only; made once after each :meth:`add`)."""
        if self._viewframes is None:
            banks = self.memory.banks
            self._viewframes = np.concatenate([b.viewframes for b in banks]) if banks else np.zeros(0, np.int64)
            self._viewframes.setflags(write=False)
        return self._viewframes

    def pattern(self, image: ArrayLike) -> NDArray[np.float32]:
        """The memory pattern of an image (viewframe or camera frame): (N, N) float32, zero mean,
        unit energy (:func:`models.preprocess.preprocess` with this index's settings)."""
        s = self.settings
        return preprocess(image, size=s.size, edge=s.edge, blur_sigma=s.blur_sigma, whiten=s.whiten)

    def query_pattern(
        self, image: ArrayLike, *, roll: float = 0.0, digest: Hashable | None = None
    ) -> NDArray[np.float32]:
        """The :meth:`pattern` of a camera image (H, W[, C], indexed (row, col)) turned by ``roll``
        degrees (:func:`models.derotate.rolled`; 0: as it is), read only: made once per process
        for all the indices with this preprocessing (:data:`models.query_patterns.SHARED`, keyed
        by the image's bytes), so the shards of a process ranking one frame share it.
        ``digest``: :func:`models.query_patterns.image_digest` of ``image``, when the caller has it."""
        from models.derotate import rolled
        from models.query_patterns import SHARED

        img = np.asarray(image)
        key = ("pattern", *self._preprocessing, float(roll))
        return SHARED.get(img, key=key, make=lambda: self.pattern(rolled(img, roll)), digest=digest)

    def query_key(
        self, image: ArrayLike, *, roll: float = 0.0, digest: Hashable | None = None
    ) -> NDArray[np.complex128]:
        """The memory's key spectrum (N, N // 2 + 1) of :meth:`query_pattern`, its seed's: the
        same numbers as ``memory.banks[0].query_key(query_pattern(image, roll=roll))``, from the
        key's seed-independent part (:meth:`models.associative.HolographicMemory.query_phase`)
        made once per process for all the indices with this preprocessing and key method. The
        index must hold a viewframe."""
        from models.query_patterns import SHARED, image_digest

        if not self.memory.banks:
            raise AssociativeMemoryError("query_key: the index holds no viewframe")
        img = np.asarray(image)
        ident = image_digest(img) if digest is None else digest
        bank = self.memory.banks[0]

        def make() -> NDArray[np.complex128]:
            phase = bank.query_phase(self.query_pattern(img, roll=roll, digest=ident))
            return np.zeros(0, np.complex128) if phase is None else phase  # empty: a featureless pattern

        phase = SHARED.get(
            img, key=("phase", *self._preprocessing, self.settings.key, float(roll)), make=make, digest=ident
        )
        return bank.key_of_phase(phase if phase.size else None)

    @property
    def _preprocessing(self) -> tuple[int, str, float, bool]:
        s = self.settings
        return (s.size, s.edge, float(s.blur_sigma), bool(s.whiten))

    def add(self, images: Iterable[ArrayLike], viewframes: Iterable[int]) -> None:
        """Preprocess and store viewframe images under their viewframe indices."""
        self.add_patterns((self.pattern(im) for im in images), viewframes)

    def add_patterns(self, patterns: Iterable[ArrayLike], viewframes: Iterable[int]) -> None:
        """Store patterns already made by :meth:`pattern` (e.g. shared by several indices); a
        featureless (all-zero) pattern is not stored, its viewframe is listed in :attr:`featureless`
        (with a warning) and never ranked."""

        vfs = [int(v) for v in viewframes]
        self._viewframes = None
        self.memory.reserve(len(self.memory) + len(vfs))
        source = iter(patterns)
        step = self.memory.bank_size  # a bank's worth at a time: the patterns are never all in memory
        for i in range(0, len(vfs), step):
            ids = vfs[i : i + step]
            pats = list(itertools.islice(source, len(ids)))
            if len(pats) < len(ids):
                raise AssociativeMemoryError(f"write: {i + len(pats)} patterns but {len(vfs)} viewframes")
            keep = [j for j, p in enumerate(pats) if np.any(p)]
            for j in sorted(set(range(len(ids))) - set(keep)):
                self.featureless.append(ids[j])
                log.warning("viewframe %d: featureless (constant) image, not stored in the index", ids[j])
            self.memory.write_many([pats[j] for j in keep], [ids[j] for j in keep])
        if next(source, None) is not None:
            raise AssociativeMemoryError(f"write: more patterns than the {len(vfs)} viewframes")

    def rank(self, image: ArrayLike, *, among: ArrayLike | None = None, pattern: ArrayLike | None = None) -> Ranking:
        """Every stored viewframe (or those ``among`` the viewframe indices given:
        :meth:`models.associative.BankedMemory.rank`) ordered by the error variance of
        ``image``'s recall, best first. ``among`` naming none of the stored viewframes: the empty
        ranking, without preprocessing the image (a shard outside a track window). ``pattern``:
        ``image``'s own :meth:`pattern`, when the caller made it already (not made again). The
        patterns and keys of the (turned) image come from :meth:`query_pattern` and
        :meth:`query_key`: made once per process for every index with the same preprocessing.

        The roll search (``roll_search_deg`` of the settings): ``image`` (H, W[, C], indexed
        (row, col)) is ranked turned by each of those rolls about its centre
        (:func:`models.derotate.rolled`), and each viewframe keeps its smallest error variance
        of them (:func:`best_of_rankings`); the variances stay those of one recall, comparable
        across banks and shards. With ``roll_shortlist`` K the turned images are ranked only among
        the first match's best K (the match at roll 0 when it is searched; the others keep its
        variance)."""
        from models.query_patterns import image_digest

        if among is not None and not np.isin(np.asarray(among, dtype=np.int64).ravel(), self.viewframes).any():
            return merge_rankings([])
        if not self.memory.banks:
            return merge_rankings([])
        img = np.asarray(image)
        ident = image_digest(img)  # once: each turned query is looked up by it

        def one(roll: float) -> tuple[ArrayLike, NDArray[np.complex128]]:
            if roll == 0.0 and pattern is not None:  # the caller's pattern of the image as it is: its own key
                return pattern, self.memory.banks[0].query_key(pattern)
            return self.query_pattern(img, roll=roll, digest=ident), self.query_key(img, roll=roll, digest=ident)

        def query(rolls: Sequence[float]) -> dict[str, Any]:
            made = [one(a) for a in rolls]
            return {"patterns": [p for p, _ in made], "keys": [k for _, k in made]}

        rolls = tuple(self.settings.roll_search_deg)
        if rolls == (0.0,):
            return self.memory.rank_many(**query(rolls), among=among)[0]
        k = self.settings.roll_shortlist
        first = 0.0 if 0.0 in rolls else rolls[0]  # the plain match, when it is searched
        turned = tuple(a for a in rolls if a != first)
        if k is None:  # every query among the same rows: picked once
            return best_of_rankings(self.memory.rank_many(**query((first, *turned)), among=among))
        plain = self.memory.rank_many(**query((first,)), among=among)[0]
        return best_of_rankings([plain, *self.memory.rank_many(**query(turned), among=plain.viewframes[:k])])

    def rank_pattern(self, pattern: ArrayLike, *, among: ArrayLike | None = None) -> Ranking:
        """:meth:`rank` of a pattern already made by :meth:`pattern`."""
        return self.memory.rank(pattern, among=among)
