"""The landmark detector agent on an in-memory board: answers the queries addressed to it."""

from __future__ import annotations

import numpy as np
import pytest

from blackboard.memory_board import MemoryBlackboard
from knowledge_sources import levels
from knowledge_sources.detector import LandmarkDetectorAgent
from tests.knowledge_sources.conftest import inline_viewframe


def _visible_landmark(small_rendered: dict) -> tuple[levels.Viewframe, dict]:
    """A viewframe and a landmark well visible in it."""
    mp = levels.Map.from_hypothesis(small_rendered["map"])
    best = max(((k, lm, px) for k, seen in mp.seen().items() for lm, px in seen.items()), key=lambda t: t[2])
    vf = inline_viewframe(levels.Viewframe.from_hypothesis(small_rendered["viewframes"][int(best[0])]))
    return vf, next(lm for lm in mp.landmarks if lm["id"] == best[1])


def _ask(
    bb: MemoryBlackboard, vf: levels.Viewframe, lm: dict, image: np.ndarray, *, to: str, columns: list | None = None
) -> levels.Query:
    bb.post(levels.VIEWFRAME, vf.to_body(), id=vf.id())
    levels.post(bb.user, levels.SensorFrame(frame=0, image=image, source="test", columns=columns))
    q = levels.Query(
        frame=0, number=1, landmark=lm["id"], landmark_index=lm["index"], kind=lm["kind"], viewframe=vf.index, p=0.5
    )
    levels.post(bb.user, q, addressed_to=to, deadline_s=5.0)
    return q


def test_present_where_the_camera_sees_the_viewframe(small_rendered: dict) -> None:
    vf, lm = _visible_landmark(small_rendered)
    bb = MemoryBlackboard()
    bb.add(LandmarkDetectorAgent("detector-x"))
    q = _ask(bb, vf, lm, vf.image, to="detector-x")
    bb.run()
    (h,) = bb.hypotheses(levels.ANSWER)
    answer = levels.Answer.from_hypothesis(h)
    assert h.id == levels.answer_id(q.id()) and answer.query == q.id()
    assert (answer.frame, answer.landmark, answer.viewframe) == (0, lm["id"], vf.index)
    assert answer.present is True and answer.score >= 0.65 and answer.location is not None
    assert set(h.links) == {q.id(), levels.frame_id(0), vf.id()}
    assert bb.user_timeouts == []


def test_absent_in_a_blank_image(small_rendered: dict) -> None:
    vf, lm = _visible_landmark(small_rendered)
    bb = MemoryBlackboard()
    bb.add(LandmarkDetectorAgent("detector-x"))
    _ask(bb, vf, lm, np.full_like(vf.image, 128), to="detector-x")
    bb.run()
    (h,) = bb.hypotheses(levels.ANSWER)
    answer = levels.Answer.from_hypothesis(h)
    assert answer.present is not True and answer.score < 0.65


def test_the_answer_carries_the_likelihood_ratio_of_the_view_with_and_without(small_rendered: dict) -> None:
    """The map renderer posts each viewframe with its view without landmarks: the answer's ratio
    favours the landmark when the camera sees the viewframe, and its absence when the camera sees
    that view without it."""
    vf, lm = _visible_landmark(small_rendered)
    assert vf.background is not None
    llrs = {}
    for name, image in (("with", vf.image), ("without", vf.background)):
        bb = MemoryBlackboard()
        bb.add(LandmarkDetectorAgent("detector-x", camera_height=vf.image.shape[0], fov_y_deg=45.0))
        _ask(bb, vf, lm, image, to="detector-x")
        bb.run()
        (h,) = bb.hypotheses(levels.ANSWER)
        llrs[name] = levels.Answer.from_hypothesis(h).llr
    assert llrs["with"] is not None and llrs["without"] is not None
    assert llrs["with"] > 0.0 > llrs["without"], llrs


def test_queries_for_another_detector_are_left_alone(small_rendered: dict) -> None:
    vf, lm = _visible_landmark(small_rendered)
    bb = MemoryBlackboard()
    bb.add(LandmarkDetectorAgent("detector-x"))
    bb.add(LandmarkDetectorAgent("detector-y"))
    _ask(bb, vf, lm, vf.image, to="detector-y")
    bb.run()
    assert [h.source for h in bb.hypotheses(levels.ANSWER)] == ["detector-y"]


def test_a_query_about_a_frame_not_on_the_board_fails_and_times_out(small_rendered: dict) -> None:
    vf, lm = _visible_landmark(small_rendered)
    bb = MemoryBlackboard(raise_errors=False)
    bb.add(LandmarkDetectorAgent("detector-x"))
    q = levels.Query(
        frame=9, number=1, landmark=lm["id"], landmark_index=lm["index"], kind=lm["kind"], viewframe=vf.index, p=0.5
    )
    levels.post(bb.user, q, addressed_to="detector-x")
    bb.run()
    ((_, _, err),) = bb.errors
    assert isinstance(err, LookupError) and levels.frame_id(9) in str(err)
    assert [h.id for h, _ in bb.user_timeouts] == [q.id()]


def test_cache_keeps_a_bounded_number_of_hypotheses(small_rendered: dict) -> None:
    vf, lm = _visible_landmark(small_rendered)
    bb = MemoryBlackboard()
    agent = LandmarkDetectorAgent("detector-x", cache=1)
    bb.add(agent)
    _ask(bb, vf, lm, vf.image, to="detector-x")
    bb.run()
    assert len(agent._store) == 1
    with pytest.raises(ValueError):
        LandmarkDetectorAgent("detector-x", cache="many")


@pytest.mark.parametrize("shift", [0, 6])
def test_the_answer_says_where_the_landmark_was_found(small_rendered: dict, shift: int) -> None:
    """With the camera's field of view, the answer carries the landmark's placement in the camera
    frame (models.placement): where the map says the viewframe shows it when the camera sees the
    viewframe itself, and that many degrees to the right when the camera image is moved right."""
    from models.placement import focal_px

    vf, lm = _visible_landmark(small_rendered)
    mp = levels.Map.from_hypothesis(small_rendered["map"])
    predicted = mp.placement_table()[vf.index][lm["id"]]
    image = np.roll(vf.image, shift, axis=1)
    if shift:
        image[:, :shift] = image[:, shift : shift + 1]
    bb = MemoryBlackboard()
    bb.add(LandmarkDetectorAgent("detector-x", camera_height=vf.image.shape[0], fov_y_deg=45.0))
    _ask(bb, vf, lm, image, to="detector-x")
    bb.run()
    (h,) = bb.hypotheses(levels.ANSWER)
    where = levels.Answer.from_hypothesis(h).where
    assert where is not None and len(where) == 3
    moved = np.degrees(np.arctan(shift / focal_px(vf.image.shape[0], 45.0)))
    assert abs(where[0] - predicted[0]) < 0.5 and abs(where[1] - (predicted[1] + moved)) < 0.6, (where, predicted)
    assert abs(np.log(where[2] / predicted[2])) < 0.1
    # without the field of view the detector cannot turn pixels into angles
    bb = MemoryBlackboard()
    bb.add(LandmarkDetectorAgent("detector-x"))
    _ask(bb, vf, lm, image, to="detector-x")
    bb.run()
    (h,) = bb.hypotheses(levels.ANSWER)
    assert levels.Answer.from_hypothesis(h).where is None


def test_the_map_places_every_visible_landmark(small_rendered: dict) -> None:
    mp = levels.Map.from_hypothesis(small_rendered["map"])
    placements, seen_in = mp.placement_table(), mp.seen()
    assert set(placements) == set(seen_in) == set(range(mp.viewframes))
    for k, seen in seen_in.items():
        assert set(placements[k]) == set(seen)
        for el, az, size in placements[k].values():
            assert abs(el) <= 22.5 and abs(az) <= 30.0 and size > 0


def test_no_answer_where_a_padded_camera_image_sees_nothing(small_rendered: dict) -> None:
    """A narrower camera image padded to the camera's width (sensor_frame.columns): a landmark
    that the candidate shows outside those columns is neither present nor absent there."""
    vf, lm = _visible_landmark(small_rendered)
    cols = np.flatnonzero((vf.mask == lm["index"]).any(axis=0))
    width = vf.image.shape[1]
    answers = {}
    for name, columns in (
        ("beside", [int(cols.max()) + 1, width] if cols.max() + 1 < width else [0, int(cols.min())]),
        ("over", [max(0, int(cols.min()) - 2), min(width, int(cols.max()) + 3)]),
    ):
        bb = MemoryBlackboard()
        bb.add(LandmarkDetectorAgent("detector-x"))
        _ask(bb, vf, lm, vf.image, to="detector-x", columns=columns)
        bb.run()
        (h,) = bb.hypotheses(levels.ANSWER)
        answers[name] = levels.Answer.from_hypothesis(h)
    assert answers["beside"].present is None and answers["beside"].llr is None
    assert "outside the columns" in answers["beside"].reason
    assert answers["over"].present is True
