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

    Options: ``threshold`` (score for "present"), ``absent_threshold`` (below it, "absent"; in
    between the answer is undecided), both defaulting to the scenario schema's
    ``scheduler.detector_threshold`` and ``scheduler.absent_threshold``; ``cache`` (frames and
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
        cache: int = 64,
        **options: Any,
    ) -> None:
        super().__init__(name, **options)
        self.threshold = float(threshold)
        self.absent_threshold = float(absent_threshold)
        self.cache = int(cache)
        self._registry: DetectorRegistry | None = None
        self._store: OrderedDict[str, Hypothesis] = OrderedDict()

    def setup(self, board: Board) -> None:
        from models.detectors import default_registry

        self._registry = default_registry(threshold=self.threshold, absent_threshold=self.absent_threshold)

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
        view = CandidateView.from_mask(vf.image, vf.mask, q.landmark_index)
        det = detector.detect(frame.image, view=view)
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
            ),
            links=(event.hypothesis.id, frame_h.id, vf_h.id),
            credibility=float(min(1.0, max(0.0, det.score))),
        )
