"""Landmark detector agents: answer the scheduler's yes/no questions from the camera image."""

from __future__ import annotations

import logging
from collections import OrderedDict
from typing import TYPE_CHECKING, Any, ClassVar

from blackboard.hypothesis import Hypothesis
from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels
from models.scenario import SchedulerSpec

if TYPE_CHECKING:
    from models.detectors import DetectorRegistry

__all__ = ["LandmarkDetectorAgent"]

log = logging.getLogger(__name__)

_DEFAULTS = SchedulerSpec()


class LandmarkDetectorAgent(KnowledgeSource):
    """Answers queries addressed to it: "is landmark L present in camera frame F, as seen from
    viewframe V?". It reads the camera frame and the candidate viewframe (image and landmark mask)
    from the blackboard and runs the detector registered for L's kind
    (:func:`models.detectors.default_registry`). It never reads the ``truth`` level.

    Each answer carries the three-way ``present`` and, when the viewframe came with its view
    without landmarks (``background``), the calibrated log-likelihood ratio ``llr`` of the
    landmark being there (:mod:`models.detectors`), and, with the camera's field of view known
    (``fov_y_deg``), ``where`` it found the landmark's best match: its placement in the camera
    image (:mod:`models.placement`, the scene analysis's position evidence).

    Options: ``threshold`` (score for "present"), ``absent_threshold`` (below it, "absent"; in
    between the answer is undecided), ``calibration`` (``{kind or family: [bias, weights...]}``)
    ``align_deg`` (pose errors the ratio tolerates, (pitch, heading) degrees) and ``scales``
    (template scales it searches, the schema's ``scheduler.detector_scales``), each
    defaulting to the scenario schema's ``scheduler`` settings; ``camera_height`` and
    ``fov_y_deg`` (the scenario camera's rows and vertical field of view: they turn ``align_deg``
    into pixels; without them the detector's own default search); ``cache`` (frames and
    viewframes kept, default 64).
    """

    consumes: ClassVar[tuple[str, ...]] = (levels.QUERY,)
    produces: ClassVar[tuple[str, ...]] = (levels.ANSWER,)

    def __init__(
        self,
        name: str,
        *,
        threshold: float = _DEFAULTS.detector_threshold,
        absent_threshold: float = _DEFAULTS.absent_threshold,
        calibration: dict[str, Any] | None = None,
        align_deg: tuple[float, float] | list[float] = _DEFAULTS.align_deg,
        scales: tuple[float, ...] | list[float] = _DEFAULTS.detector_scales,
        camera_height: int | None = None,
        fov_y_deg: float | None = None,
        cache: int = 64,
        **options: Any,
    ) -> None:
        super().__init__(name, **options)
        self.threshold = float(threshold)
        self.absent_threshold = float(absent_threshold)
        self.calibration = dict(_DEFAULTS.calibration if calibration is None else calibration)
        self.align_deg = (float(align_deg[0]), float(align_deg[1]))
        self.scales = tuple(float(v) for v in scales)
        self.camera_height = None if camera_height is None else int(camera_height)
        self.fov_y_deg = None if fov_y_deg is None else float(fov_y_deg)
        self.cache = int(cache)
        self._registry: DetectorRegistry | None = None
        self._store: OrderedDict[str, Hypothesis] = OrderedDict()

    def input_error(self, err: Exception) -> str | None:
        from models.errors import CacheEntryError

        # a viewframe's cache entry this host cannot read (another machine, a stale reference):
        # no retry helps, the run stops with the message naming the entry, viewframe and agent
        return str(err) if isinstance(err, CacheEntryError) else None

    def setup(self, board: Board) -> None:
        from models.detectors import align_pixels, default_registry

        align = None
        if self.camera_height is not None and self.fov_y_deg is not None:
            align = align_pixels(height=self.camera_height, fov_y_deg=self.fov_y_deg, tolerance_deg=self.align_deg)
        self._registry = default_registry(
            threshold=self.threshold,
            absent_threshold=self.absent_threshold,
            calibration=self.calibration,
            align_px=align,
            scales=self.scales,
        )

    def precondition(self, event: Event) -> float | None:
        h = event.hypothesis
        if event.kind is not EventKind.POSTED or h.addressed_to != self.name:
            return None
        return 1.0

    def _get(self, board: Board, hid: str) -> Hypothesis:
        if hid in self._store:
            self._store.move_to_end(hid)
            return self._store[hid]
        h = board.get(hid)
        if h is None:
            raise LookupError(f"hypothesis {hid!r} is not on the blackboard")
        self._store[hid] = h
        while len(self._store) > self.cache:
            self._store.popitem(last=False)
        return h

    def act(self, event: Event, board: Board) -> None:
        from models.detectors import CandidateView

        assert self._registry is not None
        q = levels.Query.from_hypothesis(event.hypothesis)
        frame_h = self._get(board, levels.frame_id(q.frame))
        vf_h = self._get(board, levels.viewframe_id(q.viewframe))
        frame = levels.SensorFrame.from_hypothesis(frame_h)
        vf = levels.Viewframe.from_hypothesis(vf_h)
        detector = self._registry.for_kind(q.kind)
        px = vf.pixels(agent=self.name)
        view = CandidateView.from_mask(px.image, px.mask, q.landmark_index, background=px.background)
        if frame.columns is not None and _outside(view.silhouette, frame.columns):
            from models.detectors import Detection

            # a narrower camera image padded to the camera's width: the landmark is where it sees nothing
            det = Detection(None, 0.0, reason=f"outside the columns {frame.columns} the camera image sees")
        else:
            det = detector.detect(frame.image, view=view)
        where = None
        if det.where is not None and self.fov_y_deg is not None:
            from models.placement import found_placement

            pixels = int(view.silhouette.sum())
            where = list(found_placement(det.where, pixels=pixels, shape=frame.image.shape, fov_y_deg=self.fov_y_deg))
        levels.post(
            board,
            levels.Answer(
                query=event.hypothesis.id,
                frame=q.frame,
                landmark=q.landmark,
                viewframe=q.viewframe,
                present=det.present,
                score=det.score,
                location=None if det.location is None else list(det.location),
                detector=detector.name,
                reason=det.reason,
                llr=det.llr,
                where=where,
            ),
            links=(event.hypothesis.id, frame_h.id, vf_h.id),
            credibility=float(min(1.0, max(0.0, det.score))),
        )


def _outside(silhouette, columns: list) -> bool:
    """True when most of a landmark's silhouette (H, W) bool lies outside image columns [first, last)."""
    total = int(silhouette.sum())
    inside = int(silhouette[:, columns[0] : columns[1]].sum())
    return total > 0 and inside < 0.5 * total
