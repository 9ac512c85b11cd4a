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
viewframe for a template to mean anything. A false "absent" discarded the right viewframe under
the seed paper's hard backtracking, so "absent" is called only when the evidence is clearly
missing. The default thresholds are the scenario schema's (``scheduler.detector_threshold`` and
``scheduler.absent_threshold`` of :class:`models.scenario.SchedulerSpec`), chosen with the
scheduler on simulated frames of the bundled scenarios with other seeds (BENCHMARKS.md).

The likelihood ratio
    Beside the three-way answer the detector reports ``llr``, the log of the likelihood ratio
    p(camera image | landmark there) / p(camera image | landmark not there). It compares the
    camera image with the viewframe *with* the landmark and *without* it: the camera emulator
    renders every viewframe once without landmark boxes
    (:meth:`models.camera.CameraEmulator.render_background`), and the "without" view is the
    viewframe with the landmark's silhouette filled from it (:class:`CandidateView`'s
    ``without``). Both are matched against the camera image with an alignment search that
    covers the pose errors (:func:`align_pixels`; :meth:`EdgeTemplateDetector.evidence` says
    how), and the evidence is turned into a log-likelihood ratio by a logistic
    :class:`Calibration` fitted on labelled frames of the evaluation set's tuning split
    (bench/tuning/calibrate_detectors.py; its coefficients are the scenario schema's
    ``scheduler.calibration`` defaults: one calibration for every kind, ``"any"``, which did
    better with a tuning case left out than one per detector family or per kind).

    The rule, in full: for the landmark's silhouette ``M`` in the candidate viewframe (at least
    ``min_pixels`` pixels, else no ratio), and with the search ``(sr, sc) = align_px + (h / 4,
    w / 2)`` for a silhouette box of ``h`` x ``w`` pixels (pose errors plus parallax),

    - ``statistic``: the chromaticity with/without generalised likelihood ratio over ``M``,
      each hypothesis at its best shift within the search and template scale of ``scales``
      (about the silhouette's centre; a position error along the route makes a near landmark
      larger or smaller: the scenario schema's ``scheduler.detector_scales``);
    - ``orientation``: the best energy-aware correlation of the viewframe's edge *directions*
      inside ``M`` (dilated) with the camera image's (:func:`orientation_field`: each edge's
      direction, polarity-free, soft-normalised so that a clear edge counts whatever its
      contrast), over the same shifts and scales; ``vertical``: the same with the vertical
      edges alone (the walls every renderer draws; their distance is the landmark's width);
    - ``contrast``: the best silhouette-against-ring contrast of the camera image over the
      same shifts and scales, less that of the view without the landmark;
    - ``context``: the same edge-direction correlation over a ring around the silhouette at the
      ``orientation`` match's shift and scale (the landmark's surroundings: a landmark of the
      same kind elsewhere seldom stands against the candidate's terrain and sky);
    - ``llr = bias + w . (statistic, orientation, vertical, contrast, context)``, the calibration's.
      Edge directions took the place of session 4's edge *magnitude* score (``score``, still the
      three-way answer's): renderers disagree on how strong an edge is (a wall in shadow, a red
      box against a beige wall under a roof), far less on where and which way it runs
      (BENCHMARKS.md, session 9). The scheduler's ``soft`` backtracking multiplies the
    candidates' likelihoods by it (:mod:`knowledge_sources.scene_analysis`). How well it
    separates, per landmark kind on held-out frames: bench/detectors.py and BENCHMARKS.md.

Detectors are pluggable: anything with the :class:`LandmarkDetector` protocol can be registered
for a landmark kind in a :class:`DetectorRegistry`.

Images are ``(H, W)`` or ``(H, W, 3)`` arrays indexed ``(row, col)``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import cv2
import numpy as np

from models.scenario import CALIBRATION_FEATURES, SchedulerSpec

__all__ = [
    "CandidateView",
    "Detection",
    "LandmarkDetector",
    "EdgeTemplateDetector",
    "DetectorRegistry",
    "default_registry",
    "edge_image",
    "orientation_field",
    "orientation_fields",
    "ORIENTATION_PERCENTILE",
    "Calibration",
    "LR_FEATURES",
    "KIND_FAMILY",
    "ANY_KIND",
    "align_pixels",
]

#: the defaults (thresholds, calibration, alignment tolerance): the scenario schema's ``scheduler``
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
    without : ndarray like ``image``, optional
        The viewframe as it would look without this landmark (its silhouette filled with the
        terrain and sky behind it, :func:`models.viewframes.without_landmark`). Without it a
        detector can still answer present/absent but cannot give a likelihood ratio.
    """

    image: np.ndarray
    silhouette: np.ndarray
    without: np.ndarray | None = None

    @classmethod
    def from_mask(
        cls, image: np.ndarray, mask: np.ndarray, landmark_index: int, *, background: np.ndarray | None = None
    ) -> CandidateView:
        """Build from a viewframe's landmark id mask (``-1`` background, else landmark index) and,
        optionally, the viewframe rendered without landmarks (``background``, same shape as ``image``)."""
        sil = np.asarray(mask) == landmark_index
        without = None
        if background is not None:
            if background.shape != image.shape:
                raise ValueError(f"background shape {background.shape} must equal the image's {image.shape}")
            without = image.copy()
            without[sil] = background[sil]
        return cls(image, sil, without)


@dataclass(frozen=True)
class Detection:
    """A detector's answer.

    ``present`` is ``True``, ``False`` or ``None`` (cannot tell); ``score`` in [-1, 1] is the
    best energy-aware correlation; ``location`` the ``(row, col)`` of the landmark's bounding-box top-left
    corner at the best match, ``None`` when not searched. ``llr`` is the calibrated natural log of
    the likelihood ratio p(image | landmark there) / p(image | landmark not there), ``None``
    when the detector cannot give one (no view without the landmark, too few pixels);
    ``statistic`` the uncalibrated with/without statistic it came from. ``where`` is where the
    landmark's best match lies in the camera image: ``(row, col, scale)``, the centroid of the
    matched silhouette in camera pixels and the template scale relative to the viewframe's
    silhouette (:meth:`EdgeTemplateDetector.match`), ``None`` when no likelihood ratio was
    computed.
    """

    present: bool | None
    score: float
    location: tuple[int, int] | None = None
    reason: str = ""
    llr: float | None = None
    statistic: float | None = None
    where: tuple[float, float, float] | None = None


@runtime_checkable
class LandmarkDetector(Protocol):
    """The contract of a landmark detector."""

    name: str

    def detect(self, image: np.ndarray, *, view: CandidateView) -> Detection:
        """Answer whether the landmark of ``view`` is present in camera ``image``."""
        ...


@dataclass(frozen=True)
class Calibration:
    """Logistic calibration of a detector's evidence into a log-likelihood ratio.

    ``llr = bias + sum_i weights[i] * features[i]``, the features being
    :data:`LR_FEATURES` (:meth:`EdgeTemplateDetector.evidence`). The
    coefficients come from a logistic regression on labelled frames (landmark truly visible or
    not) with the training set's prior log-odds removed from the bias, so that ``llr`` is a
    likelihood ratio, not a posterior: the scheduler supplies the prior.
    """

    bias: float
    weights: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.weights) != len(LR_FEATURES):
            raise ValueError(f"weights must have {len(LR_FEATURES)} values ({', '.join(LR_FEATURES)})")

    @classmethod
    def from_sequence(cls, values) -> Calibration:
        """From ``[bias, w_1, ..., w_n]`` (the scenario schema's form)."""
        values = [float(v) for v in values]
        if len(values) != len(LR_FEATURES) + 1:
            raise ValueError(f"a calibration is [bias, {', '.join(LR_FEATURES)}]: {len(LR_FEATURES) + 1} numbers")
        return cls(values[0], tuple(values[1:]))

    def llr(self, features) -> float:
        return float(self.bias + sum(w * float(f) for w, f in zip(self.weights, features)))


#: the features a :class:`Calibration` weighs, in order (:meth:`EdgeTemplateDetector.evidence`)
LR_FEATURES: tuple[str, ...] = CALIBRATION_FEATURES

#: the percentile of an image's gradient magnitude that soft-normalises its orientation field
#: (:func:`orientation_field`; 75 and 97 did about as well with a tuning case left out, BENCHMARKS.md)
ORIENTATION_PERCENTILE = 90.0


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


def orientation_field(
    image: np.ndarray, *, axis: str = "both", percentile: float = ORIENTATION_PERCENTILE, blur_sigma: float = 1.0
) -> np.ndarray:
    """The image's edge directions, each weighted by ``|g| / (|g| + tau)`` (``tau`` the
    ``percentile`` of its gradient magnitude ``|g|``): a soft normalisation that keeps the
    direction of every clear edge, whatever its contrast, and lets faint texture and noise fade.

    Two renderers seldom agree on how strong an edge is (a wall lit or in shadow, a roof or none,
    haze) but they agree on where it runs. ``axis``: ``"both"``, the doubled-angle field
    ``(cos 2 theta, sin 2 theta)`` of the gradient direction ``theta`` (an edge and its reverse
    polarity, dark on light or light on dark, give the same vector), shape (H, W, 2); ``"x"``,
    the vertical edges only, ``|d/dcol| / (|g| + tau)``, shape (H, W, 1). float32, values in [-1, 1].
    """
    if axis not in ("both", "x"):
        raise ValueError(f"axis must be 'both' or 'x', not {axis!r}")
    return orientation_fields(image, percentile=percentile, blur_sigma=blur_sigma)[axis]


def orientation_fields(
    image: np.ndarray, *, percentile: float = ORIENTATION_PERCENTILE, blur_sigma: float = 1.0
) -> dict[str, np.ndarray]:
    """:func:`orientation_field` of both axes from one gradient: ``{"both": (H, W, 2), "x": (H, W, 1)}``."""
    if image.ndim not in (2, 3):
        raise ValueError(f"image must be (H, W) or (H, W, 3), not shape {image.shape}")
    gray = _gray(image)
    if blur_sigma > 0:
        gray = cv2.GaussianBlur(gray, (0, 0), blur_sigma)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    mag = cv2.magnitude(gx, gy)
    soft = 1.0 / (mag + float(np.percentile(mag, percentile)) + 1e-3)
    # (gx^2 - gy^2, 2 gx gy) / |g| has length |g| and the doubled angle; times 1 / (|g| + tau)
    scale = soft / (mag + 1e-6)
    both = np.dstack([(gx * gx - gy * gy) * scale, 2.0 * gx * gy * scale]).astype(np.float32)
    return {"both": both, "x": (np.abs(gx) * soft)[..., None].astype(np.float32)}


@dataclass
class EdgeTemplateDetector:
    """Masked edge-template matching around the expected place, and the with/without likelihood
    ratio (see the module docstring).

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
    calibration : Calibration, optional
        Turns the evidence into a log-likelihood ratio (``Detection.llr``); without one, or when
        the view has no ``without`` image, ``llr`` is ``None``.
    align_px : (rows, cols)
        Half-size of the likelihood ratio's alignment search in pixels: the pose errors it must
        tolerate (pitch moves the view vertically, heading horizontally), see :func:`align_pixels`.
    scales : tuple of float
        Template scales the likelihood ratio's edge score and contrast are searched over (a
        position error along the route makes a near landmark larger or smaller than the viewframe
        shows it); default: the scenario schema's ``scheduler.detector_scales``.
    """

    name: str = "edge-template"
    threshold: float = _DEFAULTS.detector_threshold
    absent_threshold: float = _DEFAULTS.absent_threshold
    search: int = 6
    search_fraction: float = 0.06
    dilate: int = 2
    min_pixels: int = 24
    axis: str = "both"
    calibration: Calibration | None = None
    align_px: tuple[int, int] = (9, 16)
    scales: tuple[float, ...] = _DEFAULTS.detector_scales

    def evidence(self, image: np.ndarray, *, view: CandidateView) -> tuple[float, float, float, float, float] | None:
        """The uncalibrated evidence (:data:`LR_FEATURES`): ``(statistic, orientation, vertical,
        contrast, context)``, ``None`` when the view has no ``without`` image or the landmark too
        few pixels.

        ``statistic`` compares the camera image with the viewframe with the landmark (``T1``) and
        without it (``T0``, the terrain and sky behind it) over the landmark's silhouette ``M``,
        in chromaticity ``(r, g) / (r + g + b)`` (free of gain, exposure and most of the shading
        renderers disagree on; the edges carry the shape). Each hypothesis is
        matched at its best offset within the alignment search (a generalised likelihood ratio:
        the pose error is a nuisance maximised out under each): with a Gaussian error model the
        log-likelihood ratio is proportional to ``SSD0 - SSD1``, ``SSDi = min_offset sum M
        |C - Ti|^2``, and ``statistic = (SSD0 - SSD1) / sum M |T1 - T0|^2`` is about +1 when the
        camera shows the landmark as the viewframe does, -1 when it shows what lies behind it
        (searched over the template ``scales`` too, the SSDs per pixel of ``M``). The search is
        ``align_px`` (pose errors) plus a quarter of the landmark's height and half
        its width (parallax: near landmarks move more than the horizon when the camera stands
        off the route point). ``orientation`` is the energy-aware correlation of the viewframe's
        edge directions inside ``M`` (dilated: the outline and the box's own edges) with the
        camera image's, :func:`orientation_field` of both (edges where the viewframe has them,
        running the same way, whatever their contrast), at the best of the same shifts and
        template ``scales`` (:meth:`match`); ``vertical`` the same with the vertical edges only
        (``axis="x"``: a box's walls, which every renderer draws, where roofs and shading differ;
        its two sides' distance is the landmark's width, so a look-alike of another width scores
        lower). ``contrast`` asks what neither needs to trust a renderer's colours for: does the
        camera image, somewhere within the same search and scales, differ inside the silhouette
        from a ring around it, as a landmark in front of the terrain does (its best
        ``|mean_in - mean_ring| / sqrt(var_in + var_ring)`` in gray levels), less the same
        contrast in the view without the landmark (a horizon crossing the silhouette shows
        contrast with no landmark there). ``context`` is the edge-direction correlation over a
        ring around the silhouette (its box grown by a quarter of its height and half its width)
        at ``orientation``'s best shift and scale: does the terrain and sky the landmark stands
        against in the viewframe stand around the match too (a landmark of the same kind
        elsewhere, or a look-alike, seldom has the candidate's surroundings).
        """
        sil = self._check(image, view)
        if int(sil.sum()) < self.min_pixels:
            return None
        got = self._features(image, view, sil)
        return None if got is None else got[0]

    def _features(
        self, image: np.ndarray, view: CandidateView, sil: np.ndarray
    ) -> tuple[tuple[float, float, float, float, float], tuple[float, float, float] | None] | None:
        """The evidence of :meth:`evidence` (in :data:`LR_FEATURES`' order) and the match's place
        (:meth:`match`); None without a view without the landmark or a colour statistic."""
        if view.without is None:
            return None
        statistic = self._colour_statistic(image, view, sil)
        if statistic is None:
            return None
        orientation, where, vertical, context = self._scaled_matches(image, view, sil)
        return (statistic, orientation, vertical, self._contrast(image, view, sil), context), where

    def _search(self, rows: int, cols: int) -> tuple[int, int]:
        """The likelihood ratio's alignment search, ``(rows, cols)`` half-sizes, for a landmark box
        of ``rows`` x ``cols`` pixels: the pose errors (``align_px``) plus parallax."""
        return self.align_px[0] + int(0.25 * rows), self.align_px[1] + int(0.5 * cols)

    def _contrast(self, image: np.ndarray, view: CandidateView, sil: np.ndarray, *, ring: int = 3) -> float:
        k = 2 * ring + 1
        big = cv2.dilate(sil.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
        rows, cols = np.nonzero(big)
        r0, r1, c0, c1 = int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1
        m_in = sil[r0:r1, c0:c1].astype(np.float32)
        m_ring = (big & ~sil)[r0:r1, c0:c1].astype(np.float32)
        sr, sc = self._search(r1 - r0, c1 - c0)
        cam = _gray(image)
        best = -np.inf
        for s in self.scales:
            inner, outer = _scaled_mask(m_in, s), _scaled_mask(m_ring, s)
            win = _window(cam, (r0 + r1) / 2, (c0 + c1) / 2, inner.shape, sr, sc, mode="edge")
            best = max(best, float(_ring_contrast(win, inner, outer).max()))
        assert view.without is not None  # checked by the callers
        behind = _gray(view.without)[r0:r1, c0:c1]
        return best - float(_ring_contrast(behind, m_in, m_ring).max())

    def match(self, image: np.ndarray, *, view: CandidateView) -> tuple[float, float, float] | None:
        """Where the landmark of ``view`` best matches in camera ``image``: ``(row, col, scale)``,
        the centroid of the viewframe's silhouette carried to the best shift and template scale
        of the likelihood ratio's ``orientation`` search (:meth:`evidence`; a template is scaled
        about its box's centre), in camera pixels, and that scale. ``None`` when the landmark
        covers fewer than ``min_pixels`` or the viewframe shows no edges on it."""
        sil = self._check(image, view)
        if int(sil.sum()) < self.min_pixels:
            return None
        return self._scaled_matches(image, view, sil)[1]

    def _scaled_matches(
        self, image: np.ndarray, view: CandidateView, sil: np.ndarray
    ) -> tuple[float, tuple[float, float, float] | None, float, float]:
        """``(orientation, where, vertical, context)`` of :meth:`evidence`, the fields computed once:
        :meth:`_scaled_match` of the edge directions with the context ring, and of the vertical edges."""
        camera, template = orientation_fields(image), orientation_fields(view.image)
        orientation, where, context = self._scaled_match(camera["both"], template["both"], sil, context=True)
        vertical = self._scaled_match(camera["x"], template["x"], sil)[0]
        return orientation, where, vertical, context

    def _scaled_match(
        self, camera: np.ndarray, template: np.ndarray, sil: np.ndarray, *, context: bool = False
    ) -> tuple[float, tuple[float, float, float] | None, float]:
        """The best energy-aware correlation ``2 <T, W> / (|T|^2 + |W|^2)`` of the viewframe's
        :func:`orientation_field` ``template`` (H, W, C) inside the dilated silhouette with the
        camera image's, ``camera`` (H, W, C), over the likelihood ratio's shifts and template
        scales; its place (:meth:`match`); and, with ``context``, the same correlation over the
        ring around the silhouette (its box grown by a quarter of its height and half its width,
        at least 4 pixels, less the dilated silhouette) at that best shift and scale (else 0)."""
        k = 2 * self.dilate + 1
        region = cv2.dilate(sil.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
        rows, cols = np.nonzero(region)
        r0, r1, c0, c1 = int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1
        sr, sc = self._search(r1 - r0, c1 - c0)
        ring = None
        if context:  # the template's box takes in the ring
            h, w = region.shape
            pr, pc = max(4, (r1 - r0) // 4), max(4, (c1 - c0) // 2)
            r0, r1, c0, c1 = max(0, r0 - pr), min(h, r1 + pr), max(0, c0 - pc), min(w, c1 + pc)
            ring = (~region[r0:r1, c0:c1]).astype(np.float32)
        template = template[r0:r1, c0:c1]
        tmask = region[r0:r1, c0:c1].astype(np.float32)
        power = np.ascontiguousarray((camera * camera).sum(axis=2))  # the camera field's energy per pixel
        srows, scols = np.nonzero(sil)
        # the silhouette's centroid from its box's centre (pixel centres at integers)
        offset = (float(srows.mean()) - (r0 + r1 - 1) / 2, float(scols.mean()) - (c0 + c1 - 1) / 2)
        centre = ((r0 + r1) / 2, (c0 + c1) / 2)
        best, where, around = 0.0, None, 0.0
        for s in self.scales:
            m = _scaled_mask(tmask, s)
            windows = [
                _window(camera[..., ch], *centre, m.shape, sr, sc, mode="constant") for ch in range(camera.shape[2])
            ]
            energy = _window(power, *centre, m.shape, sr, sc, mode="constant")
            scores = _energy_aware(windows, energy, template, m)
            if scores is None:
                continue
            i, j = np.unravel_index(int(np.argmax(scores)), scores.shape)
            if where is None or float(scores[i, j]) > best:
                best = max(best, float(scores[i, j]))
                if ring is not None:
                    ring_scores = _energy_aware(windows, energy, template, _scaled_mask(ring, s, like=m))
                    around = 0.0 if ring_scores is None else float(ring_scores[i, j])
                # offset (i, j) of the window puts the template's top-left here (see _window)
                top = int(round(centre[0] - m.shape[0] / 2)) - sr + int(i)
                left = int(round(centre[1] - m.shape[1] / 2)) - sc + int(j)
                sy, sx = m.shape[0] / tmask.shape[0], m.shape[1] / tmask.shape[1]  # the scale, as rounded
                where = (
                    top + (m.shape[0] - 1) / 2 + sy * offset[0],
                    left + (m.shape[1] - 1) / 2 + sx * offset[1],
                    float(math.sqrt(sy * sx)),
                )
        return best, where, around

    def detect(self, image: np.ndarray, *, view: CandidateView) -> Detection:
        sil = self._check(image, view)
        n = int(sil.sum())
        if n < self.min_pixels:
            return Detection(None, 0.0, None, f"only {n} pixels in the viewframe (< {self.min_pixels})")
        best, loc, why = self._edge_score(image, view, sil)
        if loc is None:
            return Detection(None, 0.0, None, why)
        llr = statistic = where = None
        got = None if self.calibration is None else self._features(image, view, sil)
        if got is not None:
            assert self.calibration is not None
            features, where = got
            statistic, llr = features[0], self.calibration.llr(features)
        lr = "" if llr is None else f"; log-likelihood ratio {llr:+.2f}"
        if best >= self.threshold:
            why, present = f"score {best:.3f} >= {self.threshold}{lr}", True
        elif best < self.absent_threshold:
            why, present = f"score {best:.3f} < {self.absent_threshold}{lr}", False
        else:
            why, present = f"score {best:.3f} between {self.absent_threshold} and {self.threshold}{lr}", None
        return Detection(present, best, loc, why, llr, statistic, where)

    # -- parts ------------------------------------------------------------------------------
    @staticmethod
    def _check(image: np.ndarray, view: CandidateView) -> np.ndarray:
        sil = np.asarray(view.silhouette, bool)
        if sil.shape != image.shape[:2] or view.image.shape[:2] != image.shape[:2]:
            raise ValueError(f"image shape {image.shape[:2]} must equal the viewframe's {view.image.shape[:2]}")
        return sil

    def _edge_score(
        self, image: np.ndarray, view: CandidateView, sil: np.ndarray
    ) -> tuple[float, tuple[int, int] | None, str]:
        """The energy-aware edge correlation: best score and its place (``None`` and a reason
        when the viewframe shows no edges on the landmark)."""
        h, w = sil.shape
        k = 2 * self.dilate + 1
        region = cv2.dilate(sil.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
        rows, cols = np.nonzero(region)
        r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
        template = _highpass(edge_image(view.image, axis=self.axis))[r0:r1, c0:c1]
        tmask = region[r0:r1, c0:c1].astype(np.float32)
        if float((template * tmask).std()) < 1e-6:
            return 0.0, None, "the viewframe shows no edges on the landmark"
        s = self.search + int(round(self.search_fraction * w))
        wr0, wr1 = max(0, r0 - s), min(h, r1 + s)
        wc0, wc1 = max(0, c0 - s), min(w, c1 + s)
        window = _highpass(edge_image(image, axis=self.axis))[wr0:wr1, wc0:wc1]
        weighted = template * tmask
        cross = cv2.matchTemplate(window, weighted, cv2.TM_CCORR)
        energy = cv2.matchTemplate(window * window, tmask, cv2.TM_CCORR)
        scores = 2.0 * cross / (float((weighted * weighted).sum()) + energy + 1e-12)
        idx = np.unravel_index(int(np.argmax(scores)), scores.shape)
        return float(scores[idx]), (int(wr0 + idx[0]), int(wc0 + idx[1])), ""

    def _colour_statistic(self, image: np.ndarray, view: CandidateView, sil: np.ndarray) -> float | None:
        """The chromaticity with/without statistic of :meth:`evidence`, each hypothesis at its best
        shift and template scale (the SSDs per pixel of the viewframe's silhouette)."""
        rows, cols = np.nonzero(sil)
        r0, r1, c0, c1 = int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1
        m = sil[r0:r1, c0:c1].astype(np.float32)
        assert view.without is not None  # checked by the callers
        t1 = _chromaticity(view.image)[r0:r1, c0:c1]
        t0 = _chromaticity(view.without)[r0:r1, c0:c1]
        d2 = float((m[..., None] * (t1 - t0) ** 2).sum())
        if d2 < 1e-9:
            return None  # the landmark has the colour of what lies behind it: no colour evidence
        sr, sc = self._search(r1 - r0, c1 - c0)
        cam = _chromaticity(image)
        ssd0 = ssd1 = math.inf
        for s in self.scales:
            ms = _scaled_mask(m, s)
            size = (ms.shape[1], ms.shape[0])
            win = np.dstack(
                [_window(cam[..., c], (r0 + r1) / 2, (c0 + c1) / 2, ms.shape, sr, sc, mode="edge") for c in range(2)]
            )
            per = float(m.sum()) / float(ms.sum())  # back to the viewframe silhouette's pixels
            ssd0 = min(ssd0, per * float(_masked_ssd(win, cv2.resize(t0, size), ms).min()))
            ssd1 = min(ssd1, per * float(_masked_ssd(win, cv2.resize(t1, size), ms).min()))
        return (ssd0 - ssd1) / d2


def _scaled_mask(mask: np.ndarray, scale: float, *, like: np.ndarray | None = None) -> np.ndarray:
    """A 0/1 float mask resized by ``scale`` (at least 2 x 2 pixels; ``like``: to that mask's shape)."""
    if scale == 1.0 and like is None:
        return mask
    if like is not None:
        size = (like.shape[1], like.shape[0])
    else:
        size = (max(2, int(round(mask.shape[1] * scale))), max(2, int(round(mask.shape[0] * scale))))
    return (cv2.resize(mask, size, interpolation=cv2.INTER_LINEAR) > 0.5).astype(np.float32)


def _energy_aware(
    windows: Sequence[np.ndarray], energy: np.ndarray, template: np.ndarray, mask: np.ndarray
) -> np.ndarray | None:
    """``2 <T, W> / (|T|^2 + |W|^2)`` over ``mask`` for every offset of the template inside the
    windows: ``windows`` one per channel of the camera's field, ``energy`` their summed squares,
    ``template`` (h, w, C) resized to the mask's shape. ``None`` when the template is empty there."""
    size = (mask.shape[1], mask.shape[0])
    cross = None
    norm = 0.0
    for ch, win in enumerate(windows):
        t = cv2.resize(np.ascontiguousarray(template[..., ch]), size, interpolation=cv2.INTER_LINEAR) * mask
        c = cv2.matchTemplate(win, t, cv2.TM_CCORR)
        cross = c if cross is None else cross + c
        norm += float((t * t).sum())
    if norm < 1e-9 or cross is None:
        return None
    return 2.0 * cross / (norm + cv2.matchTemplate(energy, mask, cv2.TM_CCORR) + 1e-12)


def _window(
    image: np.ndarray, row: float, col: float, shape: tuple[int, ...], sr: int, sc: int, *, mode: str
) -> np.ndarray:
    """The part of ``image`` (H, W) where a template of ``shape`` centred at ``(row, col)`` can
    lie when shifted by up to ``sr`` rows and ``sc`` columns, padded (``mode``: ``"edge"``, or
    ``"constant"`` zeros) where it leaves the image: (shape[0] + 2 sr, shape[1] + 2 sc) float32."""
    th, tw = int(shape[0]), int(shape[1])
    top = int(round(row - th / 2)) - sr
    left = int(round(col - tw / 2)) - sc
    h, w = image.shape[:2]
    pad = max(0, -top, -left, top + th + 2 * sr - h, left + tw + 2 * sc - w)
    padded = np.pad(image, pad, mode=mode) if pad else image  # type: ignore[call-overload]
    out = padded[top + pad : top + pad + th + 2 * sr, left + pad : left + pad + tw + 2 * sc]
    return np.ascontiguousarray(out, dtype=np.float32)


def _gray(image: np.ndarray) -> np.ndarray:
    if image.ndim == 3:
        return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY).astype(np.float32)
    return image.astype(np.float32)


def _ring_contrast(window: np.ndarray, inner: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """``|mean_inner - mean_ring| / sqrt(var_inner + var_ring + 4)`` of the gray ``window`` for every
    offset of the two masks (same shape) inside it; the 4 (gray levels squared) keeps flat
    patches finite."""
    n_in, n_ring = float(inner.sum()), float(ring.sum())
    if n_in == 0 or n_ring == 0:
        return np.zeros((1, 1), np.float32)
    mi = cv2.matchTemplate(window, inner, cv2.TM_CCORR) / n_in
    mr = cv2.matchTemplate(window, ring, cv2.TM_CCORR) / n_ring
    vi = cv2.matchTemplate(window * window, inner, cv2.TM_CCORR) / n_in - mi * mi
    vr = cv2.matchTemplate(window * window, ring, cv2.TM_CCORR) / n_ring - mr * mr
    return np.abs(mi - mr) / np.sqrt(np.maximum(vi, 0) + np.maximum(vr, 0) + 4.0)


def _chromaticity(image: np.ndarray) -> np.ndarray:
    """``(r, g) / (r + g + b)`` of an RGB image (H, W, 3) -> (H, W, 2) float32; a gray image gives
    the neutral 1/3 everywhere."""
    if image.ndim == 2:
        return np.full((*image.shape, 2), 1.0 / 3.0, np.float32)
    f = image.astype(np.float32) + 1.0
    return np.ascontiguousarray(f[..., :2] / f.sum(axis=2, keepdims=True))


def _masked_ssd(window: np.ndarray, template: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``sum mask * |window_o - template|^2`` over channels for every offset ``o`` of the template
    (H_t, W_t, C) inside the window (H_w, W_w, C); returns (H_w - H_t + 1, W_w - W_t + 1)."""
    out = np.zeros((window.shape[0] - template.shape[0] + 1, window.shape[1] - template.shape[1] + 1), np.float32)
    for c in range(template.shape[2]):
        w = np.ascontiguousarray(window[..., c])
        t = np.ascontiguousarray(template[..., c])
        out += (
            cv2.matchTemplate(w * w, mask, cv2.TM_CCORR)
            - 2.0 * cv2.matchTemplate(w, mask * t, cv2.TM_CCORR)
            + float((mask * t * t).sum())
        )
    return out


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


def align_pixels(
    *, height: int, fov_y_deg: float, tolerance_deg: tuple[float, float], margin: int = 3
) -> tuple[int, int]:
    """The alignment search, ``(rows, cols)`` half-sizes in pixels, that covers pose errors of
    ``tolerance_deg = (pitch, heading)`` degrees for a camera of ``height`` rows and vertical
    field of view ``fov_y_deg`` (square pixels, :mod:`models.camera`'s pinhole), plus ``margin``
    pixels for position errors and rendering differences."""
    if height < 1 or not 0 < fov_y_deg < 180:
        raise ValueError("height must be >= 1 and fov_y_deg in (0, 180)")
    if any(t < 0 or t >= 45 for t in tolerance_deg):
        raise ValueError("tolerance_deg must be two angles in [0, 45) degrees")
    f = (height / 2) / math.tan(math.radians(fov_y_deg) / 2)
    rows, cols = (int(math.ceil(f * math.tan(math.radians(t)))) + int(margin) for t in tolerance_deg)
    return rows, cols


#: the calibration key that serves every kind with no entry of its own nor of its family's
ANY_KIND = "any"

#: landmark kind -> detector family (a calibration may be given per family); other kinds: "outline"
KIND_FAMILY: dict[str, str] = {"house": "outline", "barn": "outline", "tower": "vertical", "silo": "vertical"}


def default_registry(
    *,
    threshold: float = _DEFAULTS.detector_threshold,
    absent_threshold: float = _DEFAULTS.absent_threshold,
    calibration: Mapping[str, Sequence[float]] | None = None,
    align_px: tuple[int, int] | None = None,
    scales: Sequence[float] = _DEFAULTS.detector_scales,
) -> DetectorRegistry:
    """Detectors for the bundled landmark kinds: houses and barns (wide boxes) by their outline,
    towers and silos (tall, narrow) by their vertical edges; any other kind by the box outline.

    ``threshold`` / ``absent_threshold``: the present/absent score thresholds;
    ``calibration``: ``{kind, family or "any": [bias, weights...]}`` (:class:`Calibration`; a
    kind's own entry wins over its family's, :data:`KIND_FAMILY`, which wins over ``"any"``,
    :data:`ANY_KIND`; ``None``: no likelihood ratio, pass
    the schema's ``scheduler.calibration`` for the calibrated one); ``align_px``: the likelihood
    ratio's alignment search (:func:`align_pixels`); ``scales``: the template scales it searches
    (:class:`EdgeTemplateDetector`). The values come from the scenario's
    ``scheduler`` block (:class:`models.scenario.SchedulerSpec`).
    """
    cal = {k: Calibration.from_sequence(v) for k, v in (calibration or {}).items()}

    def make(name: str, kind: str | None, **kw: Any) -> EdgeTemplateDetector:
        family = KIND_FAMILY.get(kind or "", "outline")
        if align_px is not None:
            kw["align_px"] = (int(align_px[0]), int(align_px[1]))
        return EdgeTemplateDetector(
            name=name,
            threshold=threshold,
            absent_threshold=absent_threshold,
            calibration=cal.get(kind or "", cal.get(family, cal.get(ANY_KIND))),
            scales=tuple(float(v) for v in scales),
            **kw,
        )

    reg = DetectorRegistry(fallback=make("box-outline", None))
    reg.register("house", make("house-outline", "house"))
    reg.register("barn", make("barn-outline", "barn"))
    reg.register("tower", make("tower-vertical-edges", "tower", axis="x", min_pixels=12))
    reg.register("silo", make("silo-vertical-edges", "silo", axis="x", min_pixels=12))
    return reg
