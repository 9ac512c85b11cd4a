"""Landmark detectors: is landmark L present in this camera image, as seen from viewframe V?

A detector looks only at the camera image and at what the candidate viewframe predicts: the
landmark's silhouette in the synthetic view (from the viewframe's landmark id mask) and the
synthetic image's edges around it. It never sees a truth pose.

:class:`EdgeTemplateDetector` is the detector for box-like landmarks. The synthetic images have
no trustworthy gray levels, so it works on edge magnitude: the template is the viewframe's edge
image inside the landmark's silhouette dilated by a few pixels (the outline and the box's own
edges), both edge images high-passed (a flat patch carries no evidence), searched in a window of
the camera's edge image around the expected place. The score at each offset is the energy-aware
correlation ``2 <T, W> / (|T|^2 + |W|^2)`` over the silhouette: unlike normalised
cross-correlation it does not reward a weak, noisy patch (an empty sky) whose shape happens to
align, because the camera's edge energy there must also match the template's. The answer is
*present* when the best score reaches ``threshold``, *absent* below ``absent_threshold``, and
*undecided* (``present=None``) in between or when the landmark covers too few pixels in the
viewframe for a template to mean anything. The default thresholds are the scenario schema's
(``scheduler.detector_threshold`` and ``scheduler.absent_threshold`` of
:class:`models.scenario.SchedulerSpec`), chosen with the scheduler on simulated frames of the
bundled scenarios with other seeds (BENCHMARKS.md): a false "absent" discards the right
viewframe, so "absent" is called only when the evidence is clearly missing.

Detectors are pluggable: anything with the :class:`LandmarkDetector` protocol can be registered
for a landmark kind in a :class:`DetectorRegistry`.

Images are ``(H, W)`` or ``(H, W, 3)`` arrays indexed ``(row, col)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import cv2
import numpy as np

from models.scenario import SchedulerSpec

__all__ = [
    "CandidateView",
    "Detection",
    "LandmarkDetector",
    "EdgeTemplateDetector",
    "DetectorRegistry",
    "default_registry",
    "edge_image",
]

#: the default thresholds: the scenario schema's ``scheduler`` settings
_DEFAULTS = SchedulerSpec()


@dataclass(frozen=True)
class CandidateView:
    """What a candidate viewframe predicts about one landmark.

    Attributes
    ----------
    image : ndarray of shape (H, W, 3) or (H, W)
        The synthetic viewframe image.
    silhouette : ndarray of shape (H, W), bool
        Pixels where the landmark is visible in the viewframe.
    """

    image: np.ndarray
    silhouette: np.ndarray

    @classmethod
    def from_mask(cls, image: np.ndarray, mask: np.ndarray, landmark_index: int) -> CandidateView:
        """Build from a viewframe's landmark id mask (``-1`` background, else landmark index)."""
        return cls(image, np.asarray(mask) == landmark_index)


@dataclass(frozen=True)
class Detection:
    """A detector's answer.

    ``present`` is ``True``, ``False`` or ``None`` (cannot tell); ``score`` in [-1, 1] is the
    best energy-aware correlation; ``location`` the ``(row, col)`` of the landmark's bounding-box top-left
    corner at the best match, ``None`` when not searched.
    """

    present: bool | None
    score: float
    location: tuple[int, int] | None = None
    reason: str = ""


@runtime_checkable
class LandmarkDetector(Protocol):
    """The contract of a landmark detector."""

    name: str

    def detect(self, image: np.ndarray, *, view: CandidateView) -> Detection:
        """Answer whether the landmark of ``view`` is present in camera ``image``."""
        ...


def edge_image(image: np.ndarray, *, axis: str = "both", blur_sigma: float = 1.0) -> np.ndarray:
    """Sobel gradient magnitude of a gray or RGB image, smoothed, scaled to [0, 1].

    ``axis``: ``"both"`` (magnitude), ``"x"`` (|d/dcol|, vertical edges) or ``"y"``.
    Returns ndarray of shape (H, W), float32.
    """
    if image.ndim == 3:
        gray = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    elif image.ndim == 2:
        gray = image
    else:
        raise ValueError(f"image must be (H, W) or (H, W, 3), not shape {image.shape}")
    gray = gray.astype(np.float32)
    if blur_sigma > 0:
        gray = cv2.GaussianBlur(gray, (0, 0), blur_sigma)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    if axis == "both":
        mag = cv2.magnitude(gx, gy)
    elif axis == "x":
        mag = np.abs(gx)
    elif axis == "y":
        mag = np.abs(gy)
    else:
        raise ValueError(f"axis must be 'both', 'x' or 'y', not {axis!r}")
    top = float(np.percentile(mag, 99.5)) or 1.0
    return np.clip(mag / top, 0.0, 1.0)


@dataclass
class EdgeTemplateDetector:
    """Masked edge-template matching around the expected place (see the module docstring).

    Parameters
    ----------
    name : str
    threshold : float
        Score at or above which the landmark is present (default: the scenario schema's
        ``scheduler.detector_threshold``).
    absent_threshold : float
        Score below which it is absent; in between, the answer is undecided (default:
        ``scheduler.absent_threshold``).
    search : int
        Half-size in pixels of the search window around the expected place, plus
        ``search_fraction`` of the image width.
    dilate : int
        Pixels by which the silhouette is grown to take in its outline.
    min_pixels : int
        Below this many silhouette pixels the answer is undecided.
    axis : str
        Edge orientation used: ``"both"``, or ``"x"`` for tall thin landmarks (towers, masts)
        whose evidence is their vertical edges.
    """

    name: str = "edge-template"
    threshold: float = _DEFAULTS.detector_threshold
    absent_threshold: float = _DEFAULTS.absent_threshold
    search: int = 6
    search_fraction: float = 0.06
    dilate: int = 2
    min_pixels: int = 24
    axis: str = "both"

    def detect(self, image: np.ndarray, *, view: CandidateView) -> Detection:
        sil = np.asarray(view.silhouette, bool)
        if sil.shape != image.shape[:2] or view.image.shape[:2] != image.shape[:2]:
            raise ValueError(
                f"image shape {image.shape[:2]} must equal the viewframe's {view.image.shape[:2]}"
            )
        n = int(sil.sum())
        if n < self.min_pixels:
            return Detection(None, 0.0, None, f"only {n} pixels in the viewframe (< {self.min_pixels})")
        h, w = sil.shape
        k = 2 * self.dilate + 1
        region = cv2.dilate(sil.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
        rows, cols = np.nonzero(region)
        r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
        template = _highpass(edge_image(view.image, axis=self.axis))[r0:r1, c0:c1]
        tmask = region[r0:r1, c0:c1].astype(np.float32)
        if float((template * tmask).std()) < 1e-6:
            return Detection(None, 0.0, None, "the viewframe shows no edges on the landmark")
        s = self.search + int(round(self.search_fraction * w))
        wr0, wr1 = max(0, r0 - s), min(h, r1 + s)
        wc0, wc1 = max(0, c0 - s), min(w, c1 + s)
        window = _highpass(edge_image(image, axis=self.axis))[wr0:wr1, wc0:wc1]
        weighted = template * tmask
        cross = cv2.matchTemplate(window, weighted, cv2.TM_CCORR)
        energy = cv2.matchTemplate(window * window, tmask, cv2.TM_CCORR)
        scores = 2.0 * cross / (float((weighted * weighted).sum()) + energy + 1e-12)
        idx = np.unravel_index(int(np.argmax(scores)), scores.shape)
        best = float(scores[idx])
        loc = (int(wr0 + idx[0]), int(wc0 + idx[1]))
        if best >= self.threshold:
            return Detection(True, best, loc, f"score {best:.3f} >= {self.threshold}")
        if best < self.absent_threshold:
            return Detection(False, best, loc, f"score {best:.3f} < {self.absent_threshold}")
        return Detection(None, best, loc, f"score {best:.3f} between {self.absent_threshold} and {self.threshold}")


def _highpass(edges: np.ndarray, *, sigma: float = 4.0) -> np.ndarray:
    """Edges minus their local mean: a flat patch correlates with nothing."""
    return edges - cv2.GaussianBlur(edges, (0, 0), sigma)


@dataclass
class DetectorRegistry:
    """Landmark kind -> detector; ``fallback`` serves kinds with no detector of their own."""

    detectors: dict[str, LandmarkDetector] = field(default_factory=dict)
    fallback: LandmarkDetector | None = None

    def register(self, kind: str, detector: LandmarkDetector) -> None:
        if not isinstance(detector, LandmarkDetector):
            raise TypeError(f"detector for kind {kind!r} does not implement LandmarkDetector")
        self.detectors[kind] = detector

    def for_kind(self, kind: str) -> LandmarkDetector:
        det = self.detectors.get(kind, self.fallback)
        if det is None:
            raise KeyError(f"no landmark detector for kind {kind!r}")
        return det

    @property
    def kinds(self) -> list[str]:
        return sorted(self.detectors)


def default_registry(
    *, threshold: float = _DEFAULTS.detector_threshold, absent_threshold: float = _DEFAULTS.absent_threshold
) -> DetectorRegistry:
    """Detectors for the bundled landmark kinds: houses and barns (wide boxes) by their outline,
    towers and silos (tall, narrow) by their vertical edges; any other kind by the box outline."""

    def detector(name: str, **options: Any) -> EdgeTemplateDetector:
        return EdgeTemplateDetector(name=name, threshold=threshold, absent_threshold=absent_threshold, **options)

    reg = DetectorRegistry(fallback=detector("box-outline"))
    reg.register("house", detector("house-outline"))
    reg.register("barn", detector("barn-outline"))
    reg.register("tower", detector("tower-vertical-edges", axis="x", min_pixels=12))
    reg.register("silo", detector("silo-vertical-edges", axis="x", min_pixels=12))
    return reg
