"""Camera emulator: the pinhole geometry contract on real pyrender (EGL) renders."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from models.camera_emulator import CameraEmulator, Pose
from models.environment import EnvironmentModel
from models.landmarks import place_landmarks
from models.scenario import CameraSpec, LandmarkSpec
from models.terrain import Terrain

CAMERA = CameraSpec(width=160, height=120, fov_y_deg=45.0, eye_height=2.0, near=1.0, far=3000.0)
F = 60.0 / math.tan(math.radians(22.5))  # fy = (H / 2) / tan(fov_y / 2) = 144.85 px


@pytest.fixture(scope="module")
def flat():
    """Flat ground at z = 0 (1 km square) with one box 100 m east of (100, 500)."""
    terrain = Terrain(heights=np.zeros((101, 101)), cell_size=10.0)
    lms = place_landmarks(terrain, [LandmarkSpec(id="A", kind="house", x=200, y=500, width=10, depth=20, height=10)])
    with CameraEmulator(EnvironmentModel(terrain, lms), CAMERA) as cam:
        yield cam


def test_intrinsics_are_the_documented_pinhole(flat):
    fx, fy, cx, cy = flat.intrinsics
    assert fx == pytest.approx(F) and fy == pytest.approx(F)
    assert (cx, cy) == (79.5, 59.5)


def test_pose_at_stands_on_the_ground(flat):
    p = flat.pose_at(123.0, 456.0, 30.0)
    assert p == Pose(123.0, 456.0, 2.0, 30.0, 0.0)
    assert flat.pose_at(1.0, 2.0, 0.0, pitch_deg=-5.0).pitch_deg == -5.0


def test_box_projects_to_the_hand_computed_rectangle(flat):
    pose = Pose(100.0, 500.0, 2.0, 0.0)  # looking east along +x
    view = flat.render(pose)
    assert view.image.shape == (120, 160, 3) and view.image.dtype == np.uint8
    assert view.mask.dtype == np.int32 and view.depth.dtype == np.float32
    rows, cols = np.nonzero(view.mask == 0)
    # front face at x = 195 (95 m ahead): y 490..510 -> col 79.5 -/+ F * 10 / 95; z 0..10 -> row 59.5 + F * (2 - z) / 95
    col0, col1 = 79.5 - F * 10 / 95, 79.5 + F * 10 / 95
    row0, row1 = 59.5 - F * 8 / 95, 59.5 + F * 2 / 95
    assert (rows.min(), rows.max()) == (math.ceil(row0), math.floor(row1))
    assert abs(cols.min() - math.ceil(col0)) <= 1 and abs(cols.max() - math.floor(col1)) <= 1
    # the same rectangle from the emulator's own projection of the box corners
    lm = flat.environment.landmarks[0]
    rc = flat.project(lm.box_vertices(), pose)
    assert rc[:, 0].min() == pytest.approx(row0) and rc[:, 0].max() == pytest.approx(row1)
    assert rc[:, 1].min() == pytest.approx(col0) and rc[:, 1].max() == pytest.approx(col1)
    # depth is metres along the view axis: 95 on the face, 0 in the sky
    assert view.depth[55, 80] == pytest.approx(95.0, abs=0.05)
    assert view.depth[0, 0] == 0.0 and (view.mask[:40] == -1).all()
    # flat ground below the horizon: depth = eye height * F / (row - cy), whatever the column
    for row in (64, 70, 100, 119):
        np.testing.assert_allclose(view.depth[row, [3, 150]], 2.0 * F / (row - 59.5), rtol=2e-3)


@pytest.mark.parametrize(
    ("heading", "visible"), [(0.0, True), (90.0, False), (180.0, False), (-20.0, True), (40.0, False), (20.0, True)]
)
def test_heading_is_counterclockwise_from_east(flat, heading, visible):
    view = flat.render(Pose(100.0, 500.0, 2.0, heading))
    assert (view.mask == 0).any() == visible
    if heading == -20.0:  # turned right (clockwise): the box moves to the left half
        assert np.nonzero(view.mask == 0)[1].mean() < 79.5


def test_box_north_of_camera_seen_when_heading_90(flat):
    view = flat.render(Pose(200.0, 300.0, 2.0, 90.0))
    cols = np.nonzero(view.mask == 0)[1]
    assert abs(cols.mean() - 79.5) < 2  # straight ahead


def test_pitch_up_moves_the_scene_down(flat):
    level = flat.render(Pose(100.0, 500.0, 2.0, 0.0))
    up = flat.render(Pose(100.0, 500.0, 2.0, 0.0, pitch_deg=5.0))
    r_level = np.nonzero(level.mask == 0)[0].mean()
    r_up = np.nonzero(up.mask == 0)[0].mean()
    assert r_up - r_level == pytest.approx(F * math.tan(math.radians(5.0)), abs=1.5)


def test_project_gives_nan_behind_the_camera(flat):
    pose = Pose(100.0, 500.0, 2.0, 0.0)
    rc = flat.project(np.array([[200.0, 500.0, 2.0], [50.0, 500.0, 2.0]]), pose)
    np.testing.assert_allclose(rc[0], [59.5, 79.5])
    assert np.isnan(rc[1]).all()


def test_views_are_reproducible_and_lighting_changes_only_the_image(flat):
    pose = Pose(100.0, 500.0, 2.0, 5.0)
    a = flat.render(pose)
    flat.render(Pose(300.0, 300.0, 2.0, 120.0))  # something else in between
    b = flat.render(pose)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.mask, b.mask)
    dim = flat.render(pose, light_intensity=0.1, light_direction=(0.0, 0.0, -1.0))
    np.testing.assert_array_equal(dim.mask, a.mask)
    np.testing.assert_allclose(dim.depth, a.depth)
    ground = a.mask == -1
    ground &= a.depth > 0
    assert dim.image[ground].mean() < a.image[ground].mean() - 10
    c = flat.render(pose)
    np.testing.assert_array_equal(c.image, a.image)  # defaults restored


def test_background_leaves_the_landmark_out_and_the_rest_alone(flat):
    pose = Pose(100.0, 500.0, 2.0, 5.0)
    view = flat.render(pose)
    bare = flat.render_background(pose)
    box = view.mask == 0
    assert box.sum() > 50
    diff = np.abs(bare.astype(int) - view.image.astype(int)).sum(axis=2)
    # where the box was, the ground or the sky behind it (nothing of the box's colour is left)
    assert (diff[box] > 30).mean() > 0.9
    # elsewhere the same picture, but for antialiased pixels along the box's outline
    near_box = cv2.dilate(box.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    assert diff[~near_box].max() <= 2
    np.testing.assert_array_equal(flat.render(pose).image, view.image)  # the boxes come back


def test_closed_emulator_refuses_to_render():
    from models.errors import RenderError

    terrain = Terrain(heights=np.zeros((3, 3)), cell_size=10.0)
    cam = CameraEmulator(EnvironmentModel(terrain, []), CAMERA)
    cam.close()
    cam.close()
    with pytest.raises(RenderError, match="closed"):
        cam.render(Pose(5.0, 5.0, 2.0, 0.0))


def test_camera_never_under_the_drawn_ground():
    """Rough terrain: the camera stands on the bilinear F, the mesh must stay below it."""
    rng = np.random.default_rng(3)
    terrain = Terrain(heights=rng.uniform(0, 40, (33, 33)), cell_size=20.0)
    with CameraEmulator(EnvironmentModel(terrain, [], tile_cells=16), CAMERA) as cam:
        for x, y, h in rng.uniform([50, 50, 0], [590, 590, 360], (6, 3)):
            view = cam.render(cam.pose_at(x, y, h, pitch_deg=-60.0))  # look down at the feet
            assert (view.depth > 0).all()  # ground everywhere, never sky seen through it


@pytest.fixture(scope="module")
def hills():
    from models.terrain import procedural_terrain

    terrain = procedural_terrain(size=128, relief=60.0, cell_size=10.0, rng=4)
    lms = place_landmarks(
        terrain,
        [
            LandmarkSpec(id="H", kind="house", x=700, y=640, width=20, depth=12, height=8),
            LandmarkSpec(id="T", kind="tower", x=900, y=700, width=4, depth=4, height=30),
        ],
    )
    return terrain, lms


def test_level_of_detail_follows_distance_and_culls_behind(hills):
    terrain, lms = hills
    env = EnvironmentModel(terrain, lms, tile_cells=16)
    pose = Pose(600.0, 600.0, float(terrain.height_at(600, 600)) + 2, 0.0)
    fy = math.tan(math.radians(22.5))
    levels = env.tile_levels(pose.position, pose.rotation(), tan_half_fov=(fy * 4 / 3, fy), far=3000.0)
    centres = np.array([[(t.bounds[0] + t.bounds[1]) / 2, (t.bounds[2] + t.bounds[3]) / 2] for t in env.tiles])
    ahead = centres[:, 0] - 600.0
    assert (levels[ahead < -100] == -1).all()  # behind the camera: not drawn
    shown = levels >= 0
    assert levels[shown].min() == 0 and levels[shown].max() >= 2
    # farther tiles never get a finer level than nearer ones straight ahead
    row = np.abs(centres[:, 1] - 600.0) < 16 * 10
    order = np.argsort(ahead[row & shown])
    assert (np.diff(levels[row & shown][order]) >= 0).all()


def test_level_of_detail_keeps_the_picture(hills):
    terrain, lms = hills
    with (
        CameraEmulator(EnvironmentModel(terrain, lms, tile_cells=16), CAMERA) as lod,
        CameraEmulator(EnvironmentModel(terrain, lms, tile_cells=16, levels=1), CAMERA) as full,
    ):
        for x, y, h in [(600, 600, 20.0), (650, 560, 60.0), (300, 900, -30.0)]:
            a, b = lod.render(lod.pose_at(x, y, h)), full.render(full.pose_at(x, y, h))
            assert lod.triangles_last < full.triangles_last
            assert (a.mask == b.mask).mean() > 0.995
            ground = (a.depth > 0) & (b.depth > 0)
            rel = np.abs(a.depth[ground] - b.depth[ground]) / b.depth[ground]
            assert np.percentile(rel, 99) < 0.05
            assert ((a.depth > 0) == (b.depth > 0)).mean() > 0.99  # same skyline


def test_closing_one_emulator_leaves_another_working(caplog):
    terrain = Terrain(heights=np.zeros((11, 11)), cell_size=10.0)
    a = CameraEmulator(EnvironmentModel(terrain, []), CAMERA)
    b = CameraEmulator(EnvironmentModel(terrain, []), CAMERA)
    a.close()
    del a
    import gc

    gc.collect()  # pyrender's own __del__ must not terminate the shared EGL display
    view = b.render(Pose(10.0, 50.0, 2.0, 0.0))
    assert (view.depth[-1] > 0).all()
    b.close()
    assert "closing the offscreen renderer" not in caplog.text


def test_an_emulator_never_closed_leaves_another_working_when_collected():
    """An emulator dropped without close() (an agent that never shut down, a test's leftover) is
    collected at whatever moment: it must not terminate the shared EGL display (pyrender's own
    __del__ does) nor take the GL context of a renderer in use."""
    import gc

    terrain = Terrain(heights=np.zeros((11, 11)), cell_size=10.0)
    b = CameraEmulator(EnvironmentModel(terrain, []), CAMERA)
    before = b.render(Pose(10.0, 50.0, 2.0, 0.0))
    a = CameraEmulator(EnvironmentModel(terrain, []), CAMERA)
    a.render(Pose(20.0, 50.0, 2.0, 90.0))
    b.render(Pose(10.0, 50.0, 2.0, 0.0))  # b's context current (its GL objects' ids are a's too)
    del a
    gc.collect()
    after = b.render(Pose(10.0, 50.0, 2.0, 0.0))
    np.testing.assert_array_equal(after.image, before.image)
    np.testing.assert_array_equal(after.depth, before.depth)
    b.close()


def test_shader_folder_is_shared_by_processes_and_outlives_them(tmp_path):
    """Two fresh processes render with one content-named shader folder and leave no other folder."""
    import os
    import subprocess
    import sys

    code = (
        "from models.camera_emulator import _lambert_shader_dir\n"
        "import pathlib; d = pathlib.Path(_lambert_shader_dir()); print(d)\n"
        "assert (d / 'mesh.frag').read_text().count('ambient_light') > 0\n"
    )
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    dirs = [
        subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout.strip()
        for _ in range(2)
    ]
    assert dirs[0] == dirs[1]
    assert sorted(p.name for p in tmp_path.iterdir()) == [os.path.basename(dirs[0])]


def test_views_do_not_depend_on_the_history_of_views():
    """A view is the same bytes whatever was rendered before it, in this emulator or another one:
    the drawing order of equally distant nodes (every terrain tile) is fixed, not a set's."""
    from models.world import World

    with World.from_scenario("scenarios/jacksboro.yaml", cache=None) as world:
        poses = world.poses[:12]
        forward = [world.emulator.render(p) for p in poses]
        keys = [world.emulator.scene._order[n] for n in world.emulator.scene.mesh_nodes]
        with CameraEmulator(world.environment, world.emulator.camera) as other:
            backward = [other.render(p) for p in reversed(poses)][::-1]
            other.render(poses[-1])
            keys_backward = [other.scene._order[n] for n in other.scene.mesh_nodes]
    assert keys == sorted(keys)
    assert keys_backward == keys
    for a, b in zip(forward, backward):
        assert np.array_equal(a.image, b.image)
        assert np.array_equal(a.depth, b.depth)
        assert np.array_equal(a.mask, b.mask)


def _views(cam, poses):
    out = []
    for p in poses:
        v = cam.render(p)
        out.append((v.image, v.depth, v.mask, cam.render_background(p)))
    return out


def test_the_draw_caches_leave_every_pixel_as_pyrender_draws_it(hills):
    """The emulator's uniform, shader-program and pose caches skip only work whose result is
    already in place: the images, depth maps, masks and backgrounds equal those of pyrender's own
    shader programs, renderer and scene pose lookup, pixel for pixel, across a walk that changes
    the level of detail and the landmarks drawn, and interleaved with a second emulator."""
    import pyrender
    from pyrender.shader_program import ShaderProgramCache

    from models import camera_emulator

    terrain, lms = hills
    env = EnvironmentModel(terrain, lms, tile_cells=16)
    rng = np.random.default_rng(8)
    with CameraEmulator(env, CAMERA) as stock, CameraEmulator(env, CAMERA) as ours:
        inner = stock._renderer._renderer
        assert type(inner) is not pyrender.renderer.Renderer  # the caching renderer is in place
        inner.__class__ = pyrender.renderer.Renderer
        inner._program_cache = ShaderProgramCache(shader_dir=camera_emulator._lambert_shader_dir())

        class _StockPoses(camera_emulator._ActiveScene):
            def get_pose(self, node):
                return pyrender.Scene.get_pose(self, node)

        stock.scene.__class__ = _StockPoses
        poses = [ours.pose_at(x, y, h) for x, y, h in rng.uniform([500, 500, -40], [800, 800, 80], (12, 3))]
        poses += [ours.pose_at(600.0, 600.0, 20.0, pitch_deg=p) for p in (-3.0, 0.0, 4.0)]
        for a, b in zip(_views(stock, poses), _views(ours, poses)):
            for x, y in zip(a, b):
                np.testing.assert_array_equal(x, y)
        assert any((b[2] >= 0).any() for b in _views(ours, poses[:6]))  # landmarks were in view
