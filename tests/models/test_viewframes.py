"""Route poses and a-priori viewframes."""

from __future__ import annotations

import numpy as np
import pytest

from models.camera_emulator import CameraEmulator
from models.environment import build_environment
from models.scenario import scenario_from_dict
from models.skyline import profile_bins, skyline_from_depth
from models.symbolic import SymbolicDescription
from models.viewframes import render_viewframes, route_headings, route_poses
from models.world import World


def _scenario(route, **extra):
    return scenario_from_dict(
        {
            "name": "vf",
            "terrain": {"cell_size": 10.0, "procedural": {"size": 64, "relief": 40.0, "seed": 2}},
            "landmarks": [{"id": "H1", "kind": "house", "x": 260.0, "y": 320.0, "width": 20, "depth": 12, "height": 8}],
            "route": route,
            "camera": {
                "width": 160,
                "height": 120,
                "fov_y_deg": 45,
                "eye_height": 2.0,
                "pitch_deg": 1.5,
                "near": 1.0,
                "far": 2000.0,
            },
            **extra,
        }
    )


def test_headings_point_to_the_next_point_and_the_last_keeps_its_own():
    assert route_headings([[0, 0], [10, 0], [10, 10], [0, 20]]) == pytest.approx([0.0, 90.0, 135.0, 135.0])


def test_route_poses_stand_on_the_ground():
    s = _scenario([[100, 100], [140, 130], [180, 130]])
    env = build_environment(s)
    poses = route_poses(s, env.terrain)
    assert len(poses) == 3
    for (x, y), p in zip(s.route, poses):
        assert (p.x, p.y) == (x, y)
        assert p.z == pytest.approx(env.terrain.height_at(x, y) + 2.0)
        assert p.pitch_deg == 1.5
    assert poses[0].heading_deg == pytest.approx(np.degrees(np.arctan2(30, 40)))


def test_the_world_renders_and_describes_each_route_point():
    s = _scenario([[200, 300], [240, 310], [300, 300]])
    with World(s) as world:
        frames = world.viewframes
    assert [f.index for f in frames] == [0, 1, 2]
    for f in frames:
        assert f.image.shape == (120, 160, 3) and f.mask.shape == (120, 160)
        assert isinstance(f.description, SymbolicDescription)
        # the skyline comes from the depth buffer: elevation per azimuth bin, NaN without a boundary
        assert f.skyline.dtype == np.float32 and f.skyline.shape == (profile_bins(160, 120, fov_y_deg=45),)
        np.testing.assert_array_equal(f.skyline, skyline_from_depth(f.depth, fov_y_deg=45))
    assert "H1" in frames[0].description.visible  # 60 m ahead, slightly left
    assert "H1" not in frames[2].description.visible  # already passed
    # with a caller's emulator: same pictures, and the emulator stays open
    env = build_environment(s)
    with CameraEmulator(env, s.camera) as cam:
        again = render_viewframes(cam, route_poses(s, env.terrain))
        np.testing.assert_array_equal(again[1].image, frames[1].image)
        cam.render(again[0].pose)


def test_route_outside_the_terrain_is_a_scenario_error():
    from models.errors import ScenarioError

    s = _scenario([[100, 100], [900, 100]])
    with pytest.raises(ScenarioError, match=r"route\[1\]: \(900, 100\) is outside the terrain \(x 0..630"):
        build_environment(s)
