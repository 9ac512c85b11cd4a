"""Levelling a camera image by its skyline match's roll and pitch (models.derotate), on real renders."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from models.camera_emulator import CameraEmulator
from models.derotate import level_image, level_pose
from models.environment import build_environment
from models.preprocess import preprocess
from models.scenario import scenario_from_dict
from models.skyline import SkylineMatch, match_skylines, skyline_from_depth, skyline_from_image

FOV = 45.0


@pytest.fixture(scope="module")
def emulator():
    s = scenario_from_dict(
        {
            "name": "level",
            "terrain": {"cell_size": 10.0, "procedural": {"size": 128, "relief": 120.0, "seed": 4}},
            "route": [[300, 300], [400, 400]],
            "camera": {"width": 160, "height": 120, "fov_y_deg": FOV, "eye_height": 2.0, "near": 1.0, "far": 5000.0},
        }
    )
    with CameraEmulator(build_environment(s), s.camera) as cam:
        yield cam


def _rolled(image: np.ndarray, angle: float) -> np.ndarray:
    """``image`` turned by OpenCV's ``angle`` (degrees, counter-clockwise as seen) about its centre."""
    h, w = image.shape[:2]
    rot = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), angle, 1.0)
    return cv2.warpAffine(image, rot, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _similarity(a: np.ndarray, b: np.ndarray) -> float:
    """Cosine of the two images' memory patterns at zero shift (the memory's comparison, bank of one)."""
    return float(np.sum(preprocess(a) * preprocess(b)))


@pytest.mark.parametrize("angle", [3.0, -3.0])
def test_a_known_roll_is_recovered_and_levelled(emulator, angle):
    """A rendered view turned by 3 degrees: the skyline match of the level references finds the
    roll (the camera's horizon falls to the right for a clockwise turn), and the levelled image
    matches the level view better than the rolled one, nearly as well as the view itself."""
    x, y, heading = 420.0, 380.0, 80.0
    refs = np.stack(
        [
            skyline_from_depth(emulator.render(emulator.pose_at(x, y, heading + d)).depth, fov_y_deg=FOV)
            for d in (-1.0, 0.0, 1.0)
        ]
    )
    level = emulator.render(emulator.pose_at(x, y, heading)).image
    rolled = _rolled(level, angle)
    m = match_skylines(skyline_from_image(rolled, fov_y_deg=FOV), refs, max_roll_deg=4.0)
    pose = level_pose(m, candidates=3)
    assert pose is not None
    roll, pitch = pose
    assert roll == pytest.approx(-angle, abs=0.7)
    assert abs(pitch) < 1.0
    levelled = level_image(rolled, m, fov_y_deg=FOV, candidates=3)
    assert levelled.shape == rolled.shape and levelled.dtype == rolled.dtype
    assert _similarity(levelled, level) > _similarity(rolled, level) + 0.3
    assert _similarity(levelled, level) > 0.8 * _similarity(level, level)


def test_a_known_pitch_moves_the_horizon_back_to_its_row():
    """(row, col) images: a camera pitched up by p sees the horizon f tan(p) rows lower; levelling
    with that pitch moves it back up by as many rows (the principal point is the image centre)."""
    h, w = 120, 160
    f = (h / 2) / math.tan(math.radians(FOV) / 2)
    pitch = 2.0
    row = 60 + round(f * math.tan(math.radians(pitch)))
    image = np.zeros((h, w), np.uint8)
    image[row:] = 200  # terrain below the horizon of a camera pitched up
    out = level_image(image, fov_y_deg=FOV, roll_deg=0.0, pitch_deg=pitch, pitch=True)
    first = int(np.argmax(out[:, w // 2] > 100))
    assert first == pytest.approx(60, abs=1)
    # without pitch=True the pitch is left to the memory's row search: unchanged
    assert np.array_equal(level_image(image, fov_y_deg=FOV, roll_deg=0.0, pitch_deg=pitch), image)


def test_a_match_that_cannot_say_leaves_the_image_alone():
    image = np.random.default_rng(0).integers(0, 255, (120, 160, 3), dtype=np.uint8)
    bad = SkylineMatch(
        error=np.array([1.6, 1.8]),
        heading_deg=np.zeros(2),
        pitch_deg=np.array([2.0, 2.0]),
        overlap=np.ones(2),
        roll_deg=np.array([3.0, 3.0]),
    )
    assert level_pose(bad) is None  # best error above LEVEL_MAX_ERROR_DEG: the horizon was not found
    assert level_image(image, bad, fov_y_deg=FOV) is image
    assert level_image(image, fov_y_deg=FOV) is image  # neither a match nor angles
    good = SkylineMatch(
        error=np.array([0.3, 0.4, 0.9]),
        heading_deg=np.zeros(3),
        pitch_deg=np.array([1.0, 1.2, -3.0]),
        overlap=np.ones(3),
        roll_deg=np.array([2.0, 2.4, -3.0]),
    )
    # the median over the best matches: the third (worst) does not move it
    assert level_pose(good, candidates=2) == pytest.approx((2.2, 1.1))


def test_bad_input_is_refused_naming_the_parameter():
    image = np.zeros((120, 160), np.uint8)
    with pytest.raises(ValueError, match="fov_y_deg"):
        level_image(image, fov_y_deg=0.0, roll_deg=1.0)
    with pytest.raises(ValueError, match="image must have shape"):
        level_image(np.zeros(5), fov_y_deg=FOV, roll_deg=1.0)
    m = SkylineMatch(np.zeros(1), np.zeros(1), np.zeros(1), np.ones(1), np.zeros(1))
    with pytest.raises(ValueError, match="candidates"):
        level_pose(m, candidates=0)


def test_the_memorys_roll_search_tolerates_a_rolled_camera(emulator):
    """Rendered views along a line (x, y, z world metres; heading ccw from +x); the camera frame
    is the view at one of them turned 2 degrees further and rolled by 3 degrees: with the roll
    search (the schema's default) its viewframe's error variance is lower than with the plain
    match, and it ranks first."""
    from models.index import ViewframeIndex
    from models.scenario import MemorySpec

    poses = [(300.0 + 12.0 * i, 320.0 + 9.0 * i, 37.0) for i in range(8)]
    views = [emulator.render(emulator.pose_at(x, y, h)).image for x, y, h in poses]
    x, y, h = poses[4]
    frame = _rolled(emulator.render(emulator.pose_at(x, y, h + 2.0)).image, 3.0)
    searched = ViewframeIndex(MemorySpec())
    plain = ViewframeIndex(MemorySpec(roll_search_deg=(0.0,)))
    assert 0.0 in MemorySpec().roll_search_deg and max(MemorySpec().roll_search_deg) >= 3.0
    for ix in (searched, plain):
        ix.add(views, range(len(views)))
    with_search, without = searched.rank(frame), plain.rank(frame)

    def variance(r):
        return float(r.variances[r.viewframes == 4][0])

    assert with_search.best == 4
    assert variance(with_search) < 0.6 * variance(without)
