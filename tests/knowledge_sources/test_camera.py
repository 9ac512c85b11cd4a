"""The camera on an in-memory board: frames only once every shard is indexed; truth apart."""

from __future__ import annotations

import numpy as np
import pytest

from blackboard.memory_board import MemoryBlackboard
from knowledge_sources import levels
from knowledge_sources.camera import Camera
from tests.knowledge_sources.conftest import SMALL


def _board_with_map(small_rendered: dict) -> MemoryBlackboard:
    bb = MemoryBlackboard()
    mp = small_rendered["map"]
    bb.post(mp.level, mp.body, id=mp.id)
    return bb


def test_frames_start_when_every_shard_is_indexed(small_rendered: dict) -> None:
    bb = _board_with_map(small_rendered)
    bb.add(Camera("camera"))
    levels.post(bb.user, levels.Index(shard=1, shards=2, viewframes=4))
    bb.run()
    assert bb.hypotheses(levels.SENSOR_FRAME) == []
    levels.post(bb.user, levels.Index(shard=0, shards=2, viewframes=4))
    bb.run()
    frames = [levels.SensorFrame.from_hypothesis(h) for h in bb.hypotheses(levels.SENSOR_FRAME)]
    n = len(SMALL["route"]) * SMALL["sensor"]["simulate"]["per_point"]
    assert [f.frame for f in frames] == list(range(n))
    assert all(f.image.shape == (120, 160, 3) and f.source == "simulated" for f in frames)
    assert len({f.image.tobytes() for f in frames}) == n  # distinct images
    truths = {t.frame: t for t in (levels.Truth.from_hypothesis(h) for h in bb.hypotheses(levels.TRUTH))}
    assert sorted(truths) == list(range(n))
    for h in bb.hypotheses(levels.TRUTH):
        t = levels.Truth.from_hypothesis(h)
        assert h.id == levels.truth_id(t.frame) and h.links == (levels.frame_id(t.frame),)
        # simulated near its route point (jitter 0.5 m, advance 5 % of the leg)
        route = np.asarray(SMALL["route"], dtype=float)
        assert np.hypot(*(route[t.frame] - t.pose[:2])) < 10.0


def test_frames_are_posted_once(small_rendered: dict) -> None:
    bb = _board_with_map(small_rendered)
    bb.add(Camera("camera"))
    levels.post(bb.user, levels.Index(shard=0, shards=1, viewframes=8))
    bb.run()
    bb.post(levels.INDEX, levels.Index(shard=0, shards=1, viewframes=8).to_body(), id="index-again")
    bb.run()
    assert len(bb.hypotheses(levels.SENSOR_FRAME)) == len(SMALL["route"]) and bb.rejected == []


def test_camera_needs_the_map(small_rendered: dict) -> None:
    bb = MemoryBlackboard()
    bb.add(Camera("camera"))
    levels.post(bb.user, levels.Index(shard=0, shards=1, viewframes=8))
    with pytest.raises(LookupError, match="map"):
        bb.run()


def test_rate_must_be_positive() -> None:
    with pytest.raises(ValueError, match="rate_hz"):
        Camera("camera", rate_hz=0)


def test_pace_options_are_checked() -> None:
    with pytest.raises(ValueError, match="pace"):
        Camera("camera", pace="ranking")
    with pytest.raises(ValueError, match="not both"):
        Camera("camera", pace="track", rate_hz=2.0)


@pytest.mark.parametrize("track", [True, False])
def test_a_paced_camera_posts_each_frame_after_the_answer_to_the_one_before(small, track: bool) -> None:
    """Paced: frame k + 1 is posted only after the track of frame k (tracking on), or its position
    (tracking off); every frame is still localized."""
    from knowledge_sources.mission import run_mission

    order: list[tuple[str, int]] = []

    def seen(level: str, body, stamp: float) -> None:
        if level in (levels.SENSOR_FRAME, levels.POSITION, levels.TRACK):
            order.append((level, int(body["frame"])))

    results = run_mission(small, paced=True, track=track, on_hypothesis=seen)
    n = len(SMALL["route"])
    assert results["summary"]["posted"] == n and results["summary"]["localized"] == n
    answer = levels.TRACK if track else levels.POSITION
    where = {item: i for i, item in enumerate(order)}
    for k in range(n - 1):
        assert where[(answer, k)] < where[(levels.SENSOR_FRAME, k + 1)]
    if track:  # so the track of the frame before was there for every frame's ranking
        assert all(f["track_prior"] for f in results["frames"][1:])


def test_frames_are_prepared_when_the_scenario_is_posted_and_posted_once_indexed(small_rendered: dict) -> None:
    """The camera prepares its frames on the scenario (while the map is made), posts nothing before
    every shard is indexed, then the same frames as a camera that prepares them from the map's
    scenario path once indexed; it no longer needs the map."""
    early = MemoryBlackboard()  # no map on this board: the frames come from the scenario's path
    early.add(Camera("camera"))
    levels.post(early.user, levels.Scenario(path=str(small_rendered["path"]), strategy="associative"))
    early.run()
    assert early.hypotheses(levels.SENSOR_FRAME) == []
    levels.post(early.user, levels.Index(shard=0, shards=1, viewframes=8))
    early.run()
    late = _board_with_map(small_rendered)
    late.add(Camera("camera"))
    levels.post(late.user, levels.Index(shard=0, shards=1, viewframes=8))
    late.run()
    got, want = (
        [levels.SensorFrame.from_hypothesis(h) for h in bb.hypotheses(levels.SENSOR_FRAME)] for bb in (early, late)
    )
    assert len(got) == len(SMALL["route"]) and [f.frame for f in got] == [f.frame for f in want]
    assert all(np.array_equal(a.image, b.image) for a, b in zip(got, want))


def test_the_first_frame_is_posted_as_soon_as_it_is_made_not_after_the_last(small_rendered: dict, monkeypatch) -> None:
    """The camera's thread makes the frames one by one from the scenario on: once every shard is
    indexed the first frame goes out as soon as it is made, while the others are still being made
    (here held back until a second after it); the frames are those the world makes all at once, in order."""
    import threading
    import time

    from models.world import World

    plain = World.iter_sensor_frames
    gate = threading.Event()

    def held(self):
        for i, f in enumerate(plain(self)):
            yield f
            if i == 0:
                gate.wait(30)  # the others only once the test lets them

    monkeypatch.setattr(World, "iter_sensor_frames", held)
    camera = Camera("camera")
    posted: list[tuple[int, int]] = []  # (frame, frames made when it was posted)
    post = camera._post

    def recording(f, board):
        assert camera._frames is not None
        posted.append((f.index, len(camera._frames._made)))
        if f.index == 0:
            threading.Timer(1.0, gate.set).start()
        post(f, board)

    camera._post = recording  # type: ignore[method-assign]
    bb = MemoryBlackboard()
    bb.add(camera)
    levels.post(bb.user, levels.Scenario(path=str(small_rendered["path"]), strategy="associative"))
    bb.run()
    levels.post(bb.user, levels.Index(shard=0, shards=1, viewframes=8))
    start = time.perf_counter()
    bb.run()
    n = len(SMALL["route"])
    assert posted[0] == (0, 1) and [k for k, _ in posted] == list(range(n))  # the first alone, then the rest
    assert time.perf_counter() - start >= 1.0
    with World.from_scenario(small_rendered["path"]) as world:
        want = world.sensor_frames
    got = [levels.SensorFrame.from_hypothesis(h) for h in bb.hypotheses(levels.SENSOR_FRAME)]
    assert [f.frame for f in got] == [f.index for f in want]
    assert all(np.array_equal(g.image, w.image) for g, w in zip(got, want))


def test_an_error_making_the_frames_stops_the_camera_when_they_are_wanted(small_rendered: dict, monkeypatch) -> None:
    """The frames are made by the camera's own thread: its error is raised by the camera's
    activation that wants them (once the map is up), as it was when they were made in it."""
    from models.world import World

    def broken(self):
        raise ValueError(f"{self.scenario.name}: sensor.frames: no such file")
        yield  # a generator

    monkeypatch.setattr(World, "iter_sensor_frames", broken)
    bb = MemoryBlackboard()
    bb.add(Camera("camera"))
    levels.post(bb.user, levels.Scenario(path=str(small_rendered["path"]), strategy="associative"))
    bb.run()
    levels.post(bb.user, levels.Index(shard=0, shards=1, viewframes=8))
    with pytest.raises(ValueError, match="small: sensor.frames: no such file"):
        bb.run()
    assert bb.hypotheses(levels.SENSOR_FRAME) == []
