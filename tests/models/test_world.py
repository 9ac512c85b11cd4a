"""A scenario's world: one object owns the environment, the emulator, the poses, the viewframes
and the camera frames, each built once, on first use."""

from __future__ import annotations

import numpy as np
import pytest

from models.camera_emulator import CameraEmulator
from models.environment import build_environment
from models.route_views import view_count, view_poses
from models.scenario import scenario_from_dict
from models.sensor import simulate_frames
from models.symbolic import landmark_priors
from models.viewframes import render_viewframes, route_poses
from models.world import World


def _scenario(**extra):
    return scenario_from_dict(
        {
            "name": "world",
            "seed": 4,
            "terrain": {"cell_size": 10.0, "procedural": {"size": 64, "relief": 40.0, "seed": 2}},
            "landmarks": [{"id": "H1", "kind": "house", "x": 260.0, "y": 320.0, "width": 20, "depth": 12, "height": 8}],
            "route": [[200, 300], [240, 310], [300, 300]],
            "camera": {"width": 96, "height": 72, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 2000.0},
            **extra,
        }
    )


@pytest.mark.slow
@pytest.mark.parametrize("views", [1, 3])
def test_the_world_is_the_pipeline_done_by_hand(views):
    scenario = _scenario(sensor={"simulate": {"per_point": 1}}, render={"views_per_leg": views})
    with World(scenario) as world:
        viewframes, frames, poses = world.viewframes, world.sensor_frames, world.poses
        assert world.viewframes is viewframes and world.environment is world.emulator.environment  # built once
    env = build_environment(scenario)
    with CameraEmulator(env, scenario.camera) as cam:
        by_hand_poses = view_poses(scenario, env.terrain)
        by_hand = render_viewframes(cam, by_hand_poses)
        # the camera frames are taken at the route points, whatever the viewframes
        by_hand_frames = simulate_frames(scenario, cam, route_poses(scenario, env.terrain))
    assert poses == by_hand_poses
    assert [vf.index for vf in viewframes] == list(range(view_count(3, views)))
    for a, b in zip(viewframes, by_hand):
        np.testing.assert_array_equal(a.mask, b.mask)
        assert np.abs(a.image.astype(int) - b.image).mean() < 0.5
        assert a.description.visible == b.description.visible
    assert [f.truth for f in frames] == [f.truth for f in by_hand_frames]
    assert world.priors == landmark_priors([vf.description for vf in by_hand], landmark_ids=["H1"])


def test_parts_are_built_on_first_use_and_close_releases_the_renderer():
    world = World(_scenario())
    assert world.sensor_frames == []  # no sensor block: nothing to render
    assert "environment" not in vars(world) and world._emulator is None
    emulator = world.emulator
    assert world.emulator is emulator
    world.close()
    assert world._emulator is None and emulator._renderer is None
    world.close()  # twice is fine


def test_from_scenario_loads_a_file(tmp_path):
    import yaml

    path = tmp_path / "w.yaml"
    data = _scenario().model_dump(mode="json", exclude_none=True)
    path.write_text(yaml.safe_dump(data))
    world = World.from_scenario(path)
    assert world.scenario.name == "world" and world.scenario.path == path


def test_worlds_of_one_scenario_alive_at_once_share_its_terrain_and_environment(tmp_path):
    """The map renderer, the camera and the refiner of a mission each make a world of the scenario:
    while one is alive, the others get its terrain and environment (built once, also when asked
    from several threads at once); a world of another scenario, of other level-of-detail options
    or of a changed DEM file builds its own, and nothing is kept once the worlds are gone; the
    shared environment renders what a world's own does."""
    import gc
    import threading
    import weakref

    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(3).normal(0.0, 5.0, (48, 48)))
    on_dem = {"terrain": {"cell_size": 10.0, "dem": str(dem)}}
    first, second = World(_scenario()), World(_scenario())
    built: dict[int, object] = {}
    threads = [
        threading.Thread(target=lambda i=i, w=w, b=built: b.update({i: w.environment}))
        for i, w in enumerate((first, second))
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert built[0] is built[1] and first.terrain is second.terrain and first.environment.terrain is first.terrain
    moved = [{"id": "H1", "kind": "house", "x": 261.0, "y": 320.0, "width": 20, "depth": 12, "height": 8}]
    other = World(_scenario(landmarks=moved))
    assert other.environment is not first.environment and other.terrain is not first.terrain
    coarse = World(_scenario(), levels=2)
    assert coarse.environment is not first.environment and coarse.terrain is first.terrain  # lod: not the terrain
    on_file = World(_scenario(**on_dem))
    heights = on_file.terrain.heights.copy()
    np.save(dem, heights + 1.0)  # the file changed: another terrain
    assert np.array_equal(World(_scenario(**on_dem)).terrain.heights, heights + 1.0)
    with first:
        view = first.emulator.render(first.emulator.pose_at(240.0, 310.0, 10.0))
    gone = weakref.ref(first.environment)
    del first, second, built, threads, other, coarse
    gc.collect()
    assert gone() is None  # no world uses it: not kept
    with World(_scenario()) as own:
        own.__dict__["environment"] = build_environment(own.scenario, terrain=own.terrain)  # its own
        mine = own.emulator.render(own.emulator.pose_at(240.0, 310.0, 10.0))
    assert np.array_equal(view.image, mine.image) and np.array_equal(view.depth, mine.depth)
