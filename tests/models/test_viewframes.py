"""Route poses and a-priori viewframes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.camera_emulator import CameraEmulator
from models.environment import build_environment
from models.scenario import scenario_from_dict
from models.skyline import profile_bins, skyline_from_depth
from models.symbolic import SymbolicDescription
from models.viewframes import render_viewframes, render_viewframes_parallel, route_headings, route_poses
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
    s = _scenario([[200, 300], [240, 310], [300, 300]], render={"views_per_leg": 1})
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


def _equal(a, b) -> bool:
    return (
        a.index == b.index
        and a.pose == b.pose
        and np.array_equal(a.image, b.image)
        and np.array_equal(a.depth, b.depth)
        and np.array_equal(a.mask, b.mask)
        and np.array_equal(a.skyline, b.skyline, equal_nan=True)
        and a.description == b.description
        and ((a.background is None and b.background is None) or np.array_equal(a.background, b.background))
    )


def test_worker_processes_render_the_same_viewframes_as_one_process():
    route = [[150.0 + 25.0 * i, 300.0 + 10.0 * math.sin(i / 2.0)] for i in range(14)]
    s = _scenario(route)
    env = build_environment(s)
    poses = route_poses(s, env.terrain)
    with CameraEmulator(env, s.camera) as cam:
        serial = render_viewframes(cam, poses)
    seen = []
    # chunks of 3 poses: every worker renders several shares, out of route order
    parallel = render_viewframes_parallel(
        env, s.camera, poses, workers=2, chunk=3, progress=lambda done, total: seen.append((done, total))
    )
    assert [f.index for f in parallel] == list(range(14))
    assert any(f.background is not None for f in serial) and any("H1" in f.description.visible for f in serial)
    assert all(_equal(a, b) for a, b in zip(serial, parallel))
    assert seen[-1] == (14, 14) and [d for d, _ in seen] == sorted(d for d, _ in seen)


def test_the_world_renders_in_workers_when_the_scenario_says_so():
    route = [[150.0 + 30.0 * i, 300.0] for i in range(6)]
    with World(_scenario(route), cache=None) as one:
        serial = one.viewframes
    with World(_scenario(route, render={"workers": 2}), cache=None) as world:
        assert world.scenario.render.worker_count(len(route)) == 2
        assert all(_equal(a, b) for a, b in zip(serial, world.viewframes))
        assert world._emulator is None  # no renderer opened in this process


def test_render_workers_default_to_one_per_share_of_the_route_at_most_the_cpus():
    import os

    from models.scenario import RenderSpec

    cpus = len(os.sched_getaffinity(0))
    spec = RenderSpec()
    assert spec.worker_count(10) == 1  # short routes render in the calling process
    assert spec.worker_count(spec.viewframes_per_worker * 2) == min(2, cpus)
    assert spec.worker_count(10**6) == cpus
    assert RenderSpec(workers=3).worker_count(2) == 2  # never more workers than viewframes
    with pytest.raises(ValueError, match="workers"):
        RenderSpec(workers=0)


def test_a_failing_worker_is_a_render_error_naming_the_cause():
    from models.errors import RenderError

    s = _scenario([[150.0, 300.0], [180.0, 300.0]])
    env = build_environment(s)
    with pytest.raises(RenderError, match="worker processes failed: AttributeError"):
        render_viewframes_parallel(env, None, route_poses(s, env.terrain), workers=2)  # no camera


def test_workers_start_from_a_script_without_a_main_guard(tmp_path):
    """A worker is a fresh ``python -m models.render_worker``: it never imports the caller's
    script again (a multiprocessing pool would, and a script without ``if __name__ ==
    "__main__"`` would run twice and fail)."""
    import subprocess
    import sys
    from pathlib import Path

    script = tmp_path / "unguarded.py"
    script.write_text(
        "import sys\n"
        "from models.environment import build_environment\n"
        "from models.scenario import scenario_from_dict\n"
        "from models.viewframes import render_viewframes_parallel, route_poses\n"
        "s = scenario_from_dict({'name': 'u', 'terrain': {'cell_size': 10.0, 'procedural': {'size': 48,"
        " 'relief': 20.0, 'seed': 1}}, 'route': [[100, 200], [130, 200], [160, 210], [190, 200]],"
        " 'camera': {'width': 32, 'height': 24, 'fov_y_deg': 45, 'eye_height': 2.0, 'near': 1.0, 'far': 500.0}})\n"
        "env = build_environment(s)\n"
        "frames = render_viewframes_parallel(env, s.camera, route_poses(s, env.terrain), workers=2, chunk=1)\n"
        "print('rendered', [f.index for f in frames])\n"
    )
    root = Path(__file__).resolve().parents[2]
    done = subprocess.run(
        [sys.executable, str(script)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env={**__import__("os").environ, "PYTHONPATH": str(root)},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().splitlines()[-1] == "rendered [0, 1, 2, 3]"
