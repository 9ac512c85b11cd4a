from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from models.errors import InputError
from models.scenario import SimulateSpec, scenario_from_dict
from models.sensor import degrade, load_frame_image, simulate_frames
from models.world import World

CAMERA = {"width": 160, "height": 120, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 5000.0}


def _scenario(tmp_path: Path, sensor: dict, **extra):
    data = {
        "name": "sensor-test",
        "seed": 5,
        "terrain": {"cell_size": 10.0, "procedural": {"size": 64, "relief": 40.0, "seed": 2}},
        "landmarks": [{"id": "H1", "kind": "house", "x": 330, "y": 300, "width": 20, "depth": 12, "height": 8}],
        "route": [[200, 300], [250, 300], [300, 320]],
        "camera": CAMERA,
        "sensor": sensor,
        **extra,
    }
    return scenario_from_dict(data, path=tmp_path / "s.yaml")


@pytest.mark.parametrize(
    "make, ext",
    [
        (lambda rng: rng.integers(0, 256, (60, 80), dtype=np.uint8), ".png"),  # gray, smaller
        (lambda rng: rng.integers(0, 256, (240, 320, 3), dtype=np.uint8), ".png"),  # colour, larger
        (lambda rng: rng.integers(0, 256, (120, 160, 4), dtype=np.uint8), ".png"),  # with alpha
        (lambda rng: rng.integers(0, 256, (120, 160, 3), dtype=np.uint8), ".jpg"),
        (lambda rng: (rng.integers(0, 65535, (120, 160))).astype(np.uint16), ".png"),  # 16-bit
    ],
)
def test_load_frame_image_any_format_to_camera_size(tmp_path, make, ext):
    data = make(np.random.default_rng(1))
    path = tmp_path / f"f{ext}"
    assert cv2.imwrite(str(path), data)
    img = load_frame_image(path, width=160, height=120)
    assert img.shape == (120, 160, 3) and img.dtype == np.uint8


def test_load_frame_image_keeps_colour_order(tmp_path):
    rgb = np.zeros((120, 160, 3), np.uint8)
    rgb[..., 0] = 200  # red
    cv2.imwrite(str(tmp_path / "red.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    img = load_frame_image(tmp_path / "red.png", width=160, height=120)
    assert img[..., 0].mean() == 200 and img[..., 2].mean() == 0


@pytest.mark.parametrize(
    "content, message",
    [(None, "not found"), (b"this is not a png", "not a readable image")],
)
def test_load_frame_image_errors_name_the_file(tmp_path, content, message):
    path = tmp_path / "frame.png"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError, match=message) as err:
        load_frame_image(path, width=160, height=120)
    assert err.value.path == path
    assert "frame.png" in str(err.value)


def test_degrade_is_seeded_and_changes_the_image():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    spec = SimulateSpec()
    a = degrade(image, spec=spec, rng=11)
    b = degrade(image, spec=spec, rng=11)
    c = degrade(image, spec=spec, rng=12)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.abs(a.astype(int) - image).mean() > 2


def test_degrade_with_zero_strengths_is_identity():
    image = np.random.default_rng(3).integers(0, 256, (40, 50, 3), dtype=np.uint8)
    spec = SimulateSpec(lighting=0, haze=0, gain=0, gamma=0, noise=0, blur=0, texture=0)
    assert np.array_equal(degrade(image, spec=spec, rng=1), image)


def test_haze_brightens_distant_pixels_more():
    image = np.full((20, 20, 3), 40, np.uint8)
    depth = np.full((20, 20), 10.0, np.float32)
    depth[:, 10:] = 3000.0
    spec = SimulateSpec(haze=0.6, gain=0, gamma=0, noise=0, blur=0, texture=0)
    out = degrade(image, depth=depth, spec=spec, rng=1)
    assert out[:, 10:].mean() > out[:, :10].mean() + 20


def test_degrade_rejects_gray_input():
    with pytest.raises(ValueError, match="image must have shape"):
        degrade(np.zeros((10, 10), np.uint8), spec=SimulateSpec())


@pytest.mark.slow
def test_simulated_frames_near_route_points_and_reproducible(tmp_path):
    from models.camera_emulator import CameraEmulator
    from models.environment import build_environment
    from models.viewframes import route_poses

    sim = {"per_point": 2, "jitter_m": 1.0, "jitter_deg": 2.0, "advance": 0.2}
    scenario = _scenario(tmp_path, {"simulate": sim})
    env = build_environment(scenario)
    with CameraEmulator(env, scenario.camera) as cam:
        poses = route_poses(scenario, env.terrain)
        first = simulate_frames(scenario, cam, poses)
        second = simulate_frames(scenario, cam, poses)
        exact = cam.render(poses[0]).image
    assert len(first) == 2 * len(scenario.route)
    for f, g in zip(first, second):
        assert np.array_equal(f.image, g.image) and f.truth == g.truth
    for f in first:
        i = f.index // 2
        x, y, heading = f.truth
        leg = math.dist(scenario.route[min(i + 1, 2)], scenario.route[i]) or 50.0
        assert math.dist((x, y), scenario.route[i]) <= 0.2 * leg + 5 * 1.0
        assert abs((heading - poses[i].heading_deg + 180) % 360 - 180) <= 5 * 2.0
        assert f.image.shape == (120, 160, 3)
    # like the viewframe, but not the same picture
    diff = np.abs(first[0].image.astype(int) - exact).mean()
    assert 1.0 < diff < 60.0


@pytest.mark.slow
@pytest.mark.parametrize("stride, per_point, points", [(1, 1, [0, 1, 2]), (2, 1, [0, 2]), (2, 3, [0, 0, 0, 2, 2, 2])])
def test_simulate_stride_and_per_point(tmp_path, stride, per_point, points):
    scenario = _scenario(
        tmp_path, {"simulate": {"stride": stride, "per_point": per_point, "jitter_m": 0.0, "advance": 0.0}}
    )
    with World(scenario) as world:
        frames = world.sensor_frames
    assert [f.index for f in frames] == list(range(len(points)))
    nearest = [min(range(3), key=lambda i: math.dist(f.truth[:2], scenario.route[i])) for f in frames]
    assert nearest == points


def test_sensor_frames_from_files_with_truth(tmp_path):
    (tmp_path / "frames").mkdir()
    for i in range(2):
        cv2.imwrite(str(tmp_path / "frames" / f"f{i}.png"), np.full((60, 80), 100 + i, np.uint8))
    scenario = _scenario(
        tmp_path,
        {
            "frames": [
                {"image": "frames/f0.png", "truth": {"x": 1.0, "y": 2.0, "heading_deg": 3.0}},
                {"image": "frames/f1.png"},
            ]
        },
    )
    world = World(scenario)
    frames = world.sensor_frames
    assert "environment" not in vars(world), "frames on file need no environment model or renderer"
    assert [f.index for f in frames] == [0, 1]
    assert frames[0].truth == (1.0, 2.0, 3.0) and frames[1].truth is None
    assert frames[1].image.shape == (120, 160, 3) and frames[1].image.mean() == 101


# -- drives ------------------------------------------------------------------------------------

from models.scenario import DriveSpec  # noqa: E402
from models.sensor import drive_poses  # noqa: E402

DRIVE_ROUTE = [(0.0, 0.0), (40.0, 0.0), (80.0, 10.0), (120.0, 40.0), (160.0, 40.0), (200.0, 60.0), (240.0, 60.0)]


def _distance_to_route(x: float, y: float, route) -> float:
    pts = np.asarray(route, float)
    best = math.inf
    for a, b in zip(pts, pts[1:]):
        d = b - a
        u = float(np.clip(np.dot([x, y] - a, d) / np.dot(d, d), 0, 1))
        best = min(best, float(np.hypot(*(a + u * d - [x, y]))))
    return best


def test_drive_times_increase_and_poses_lie_between_route_points():
    spec = DriveSpec(interval_s=1.0, speed_mps=(4.0, 12.0), p_stop=0.2, lateral_m=1.0, heading_deg=2.0)
    poses = drive_poses(DRIVE_ROUTE, spec, rng=3)
    times = [p.time for p in poses]
    assert all(b > a for a, b in zip(times, times[1:]))
    arcs = [p.arc_m for p in poses]
    assert all(b >= a for a, b in zip(arcs, arcs[1:]))  # forward or stopped, never back
    assert any(b == a for a, b in zip(arcs, arcs[1:]))  # with p_stop 0.2 it stops somewhere
    steps = np.diff(arcs)
    assert steps.max() <= 12.0 + 1e-9
    # off the route by the lateral error only (4 sigma), and mostly between route points
    assert max(_distance_to_route(p.x, p.y, DRIVE_ROUTE) for p in poses) < 4.0
    nearest = [min(np.hypot(p.x - x, p.y - y) for x, y in DRIVE_ROUTE) for p in poses]
    assert np.median(nearest) > 3.0
    assert len(poses) > 20


def test_drive_kidnapping_jumps_far():
    spec = DriveSpec(interval_s=1.0, speed_mps=(5.0, 5.0), p_stop=0.0, kidnap_at=5, frames=12)
    poses = drive_poses(DRIVE_ROUTE, spec, rng=1)
    assert len(poses) == 12
    assert [p.kidnapped for p in poses].index(True) == 5
    total = 40 + math.hypot(40, 10) + math.hypot(40, 30) + 40 + math.hypot(40, 20) + 40
    assert abs(poses[5].arc_m - poses[4].arc_m) >= 0.25 * total - 5.0 - 1e-6


def test_drive_frames_are_rendered_with_their_times(tmp_path):
    sc = _scenario(
        tmp_path, {"simulate": {"drive": {"interval_s": 0.5, "speed_mps": [20, 30], "p_stop": 0, "frames": 4}}}
    )
    with World(sc) as world:
        frames = world.sensor_frames
    assert [f.time for f in frames] == [0.0, 0.5, 1.0, 1.5]
    assert all(f.image.shape == (120, 160, 3) for f in frames)
    xs = [f.truth[0] for f in frames]
    assert all(b > a for a, b in zip(xs, xs[1:]))  # this route heads east


def test_frame_files_carry_times_in_order(tmp_path):
    img = np.zeros((120, 160, 3), np.uint8)
    for name in ("a.png", "b.png"):
        cv2.imwrite(str(tmp_path / name), img)
    sc = _scenario(tmp_path, {"frames": [{"image": "a.png", "time": 1.0}, {"image": "b.png", "time": 2.5}]})
    assert [f.time for f in World(sc).sensor_frames] == [1.0, 2.5]
    from models.errors import ScenarioError

    with pytest.raises(ScenarioError, match=r"frames\[1\].time"):
        _scenario(tmp_path, {"frames": [{"image": "a.png", "time": 3.0}, {"image": "b.png", "time": 2.5}]})
