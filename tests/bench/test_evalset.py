"""The evaluation set's generator: deterministic by seed, splits apart, truth within its bounds,
the independent renderer at the requested sizes and in agreement with the viewframes' geometry."""

from __future__ import annotations

import dataclasses
import itertools
import math

import cv2
import numpy as np
import pytest

from bench.evalset import ERROR_BOUNDS, ERROR_PROFILES, SPLITS, TERRAINS, TUNING_SPLITS, case_names, cases, seeds
from bench.evalset.cases import _drive_poses, _polyline, _sweep_poses
from bench.evalset.raster import KIND_COLOURS, Block, Rasteriser
from bench.evalset.raster import Look as RasterLook
from bench.evalset.raster import Sensor as RasterSensor
from bench.evalset.raster import sensor_effects as raster_sensor_effects
from bench.evalset.raycast import Box, Look, RayCaster, Sensor, World, sensor_effects
from bench.evalset.terrains import FAMILIES
from models.scenario import load_scenario

SMALL = "h-fbm-rough"  # 200x150 camera frames: the quickest to render


def _files(case):
    return {f.image.name: f.image.read_bytes() for f in case.frames}


def test_same_seed_same_files(tmp_path):
    a = next(cases("heldout", out_dir=tmp_path / "a", names=[SMALL], max_frames=2))
    b = next(cases("heldout", out_dir=tmp_path / "b", names=[SMALL], max_frames=2))
    assert _files(a) == _files(b)
    assert (a.folder / "terrain.npy").read_bytes() == (b.folder / "terrain.npy").read_bytes()
    assert [f.truth for f in a.frames] == [f.truth for f in b.frames]
    assert a.scenario_dict()["landmarks"] == b.scenario_dict()["landmarks"]
    # cached: a second call reads the same folder back without rewriting it
    stamp = a.frames[0].image.stat().st_mtime_ns
    again = next(cases("heldout", out_dir=tmp_path / "a", names=[SMALL], max_frames=2))
    assert again.frames[0].image.stat().st_mtime_ns == stamp and again.frames == a.frames


def test_other_seed_other_terrain():
    rng_a, rng_b = np.random.default_rng(1), np.random.default_rng(2)
    for name, fn in FAMILIES.items():
        za, zb = fn(64, relief=50.0, rng=rng_a), fn(64, relief=50.0, rng=rng_b)
        assert za.shape == (64, 64) and abs(np.ptp(za) - 50.0) < 1e-6, name
        assert not np.allclose(za, zb), name


#: the window of the Jacksboro DEM (source rows, cols) the bundled jacksboro scenarios' route uses
BUNDLED_JACKSBORO = {"dem": "jacksboro", "rows": (181, 195), "cols": (212, 226)}


#: the procedural families each split uses
def _families(split):
    return {t.source["family"] for t in TERRAINS if t.split == split and "family" in t.source}


def _overlap(a, b):
    rows = min(a["rows"][1], b["rows"][1]) > max(a["rows"][0], b["rows"][0])
    cols = min(a["cols"][1], b["cols"][1]) > max(a["cols"][0], b["cols"][0])
    return a["dem"] == b["dem"] and rows and cols


@pytest.mark.parametrize("a, b", list(itertools.combinations(SPLITS, 2)))
def test_splits_are_disjoint(a, b):
    assert seeds(a) and seeds(b) and not seeds(a) & seeds(b)
    names = {s: {t.name for t in TERRAINS if t.split == s} for s in (a, b)}
    assert names[a] and names[b] and not names[a] & names[b]
    for s in (a, b):
        assert {n.split("/")[0] for n in case_names(s)} == names[s]
    # crops of the same real DEM must not overlap between the splits
    for ta in (t for t in TERRAINS if t.split == a and "dem" in t.source):
        for tb in (t for t in TERRAINS if t.split == b and "dem" in t.source):
            assert not _overlap(ta.source, tb.source), (ta.name, tb.name)


def test_the_splits_have_what_the_issues_ask_for():
    assert SPLITS == (
        "tuning",
        "heldout",
        "fresh",
        "confirm",
        "confirm2",
        "tuning-sky",
        "confirm3",
        "tuning-snow",
        "confirm4",
        "confirm5",
    )
    # the held-out set: real DEM crops, a contour map, drives, a kidnap
    held = [t for t in TERRAINS if t.split == "heldout"]
    assert any("dem" in t.source for t in held) and any(t.contours > 0 for t in held)
    assert {"drive", "kidnap"} <= {k for t in held for k in t.drives}
    assert {t.frame_size for t in held} >= {(200, 150), (320, 240), (640, 480)}
    with pytest.raises(ValueError, match="split"):
        case_names("test")


def test_the_fresh_split_is_unlike_the_others():
    fresh = [t for t in TERRAINS if t.split == "fresh"]
    others = [t for t in TERRAINS if t.split != "fresh"]
    assert len(fresh) >= 6
    # terrain seeds 3xxx, case seeds 3xxxx; the other splits' below
    assert all(3000 <= t.seed < 4000 for t in fresh) and all(t.seed < 3000 or t.seed >= 4000 for t in others)
    assert all(30000 <= s < 40000 for s in seeds("fresh") - {t.seed for t in fresh})
    # terrain families the other splits do not have, a real DEM crop and a contour map
    assert len(_families("fresh") - _families("tuning") - _families("heldout")) >= 4
    assert any("dem" in t.source for t in fresh) and any(t.contours > 0 for t in fresh)
    # no crop overlaps the bundled jacksboro scenarios' route either
    assert not any(_overlap(t.source, BUNDLED_JACKSBORO) for t in TERRAINS if "dem" in t.source)
    # sweeps on every terrain, drives or kidnaps on at least four
    assert sum(bool(t.drives) for t in fresh) >= 4
    assert {"drive", "kidnap"} <= {k for t in fresh for k in t.drives}
    # frame sizes the others lack (16:9, portrait, tiny), route spacings of 20-50 m
    sizes = {t.frame_size for t in fresh}
    assert {(1280, 720), (480, 640), (96, 72)} <= sizes and not sizes & {(200, 150)}
    assert sizes - {t.frame_size for t in others}
    assert min(t.spacing for t in fresh) == 20.0 and max(t.spacing for t in fresh) == 50.0
    # the rasteriser makes most of its frames, the ray caster at least one terrain's
    renderers = [t.renderer for t in fresh]
    assert renderers.count("raster") > len(fresh) / 2 and "raycast" in renderers
    assert all(t.renderer == "raycast" for t in others if t.split in ("tuning", "heldout"))


@pytest.mark.parametrize(
    "split, thousands", [("confirm", 4), ("confirm2", 5), ("confirm3", 6), ("confirm4", 7), ("confirm5", 8)]
)
def test_the_confirm_splits_mix_the_others_with_new_seeds(split, thousands):
    confirm = [t for t in TERRAINS if t.split == split]
    lo, hi = thousands * 1000, (thousands + 1) * 1000
    assert len(confirm) >= 6
    assert all(lo <= t.seed < hi for t in confirm)
    assert all(10 * lo <= s < 10 * hi for s in seeds(split) - {t.seed for t in confirm})
    assert not any(lo <= t.seed < hi for t in TERRAINS if t.split != split)
    # both renderers, a real DEM crop, a contour map, drives and a kidnap
    assert {t.renderer for t in confirm} == {"raster", "raycast"}
    assert any("dem" in t.source for t in confirm) and any(t.contours > 0 for t in confirm)
    assert {"drive", "kidnap"} <= {k for t in confirm for k in t.drives}


def test_the_tuning_sky_split_has_clouds_and_tuning_seeds():
    # the splits parameters may be chosen on are the tuning-seeded ones, and only those
    assert set(TUNING_SPLITS) < set(SPLITS)
    assert all((1000 <= t.seed < 2000) == (t.split in TUNING_SPLITS) for t in TERRAINS)
    sky = [t for t in TERRAINS if t.split == "tuning-sky"]
    tuning = {t.seed for t in TERRAINS if t.split == "tuning"}
    assert len(sky) >= 4 and all(1000 <= t.seed < 2000 for t in sky) and not {t.seed for t in sky} & tuning
    # the raster renderer's cloud layer over every terrain (the tuning split's ray caster draws none)
    assert all(t.renderer == "raster" and t.look.get("cloud_cover", 0) >= 0.2 for t in sky)
    assert all(t.look.get("cloud_cover") is None for t in TERRAINS if t.split == "tuning")


def test_the_tuning_snow_split_has_snow_against_the_sky_and_tuning_seeds():
    snow = [t for t in TERRAINS if t.split == "tuning-snow"]
    others = {t.seed for t in TERRAINS if t.split in TUNING_SPLITS and t.split != "tuning-snow"}
    assert len(snow) >= 4 and all(1700 <= t.seed < 1800 for t in snow) and not {t.seed for t in snow} & others
    # mountains high enough for the alpine palette's pale rock (ray caster) or a snow line (raster)
    assert all(t.look["palette"] == "alpine" for t in snow)
    assert all(t.source["relief"] >= 400 for t in snow)
    assert {t.renderer for t in snow} == {"raster", "raycast"}
    assert all(t.look.get("snow_line") is not None for t in snow if t.renderer == "raster")
    # the confirm split for the rule chosen on it has snow too
    assert (
        sum(
            t.look.get("palette") == "alpine" or t.look.get("snow_line") is not None
            for t in TERRAINS
            if t.split == "confirm4"
        )
        >= 3
    )


def _check_frame_bounds(case):
    pts, arc = _polyline(case.route)
    b = ERROR_BOUNDS
    tol = 1e-6
    for f in case.frames:
        assert abs(f.lateral_m) <= b["lateral_m"] + tol
        assert abs(f.heading_error_deg) <= b["heading_deg"] + tol
        assert abs(f.pitch_deg) <= b["pitch_deg"] + tol and abs(f.roll_deg) <= b["roll_deg"] + tol
        assert abs(f.eye_height_m - 2.0) <= b["eye_height_m"] + tol
        if f.along_frac is not None:
            assert abs(f.along_frac) <= b["along_frac"] + tol
        # the truth position really is that far from the route polyline (segments, extended at the ends)
        d = min(_segment_distance(np.array([f.x, f.y]), pts[i], pts[i + 1]) for i in range(len(pts) - 1))
        assert d <= b["lateral_m"] + 1e-3
        near = int(np.argmin(np.hypot(pts[:, 0] - f.x, pts[:, 1] - f.y)))
        assert f.route_index == near
        img = cv2.imread(str(f.image), cv2.IMREAD_UNCHANGED)
        assert img.shape == (f.size[1], f.size[0], 3)
    times = [f.time_s for f in case.frames]
    assert times == sorted(times) and len(set(times)) == len(times)


def _segment_distance(p, a, b):
    d = b - a
    u = float(np.dot(p - a, d) / np.dot(d, d))  # no clamping: frames may lie beyond the end points
    return float(np.hypot(*(p - (a + u * d)))) if -0.5 <= u <= 1.5 else math.inf


def test_frames_truth_within_bounds_and_scenario_loads(tmp_path):
    for case in cases("heldout", out_dir=tmp_path, names=[SMALL], max_frames=4):
        _check_frame_bounds(case)
        sc = load_scenario(case.scenario_path)
        assert len(sc.sensor.frames) == len(case.frames)
        for spec, f in zip(sc.sensor.frames, case.frames):
            assert spec.image == f.image.resolve()
            assert (spec.truth.x, spec.truth.y) == pytest.approx((f.x, f.y), abs=1e-3)
        copy = load_scenario(case.write_scenario(memory={"bank_size": 1}))
        assert copy.memory.bank_size == 1 and copy.route == sc.route
        assert case.horizons().shape == (len(case.frames), case.frames[0].size[0])


def test_drive_poses_bounds_gaps_stops_and_kidnap():
    route = [(100.0 + 30 * i, 200.0 + 5 * math.sin(i / 3)) for i in range(32)]
    pts, arc = _polyline(route)
    poses = _drive_poses(route, 30.0, np.random.default_rng(7), frames=60, kidnap=True)
    steps = np.diff([p["arc"] for p in poses])
    events = [p["event"] for p in poses]
    assert "stop" in events and "gap" in events and events.count("kidnap") == 1
    jump = events.index("kidnap")
    assert abs(poses[jump]["arc"] - poses[jump - 1]["arc"]) >= 0.2 * arc[-1]
    for p, step, ev in zip(poses[1:], steps, events[1:]):
        if ev == "stop":
            assert step == 0.0
        elif ev == "gap":
            assert step >= 2.5 * 30.0 - 1e-9 or p["arc"] < arc[-1]  # turned round at the route's end
    for p in poses:
        assert abs(p["lateral"]) <= ERROR_BOUNDS["lateral_m"] and abs(p["pitch"]) <= ERROR_BOUNDS["pitch_deg"]
        assert 0.0 <= p["arc"] <= arc[-1]
    plain = _drive_poses(route, 30.0, np.random.default_rng(7), frames=60, kidnap=False)
    assert "kidnap" not in [p["event"] for p in plain]


def _profile_poses(kind: str, route: list, bounds: dict, *, seed: int) -> list[dict]:
    """The poses of a sweep (a frame a route point) or a drive (a frame a route point, no
    kidnapping) along ``route`` at 30 m spacing, drawn within ``bounds`` from ``seed``."""
    rng = np.random.default_rng(seed)
    if kind == "sweep":
        return _sweep_poses(route, 30.0, rng, bounds=bounds)
    return _drive_poses(route, 30.0, rng, frames=len(route), kidnap=False, bounds=bounds)


@pytest.mark.parametrize("kind", ["sweep", "drive"])
def test_the_large_pose_error_profile_reaches_past_the_standard_bounds(kind):
    route = [(100.0 + 30 * i, 200.0 + 5 * math.sin(i / 3)) for i in range(200)]
    large, std = ERROR_PROFILES["large"], ERROR_BOUNDS

    def poses(bounds):
        return _profile_poses(kind, route, bounds, seed=11)

    got, base = poses(large), poses(std)
    for key, bound in (("heading_error", "heading_deg"), ("lateral", "lateral_m"), ("pitch", "pitch_deg")):
        worst = max(abs(p[key]) for p in got)
        assert std[bound] < worst <= large[bound] + 1e-9, (key, worst)
        # the errors are larger throughout, not only beyond the standard bound (a drive's walk too)
        spread = float(np.std([p[key] for p in got])) / float(np.std([p[key] for p in base]))
        assert spread > 1.4, (key, spread)
    # the standard profile is the default, as before
    assert [p["heading_error"] for p in poses(std)] == [
        p["heading_error"]
        for p in (
            _sweep_poses(route, 30.0, np.random.default_rng(11))
            if kind == "sweep"
            else _drive_poses(route, 30.0, np.random.default_rng(11), frames=200, kidnap=False)
        )
    ]


def test_a_pose_error_profile_is_its_own_cache_entry(tmp_path):
    std = next(cases("heldout", out_dir=tmp_path, names=[SMALL], max_frames=2))
    big = next(cases("heldout", out_dir=tmp_path, names=[SMALL], max_frames=2, errors="large"))
    assert (std.errors, big.errors) == ("standard", "large")
    assert std.folder.parent.parent.name == "heldout" and big.folder.parent.parent.name == "heldout-large"
    assert [f.heading_error_deg for f in std.frames] != [f.heading_error_deg for f in big.frames]
    assert load_scenario(big.scenario_path).route == load_scenario(std.scenario_path).route  # same terrain and route
    with pytest.raises(ValueError, match="errors must be one of"):
        next(cases("heldout", out_dir=tmp_path, names=[SMALL], errors="huge"))


def _tiny_world():
    rng = np.random.default_rng(3)
    h = FAMILIES["fbm"](96, hurst=0.8, relief=60.0, rng=rng)
    w = World(h, 10.0)
    z0 = float(w.height_at(520.0, 480.0))
    w.boxes = [Box(520.0, 480.0, 18.0, 12.0, 30.0, z0 - 3, z0 + 8, (0.9, 0.8, 0.7), (0.5, 0.2, 0.2), "H1")]
    return w


@pytest.mark.parametrize("size", [(200, 150), (320, 240), (64, 48), (100, 100)])
def test_raycaster_renders_requested_size(size):
    w = _tiny_world()
    rc = RayCaster(w, Look(), rng=np.random.default_rng(0))
    z = float(w.height_at(400.0, 400.0)) + 2.0
    img, horizon, visible = rc.render(
        400.0, 400.0, z, heading_deg=45.0, pitch_deg=1.5, roll_deg=-1.0, width=size[0], height=size[1], fov_y_deg=45.0
    )
    assert img.shape == (size[1], size[0], 3) and horizon.shape == (size[0],)
    assert 0.0 <= img.min() and img.max() <= 1.0 and img.std() > 0.01
    out = sensor_effects(img, sensor=Sensor(), rng=np.random.default_rng(1))
    assert out.shape == (size[1], size[0], 3) and out.dtype == np.uint8
    assert visible.get("H1", 0) > 0  # the house 170 m ahead is in view


def test_raycaster_pitch_moves_the_horizon_as_a_pinhole_would():
    w = _tiny_world()
    rc = RayCaster(w, Look(), rng=np.random.default_rng(0))
    z = float(w.height_at(400.0, 400.0)) + 2.0
    kw = dict(heading_deg=45.0, roll_deg=0.0, width=160, height=120, fov_y_deg=45.0)
    _, level, _ = rc.render(400.0, 400.0, z, pitch_deg=0.0, **kw)
    _, up, _ = rc.render(400.0, 400.0, z, pitch_deg=2.0, **kw)
    f = 60.0 / math.tan(math.radians(22.5))
    cols = (level < 119) & (up < 119) & (level > 0) & (up > 0)
    assert cols.sum() > 80
    # pitching the camera up by 2 degrees moves distant ground down by about f * tan(2 deg) rows
    assert np.median(up[cols] - level[cols]) == pytest.approx(f * math.tan(math.radians(2.0)), abs=1.0)


@pytest.mark.slow
def test_raycaster_agrees_with_the_viewframe_renderer(tmp_path):
    """Two independent renderers, one pinhole convention: the horizon rows agree."""
    from models.camera_emulator import CameraEmulator, Pose
    from models.environment import EnvironmentModel
    from models.scenario import CameraSpec
    from models.terrain import Terrain

    w = _tiny_world()
    w.boxes = []
    env = EnvironmentModel(Terrain(heights=w.heights, cell_size=w.cell), [])
    cam = CameraSpec(width=160, height=120, fov_y_deg=45.0, eye_height=2.0, near=1.0, far=5000.0)
    rc = RayCaster(w, Look(), rng=np.random.default_rng(0))
    with CameraEmulator(env, cam) as emu:
        for x, y, heading in ((400.0, 400.0, 45.0), (300.0, 500.0, -30.0)):
            z = float(w.height_at(x, y)) + 2.0
            view = emu.render(Pose(x, y, z, heading, 0.0))
            ground = view.depth > 0
            ref = np.where(ground.any(0), np.argmax(ground, 0), 120)
            _, ours, _ = rc.render(
                x, y, z, heading_deg=heading, pitch_deg=0.0, roll_deg=0.0, width=160, height=120, fov_y_deg=45.0
            )
            assert np.median(np.abs(ours - ref)) <= 1.0


def test_one_view_a_point_pins_the_benchmarks_scenario_and_keeps_its_files(tmp_path):
    """The benchmarks that judge their own rankings by route point pin one viewframe a point; the
    copy still resolves the scenario's relative files (its DEM)."""
    import yaml

    from bench.evalset import one_view_a_point
    from models.scenario import load_scenario
    from models.world import World

    np.save(tmp_path / "dem.npy", np.random.default_rng(1).uniform(0, 30, (40, 40)))
    path = tmp_path / "s.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "name": "pinned",
                "terrain": {"cell_size": 10.0, "dem": "dem.npy"},
                "route": [[100.0, 100.0], [140.0, 110.0], [180.0, 100.0]],
                "camera": {"width": 32, "height": 24, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 900.0},
            }
        )
    )
    sc = load_scenario(path)
    assert sc.views_per_leg == 3  # a short route: viewframes between the points by default
    pinned = one_view_a_point(sc)
    assert pinned.views_per_leg == 1 and sc.views_per_leg == 3
    assert len(World(pinned, cache=None).poses) == 3 and World(pinned, cache=None).terrain.heights.shape == (40, 40)


@pytest.mark.parametrize("kind", ["sweep", "drive"])
@pytest.mark.parametrize("component", ["along", "lateral", "heading", "pitch", "roll"])
def test_a_component_profile_enlarges_that_component_alone(kind, component):
    """``large-<component>`` (bench/pose_ablation.py's ablation): the standard poses with that one
    error component drawn within the large profile's bound, every other component the same."""
    from bench.evalset.cases import ABLATION_COMPONENTS

    route = [(100.0 + 30 * i, 200.0 + 5 * math.sin(i / 3)) for i in range(120)]
    bound = ABLATION_COMPONENTS[component]
    profile = ERROR_PROFILES[f"large-{component}"]
    assert {k for k in ERROR_BOUNDS if profile[k] != ERROR_BOUNDS[k]} == {bound}
    assert profile[bound] == ERROR_PROFILES["large"][bound] > ERROR_BOUNDS[bound]

    def poses(bounds):
        return _profile_poses(kind, route, bounds, seed=5)

    got, base = poses(profile), poses(ERROR_BOUNDS)
    field = {"along_frac": "along_frac", "lateral_m": "lateral", "heading_deg": "heading_error"}.get(
        bound, bound.removesuffix("_deg")
    )
    if kind == "drive" and field == "along_frac":
        field = "arc"  # a drive's along error is its walk: the same arc lengths
        assert [p[field] for p in got] == [p[field] for p in base]
        return
    others = [f for f in ("lateral", "heading_error", "pitch", "roll", "eye") if f != field]
    for f in others:
        assert [p[f] for p in got] == pytest.approx([p[f] for p in base]), f
    assert max(abs(p[field]) for p in got) > ERROR_BOUNDS[bound]


# ---------------------------------------------------------------------------------------------
# the fresh split: its terrain families, its renderer (bench/evalset/raster.py), its cases

NEW_FAMILIES = ["dunes", "canyon", "lakes", "volcano", "alpine"]


@pytest.mark.parametrize("family", NEW_FAMILIES)
@pytest.mark.parametrize("size, relief", [(128, 40.0), (256, 1100.0)])
def test_a_new_terrain_family_is_finite_of_its_relief_and_differs_by_seed(family, size, relief):
    fn = FAMILIES[family]
    a = fn(size, relief=relief, rng=np.random.default_rng(31))
    again = fn(size, relief=relief, rng=np.random.default_rng(31))
    b = fn(size, relief=relief, rng=np.random.default_rng(32))
    assert a.shape == (size, size) and np.isfinite(a).all()
    assert a.min() == pytest.approx(0.0, abs=1e-9) and np.ptp(a) == pytest.approx(relief, rel=1e-9)
    assert np.array_equal(a, again)
    assert np.mean(np.abs(a - b)) > 0.02 * relief  # another terrain, not a small perturbation
    # not a field of white noise: neighbouring cells are far closer than the same heights shuffled
    shuffled = np.random.default_rng(0).permutation(a.ravel()).reshape(a.shape)
    assert np.median(np.abs(np.diff(a, axis=1))) < 0.3 * np.median(np.abs(np.diff(shuffled, axis=1)))


def test_the_new_families_have_their_shapes():
    rng = np.random.default_rng
    lakes = FAMILIES["lakes"](128, relief=50.0, rng=rng(1), water=0.25)
    assert 0.24 <= np.mean(lakes == 0.0) <= 0.26  # the lowest quarter is one flat level
    volcano = FAMILIES["volcano"](128, relief=300.0, rng=rng(2))
    r, c = np.unravel_index(np.argmax(volcano), volcano.shape)
    assert abs(r - 64) < 24 and abs(c - 64) < 24  # the summit near the middle
    assert np.percentile(volcano, 50) < 0.25 * 300.0  # a cone on a plain, not a plateau
    canyon = FAMILIES["canyon"](128, relief=200.0, rng=rng(3))
    gy, gx = np.gradient(canyon)
    assert np.mean(np.hypot(gx, gy) > 20.0) > 0.005  # cliffs: drops of 10 % of the relief a cell
    dunes = FAMILIES["dunes"](128, relief=40.0, rng=rng(4))
    gy, gx = np.gradient(dunes)
    slope = np.hypot(gx, gy)
    assert np.percentile(slope, 99) > 3 * np.median(slope)  # short steep slip faces, long gentle slopes
    alpine = FAMILIES["alpine"](128, relief=1100.0, rng=rng(5))
    assert np.mean(alpine < 0.3 * 1100.0) > 0.1 and alpine.max() == pytest.approx(1100.0)  # a valley among peaks


def _raster_world(*, with_box: bool = True):
    """The ray caster tests' hill (fBm, 96 cells of 10 m) and house, for the rasteriser, the
    ray caster and the viewframe renderer alike."""
    from models.landmarks import Landmark

    w = _tiny_world()
    (box,) = w.boxes
    lm = Landmark("H1", "house", box.x, box.y, box.width, box.depth, 8.0, box.yaw_deg, box.z0 + 3.0)
    blocks = [Block(box.x, box.y, box.width, box.depth, box.yaw_deg, box.z0, box.z1, *KIND_COLOURS["house"], "H1")]
    if not with_box:
        w.boxes, blocks = [], []
    ras = Rasteriser(w.heights, w.cell, look=RasterLook(), rng=np.random.default_rng(0), blocks=blocks)
    return w, ras, lm


@pytest.mark.parametrize("size", [(96, 72), (160, 90), (120, 160), (320, 240)])
def test_rasteriser_renders_requested_size(size):
    w, ras, _ = _raster_world()
    z = float(w.height_at(400.0, 400.0)) + 2.0
    img, horizon, visible = ras.render(
        400.0, 400.0, z, heading_deg=45.0, pitch_deg=1.5, roll_deg=-1.0, width=size[0], height=size[1], fov_y_deg=45.0
    )
    assert img.shape == (size[1], size[0], 3) and horizon.shape == (size[0],)
    assert 0.0 <= img.min() and img.max() <= 1.0 and img.std() > 0.01
    assert ((0 < horizon) & (horizon < size[1])).mean() > 0.5  # ground below, sky above
    assert visible.get("H1", 0) > 0  # the house 170 m ahead is in view
    out = raster_sensor_effects(
        img, sensor=RasterSensor(white_balance=0.1, aberration_px=1.0), rng=np.random.default_rng(1)
    )
    assert out.shape == (size[1], size[0], 3) and out.dtype == np.uint8


def test_rasteriser_is_deterministic_and_its_seed_is_its_world():
    w, ras, _ = _raster_world()
    z = float(w.height_at(400.0, 400.0)) + 2.0
    kw = dict(heading_deg=45.0, pitch_deg=1.0, roll_deg=2.0, width=160, height=120, fov_y_deg=45.0)
    a, _, _ = ras.render(400.0, 400.0, z, **kw)
    b, _, _ = ras.render(400.0, 400.0, z, **kw)
    assert a.tobytes() == b.tobytes()
    other = Rasteriser(w.heights, w.cell, look=RasterLook(), rng=np.random.default_rng(1), blocks=ras.blocks)
    c, _, _ = other.render(400.0, 400.0, z, **kw)
    assert np.abs(a - c).mean() > 0.005  # another seed: another ground texture and other clouds


@pytest.mark.parametrize("pitch", [-20.0, -8.0])
def test_rasteriser_draws_the_ground_under_the_camera_without_holes(pitch):
    """Looking down, the ground's triangles around and under the camera cross the near plane:
    clipped, they still cover every pixel below the horizon."""
    w, ras, _ = _raster_world(with_box=False)
    z = float(w.height_at(300.0, 500.0)) + 2.0
    fr = ras.render_frame(
        300.0, 500.0, z, heading_deg=-30.0, pitch_deg=pitch, roll_deg=0.0, width=160, height=120, fov_y_deg=45.0
    )
    below = np.arange(120)[:, None] > fr.horizon[None, :] + 1  # (the horizon's row is partly sky)
    assert below[-1].all() and (fr.depth[below] > 0).all()
    assert fr.depth[-1].min() > 1.0  # the nearest ground is the ground 2 m below, seen at an angle


def test_rasteriser_rolls_and_pitches_as_the_ray_caster():
    """Two independent renderers (a mesh rasteriser, a height-field ray caster), one camera
    convention: the same horizon under pitch and roll, to a pixel (median over columns)."""
    w, ras, _ = _raster_world()
    rc = RayCaster(w, Look(), rng=np.random.default_rng(0))
    for x, y, heading, pitch, roll in ((400.0, 400.0, 45.0, 1.5, 2.0), (300.0, 500.0, -30.0, -2.0, -3.0)):
        z = float(w.height_at(x, y)) + 2.0
        kw = dict(heading_deg=heading, pitch_deg=pitch, roll_deg=roll, width=160, height=120, fov_y_deg=45.0)
        _, ref, seen_ref = rc.render(x, y, z, **kw)
        _, ours, seen = ras.render(x, y, z, **kw)
        assert np.median(np.abs(ours - ref)) <= 1.0
        assert seen["H1"] == pytest.approx(seen_ref["H1"], rel=0.15)
        # and the roll is there: rolling by 3 degrees (the right axis up) tilts the horizon by
        # tan(3 deg) across the image, lower on the right
        _, flat, _ = ras.render(x, y, z, **{**kw, "roll_deg": 0.0})
        _, tilted, _ = ras.render(x, y, z, **{**kw, "roll_deg": 3.0})
        cols = np.arange(160)
        slope_diff = np.polyfit(cols, tilted - flat, 1)[0]
        assert slope_diff == pytest.approx(math.tan(math.radians(3.0)), abs=0.01)


@pytest.mark.slow
def test_rasteriser_agrees_with_the_viewframe_renderer():
    """The rasteriser and the viewframes' pyrender path at the same poses: the horizon rows agree
    within a pixel (median over columns) and the house covers the same pixels."""
    from models.camera_emulator import CameraEmulator, Pose
    from models.environment import EnvironmentModel
    from models.scenario import CameraSpec
    from models.terrain import Terrain

    w, _, lm = _raster_world()
    env = EnvironmentModel(Terrain(heights=w.heights, cell_size=w.cell), [lm])
    (box,) = w.boxes
    block = Block(
        lm.x, lm.y, lm.width, lm.depth, lm.yaw_deg, lm.z0 - env.ground_margin(lm), lm.top, *KIND_COLOURS["house"], "H1"
    )
    ras = Rasteriser(w.heights, w.cell, look=RasterLook(), rng=np.random.default_rng(0), blocks=[block])
    cam = CameraSpec(width=160, height=120, fov_y_deg=45.0, eye_height=2.0, near=1.0, far=5000.0)
    with CameraEmulator(env, cam) as emu:
        for x, y, heading, pitch in (
            (400.0, 400.0, 45.0, 0.0),
            (300.0, 500.0, -30.0, 2.0),
            (650.0, 300.0, 120.0, -2.0),
        ):
            z = float(w.height_at(x, y)) + 2.0
            view = emu.render(Pose(x, y, z, heading, pitch))
            ground = view.depth > 0
            ref = np.where(ground.any(0), np.argmax(ground, 0), 120)
            fr = ras.render_frame(
                x, y, z, heading_deg=heading, pitch_deg=pitch, roll_deg=0.0, width=160, height=120, fov_y_deg=45.0
            )
            assert np.median(np.abs(fr.horizon - ref)) <= 1.0
            theirs, ours = view.mask == 0, fr.landmarks == 0
            assert theirs.sum() > 40
            assert (theirs & ours).sum() / (theirs | ours).sum() > 0.75
            centre = [np.argwhere(m).mean(0) for m in (theirs, ours)]
            assert np.hypot(*(centre[0] - centre[1])) < 1.5


def test_rasterise_covers_a_quad_once_and_keeps_the_nearest():
    """Two triangles sharing an edge leave no pixel out; a nearer triangle hides a farther one."""
    from bench.evalset.raster import _rasterise

    quad = np.array([[-1.0, -1.0, 10.0], [1.0, -1.0, 10.0], [1.0, 1.0, 10.0], [-1.0, 1.0, 10.0]])
    tri = np.stack([quad[[0, 1, 2]], quad[[0, 2, 3]]])
    ids = _rasterise(tri, np.array([0, 1]), f=50.0, width=40, height=40, far=100.0)
    # the square spans cols/rows 19.5 +- 5: pixel centres 15..24 inside
    inside = np.zeros((40, 40), bool)
    inside[15:25, 15:25] = True
    assert ((ids >= 0) == inside).all()
    assert set(np.unique(ids[inside])) == {0, 1}
    near = quad.copy()
    near[:, 2] = 5.0
    both = np.concatenate([tri, near[[0, 1, 2]][None]])
    ids = _rasterise(both, np.array([0, 1, 2]), f=50.0, width=40, height=40, far=100.0)
    assert (ids[10:30, 10:30][np.triu(np.ones((20, 20), bool), 1)[::-1]] == 2).mean() > 0.9
    assert (_rasterise(tri, np.array([0, 1]), f=50.0, width=40, height=40, far=8.0) == -1).all()  # beyond far


def test_the_old_splits_cases_keep_their_spec():
    """The fresh split's new fields leave the tuning and held-out cases' spec hashes (their cache
    keys, in their case.json) as they were before it."""
    from bench.evalset.cases import _spec_hash

    by_name = {t.name: t for t in TERRAINS}
    assert _spec_hash(by_name["h-fbm-rough"], "sweep", None) == "c8b25e4ac33c0340"
    assert _spec_hash(by_name["h-topobathy"], "kidnap", None) == "2b56cb6f497d86ec"
    assert _spec_hash(by_name["t-ridged"], "drive", 4, "large") == "50bfc92cf9ce6333"


FRESH_SMALL = "f-volcano-contours"  # 96x72 frames: the quickest


def test_a_fresh_case_is_deterministic(tmp_path):
    a = next(cases("fresh", out_dir=tmp_path / "a", names=[FRESH_SMALL], max_frames=2))
    b = next(cases("fresh", out_dir=tmp_path / "b", names=[FRESH_SMALL], max_frames=2))
    assert _files(a) == _files(b) and len(a.frames) == 2
    assert (a.folder / "contours.geojson").read_bytes() == (b.folder / "contours.geojson").read_bytes()
    assert a.frames == tuple(dataclasses.replace(f, image=a.folder / f.image.relative_to(b.folder)) for f in b.frames)
    assert "(raster)" in a.description and a.frames[0].size == (96, 72)


@pytest.mark.parametrize("errors", ["standard", "large"])
def test_fresh_cases_build_within_their_bounds_and_load(tmp_path, errors):
    bounds = ERROR_PROFILES[errors]
    got = list(cases("fresh", out_dir=tmp_path, names=["f-lakes", FRESH_SMALL], max_frames=2, errors=errors))
    assert [c.name for c in got] == ["f-lakes/sweep", "f-lakes/drive", "f-lakes/kidnap", f"{FRESH_SMALL}/sweep"]
    for case in got:
        assert case.split == "fresh" and case.errors == errors
        sc = load_scenario(case.scenario_path)
        assert len(sc.sensor.frames) == len(case.frames) == 2
        assert ("contours" in case.scenario_dict()["terrain"]) == (case.terrain == FRESH_SMALL)
        for f in case.frames:
            assert abs(f.lateral_m) <= bounds["lateral_m"] + 1e-6
            assert abs(f.heading_error_deg) <= bounds["heading_deg"] + 1e-6
            assert abs(f.pitch_deg) <= bounds["pitch_deg"] + 1e-6 and abs(f.roll_deg) <= bounds["roll_deg"] + 1e-6
            img = cv2.imread(str(f.image), cv2.IMREAD_UNCHANGED)
            assert img.shape == (f.size[1], f.size[0], 3) and img.std() > 2.0
        assert case.horizons().shape == (2, case.frames[0].size[0])
    # the lakes' route keeps off the water (its route floor)
    lakes = got[0]
    heights = np.load(lakes.folder / "terrain.npy")
    cell = lakes.scenario_dict()["terrain"]["cell_size"]
    on_route = [heights[int(round(y / cell)), int(round(x / cell))] for x, y in lakes.route]
    assert min(on_route) > 0.0


@pytest.mark.parametrize("name", [t.name for t in TERRAINS if t.route_floor is not None])
def test_a_route_floor_keeps_the_route_and_its_landmarks_above_it(name):
    from bench.evalset.cases import _heights, _landmarks, _route

    (t,) = [t for t in TERRAINS if t.name == name]
    heights = _heights(t)
    route = _route(t, heights)
    world = World(heights, t.cell)
    assert len(route) == t.points
    assert min(world.height_at(x, y) for x, y in route) >= t.route_floor
    lms = _landmarks(t, route, heights)
    assert len(lms) >= 4 and min(world.height_at(lm["x"], lm["y"]) for lm in lms) >= t.route_floor
    # a floor that matters: some of the map's ground lies below it (water, a canyon)
    assert np.mean(heights < t.route_floor) > 0.05
