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
