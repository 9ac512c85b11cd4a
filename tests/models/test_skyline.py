"""The skyline: horizon extraction from images and depth buffers, and profile matching."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models import skyline
from models.camera_emulator import CameraEmulator
from models.environment import build_environment
from models.scenario import SimulateSpec, scenario_from_dict
from models.sensor import degrade
from models.skyline import (
    boundary_to_profile,
    match_skylines,
    profile_azimuths,
    profile_bins,
    skyline_from_depth,
    skyline_from_image,
)

FOV = 45.0


def _scenario(width=160, height=120, pitch=0.0):
    return scenario_from_dict(
        {
            "name": "sky",
            "terrain": {"cell_size": 10.0, "procedural": {"size": 128, "relief": 120.0, "seed": 4}},
            "route": [[300, 300], [400, 400]],
            "camera": {
                "width": width,
                "height": height,
                "fov_y_deg": FOV,
                "eye_height": 2.0,
                "pitch_deg": pitch,
                "near": 1.0,
                "far": 5000.0,
            },
        }
    )


@pytest.fixture(scope="module")
def emulator():
    s = _scenario()
    with CameraEmulator(build_environment(s), s.camera) as cam:
        yield cam


def test_profile_grid_is_centred_and_the_same_at_every_resolution():
    n = profile_bins(160, 120, fov_y_deg=FOV)
    assert n % 2 == 1 and profile_azimuths(n)[(n - 1) // 2] == 0.0
    assert profile_bins(320, 240, fov_y_deg=FOV) == n == profile_bins(640, 480, fov_y_deg=FOV)
    # a flat horizon through the image centre is at elevation 0 in every bin; one row above at ~atan(1/f)
    f = 60 / math.tan(math.radians(FOV / 2))
    flat = boundary_to_profile(np.full(160, 60.0), 120, fov_y_deg=FOV)
    np.testing.assert_allclose(flat, 0.0, atol=0.5 / f * 180 / math.pi + 1e-6)
    assert np.isnan(boundary_to_profile(np.full(160, 0.0), 120, fov_y_deg=FOV)).all()  # no sky
    assert np.isnan(boundary_to_profile(np.full(160, 120.0), 120, fov_y_deg=FOV)).all()  # no terrain


@pytest.mark.parametrize("bad", [dict(fov_y_deg=0), dict(fov_y_deg=45, step_deg=0)])
def test_profile_bins_names_the_bad_parameter(bad):
    with pytest.raises(ValueError, match=next(iter(bad)) if bad.get("fov_y_deg") == 0 else "step_deg"):
        profile_bins(160, 120, **bad)


def _synthetic(height, width, horizon_rows, rng, *, haze=0.0):
    """Sky (bright blue, smooth) over textured green terrain below ``horizon_rows`` (W,)."""
    rows = np.arange(height)[:, None]
    sky = rows < horizon_rows[None, :]
    img = np.empty((height, width, 3), np.float32)
    img[:] = (0.70, 0.80, 0.92)
    terrain = np.array([0.35, 0.45, 0.22]) * (1 + 0.25 * rng.standard_normal((height, width, 1)))
    img = np.where(sky[..., None], img, terrain)
    img = img * (1 - haze) + 0.8 * haze
    return np.clip(img * 255 + rng.normal(0, 6, img.shape), 0, 255).astype(np.uint8), sky


@pytest.mark.parametrize("size", [(120, 160), (240, 320), (96, 96)])
@pytest.mark.parametrize("haze", [0.0, 0.5])
def test_known_synthetic_horizon_is_recovered(size, haze):
    h, w = size
    rng = np.random.default_rng(11)
    cols = np.arange(w)
    truth = (0.45 * h + 0.12 * h * np.sin(cols / w * 2 * math.pi * 1.5)).round()
    truth[w // 3 : w // 3 + max(2, w // 40)] = 0.2 * h  # a tower: a steep, narrow silhouette
    img, _ = _synthetic(h, w, truth, rng, haze=haze)
    got = skyline_from_image(img, fov_y_deg=FOV)
    want = boundary_to_profile(truth, h, fov_y_deg=FOV)
    pixel_deg = FOV / min(h, 128)  # a pixel of the working image (at most 128 rows)
    err = np.abs(got - want)
    assert np.isfinite(got).mean() > 0.95
    assert np.nanmedian(err) <= pixel_deg + 0.05  # within a pixel
    assert np.nanpercentile(err, 90) <= 3 * pixel_deg  # steep slopes of the small image: a few pixels


def _pale_sky(height, width, horizon_rows, rng, *, clouds):
    """A sky that pales towards the horizon (as the evaluation set's raster renderer draws it: the
    haze colour at elevation 0, the sky's from 17 degrees up, a smoothstep) with ``clouds`` white
    patches high in it, over brown textured terrain below ``horizon_rows`` (W,)."""
    f = (height / 2) / math.tan(math.radians(FOV) / 2)
    rows, cols = np.arange(height)[:, None], np.arange(width)[None, :]
    x = np.clip(np.arctan((0.5 * height + 4 - rows) / f) / 0.3, 0, 1) * np.ones((1, width))
    t = (x * x * (3 - 2 * x)) ** 0.8
    img = np.array([0.76, 0.79, 0.83]) * (1 - t[..., None]) + np.array([0.52, 0.66, 0.86]) * t[..., None]
    for _ in range(clouds):
        cy, cx = rng.uniform(0.08, 0.3) * height, rng.uniform(0, width)
        ry, rx = rng.uniform(0.03, 0.07) * height, rng.uniform(0.08, 0.2) * width
        img[((rows - cy) / ry) ** 2 + ((cols - cx) / rx) ** 2 < 1] = np.array([0.94, 0.94, 0.96]) * rng.uniform(0.8, 1)
    terrain = np.array([0.45, 0.38, 0.25]) * (1 + 0.25 * rng.standard_normal((height, width, 1)))
    img = np.where((rows < horizon_rows[None, :])[..., None], img, terrain)
    return np.clip(img * 255 + rng.normal(0, 3, img.shape), 0, 255).astype(np.uint8)


def _pale_sky_errors(size, seed):
    h, w = size
    rng = np.random.default_rng(seed)
    truth = (0.5 * h + 0.06 * h * np.sin(np.arange(w) / w * 2 * math.pi * 1.2 + seed)).round()
    img = _pale_sky(h, w, truth, rng, clouds=4)
    return np.abs(skyline_from_image(img, fov_y_deg=FOV) - boundary_to_profile(truth, h, fov_y_deg=FOV))


PALE_SKIES = [(size, seed) for size in [(120, 160), (240, 320), (96, 128)] for seed in (1, 2, 3)]


@pytest.mark.parametrize("size, seed", PALE_SKIES)
def test_a_sky_paling_towards_the_horizon_under_clouds_is_sky(size, seed):
    # the class models' EM runs until the boundary settles: each round its sky model reaches
    # further down the pale band (and the clouds, not sky to the first rounds' model, join the sky)
    err = _pale_sky_errors(size, seed)
    assert np.isfinite(err).mean() > 0.95
    assert np.nanmedian(err) <= FOV / min(size[0], 128) + 0.05  # within a pixel of the working image
    assert np.nanmean(err > 1.0) <= 0.02


def test_three_rounds_left_the_boundary_in_such_a_sky(monkeypatch):
    # the rule before session 14 (three fixed rounds) on the same skies: the test above needs the change
    monkeypatch.setattr(skyline, "_ROUNDS", 3)
    off = [np.nanmean(_pale_sky_errors(size, seed) > 1.0) for size, seed in PALE_SKIES]
    assert sum(share > 0.1 for share in off) >= len(PALE_SKIES) // 2


@pytest.mark.parametrize("haze, noise, gain", [(0.0, 0.0, 0.0), (0.6, 4.0, 0.2), (0.3, 12.0, 0.4)])
def test_rendered_horizon_matches_the_depth_buffer(emulator, haze, noise, gain):
    """A rendered view, degraded like a camera image, gives the skyline of its own depth buffer."""
    spec = SimulateSpec(haze=haze, noise=noise, gain=gain, gamma=0.2, blur=0.8, texture=0.4)
    errs = []
    for i, heading in enumerate((20.0, 80.0, 150.0, 230.0)):
        view = emulator.render(emulator.pose_at(420.0, 380.0, heading))
        image = degrade(view.image, depth=view.depth, spec=spec, rng=i)
        want = skyline_from_depth(view.depth, fov_y_deg=FOV)
        got = skyline_from_image(image, fov_y_deg=FOV)
        assert np.isfinite(want).mean() > 0.9, "the test view should show a horizon"
        errs.append(np.abs(got - want)[np.isfinite(want)])
    err = np.concatenate(errs)
    assert np.nanmedian(err) < 0.4  # about one pixel (0.375 degrees at 120 rows)
    assert np.nanmean(np.nan_to_num(err, nan=5.0) > 1.5) < 0.1  # gross errors (or misses) on few bins


def test_other_resolution_gives_the_same_profile():
    s_small, s_big = _scenario(160, 120), _scenario(320, 240)
    env = build_environment(s_small)
    spec = SimulateSpec(haze=0.3, noise=4.0)
    profiles = []
    for s in (s_small, s_big):
        with CameraEmulator(env, s.camera) as cam:
            view = cam.render(cam.pose_at(420.0, 380.0, 80.0))
            profiles.append(skyline_from_image(degrade(view.image, depth=view.depth, spec=spec, rng=1), fov_y_deg=FOV))
    assert profiles[0].shape == profiles[1].shape
    assert np.nanmedian(np.abs(profiles[0] - profiles[1])) < 0.4


@pytest.mark.parametrize("turn, pitch", [(5.0, 0.0), (-8.0, 1.5), (3.0, -2.0)])
def test_matching_recovers_a_known_heading_and_pitch_shift(emulator, turn, pitch):
    x, y, heading = 420.0, 380.0, 80.0
    ref = skyline_from_depth(emulator.render(emulator.pose_at(x, y, heading)).depth, fov_y_deg=FOV)
    view = emulator.render(emulator.pose_at(x, y, heading + turn, pitch_deg=pitch))
    image = degrade(view.image, depth=view.depth, spec=SimulateSpec(haze=0.3, noise=6.0), rng=3)
    q = skyline_from_image(image, fov_y_deg=FOV)
    other = skyline_from_depth(emulator.render(emulator.pose_at(x, y, heading + 60)).depth, fov_y_deg=FOV)
    m = match_skylines(q, np.stack([other, ref]))
    assert m.error[1] < m.error[0]  # the right reference wins against a view elsewhere
    assert m.heading_deg[1] == pytest.approx(turn, abs=0.75)
    assert m.pitch_deg[1] == pytest.approx(pitch, abs=0.5)
    assert m.overlap[1] > 0.6


def test_matching_is_robust_to_an_occluded_stretch():
    rng = np.random.default_rng(2)
    n = 81
    ref = np.cumsum(rng.normal(0, 0.4, n)).astype(np.float32)
    q = np.roll(ref, 4) - 1.0  # turned 4 bins (2 degrees at 0.5) and pitched up by 1 degree
    q[:4] = np.nan
    q[30:40] += 6.0  # a vehicle or a tree in front of the horizon
    m = match_skylines(q, ref[None])
    assert m.heading_deg[0] == pytest.approx(2.0) and m.pitch_deg[0] == pytest.approx(1.0, abs=0.05)
    assert m.error[0] < 0.4


@pytest.mark.parametrize("roll", [2.0, -2.0])
def test_matching_fits_the_cameras_roll(emulator, roll):
    """A camera rolled by 2 degrees (the image rotated about its centre) tilts its horizon by up to
    a degree at the borders: the match with the roll fitted is closer than the match without,
    finds the tilt's sign and size, and keeps the heading."""
    import cv2

    x, y, heading = 420.0, 380.0, 80.0
    ref = skyline_from_depth(emulator.render(emulator.pose_at(x, y, heading)).depth, fov_y_deg=FOV)
    view = emulator.render(emulator.pose_at(x, y, heading + 3.0))
    h, w = view.image.shape[:2]
    rot = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), roll, 1.0)
    rolled = cv2.warpAffine(view.image, rot, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    image = degrade(rolled, spec=SimulateSpec(haze=0.3, noise=6.0), rng=3)
    q = skyline_from_image(image, fov_y_deg=FOV)
    flat = match_skylines(q, ref[None], max_roll_deg=0.0)
    tilted = match_skylines(q, ref[None], max_roll_deg=3.0)
    assert flat.roll_deg is not None and not np.any(flat.roll_deg)
    assert tilted.error[0] < 0.7 * flat.error[0]
    # the image turned counter-clockwise (OpenCV's positive angle): the right half of the horizon
    # rises against the reference's, r - q falls to the right
    assert tilted.roll_deg is not None and tilted.roll_deg[0] == pytest.approx(-roll, abs=0.7)
    assert tilted.heading_deg[0] == pytest.approx(3.0, abs=0.75)


def test_the_fitted_tilt_is_bounded_and_robust_to_an_occluder():
    rng = np.random.default_rng(4)
    n = 81
    az = profile_azimuths(n)
    ref = np.cumsum(rng.normal(0, 0.4, n)).astype(np.float64)
    q = ref - 0.5 - math.tan(math.radians(1.5)) * az  # pitched up by 0.5 degrees, tilted 1.5
    q[50:60] += 6.0  # an occluder
    m = match_skylines(q, ref[None], max_heading_deg=0.0, max_roll_deg=3.0)
    assert m.roll_deg is not None and m.roll_deg[0] == pytest.approx(1.5, abs=0.3)
    assert m.pitch_deg[0] == pytest.approx(0.5, abs=0.15) and m.error[0] < 0.4
    bounded = match_skylines(q, ref[None], max_heading_deg=0.0, max_roll_deg=0.5)
    assert bounded.roll_deg is not None and bounded.roll_deg[0] == pytest.approx(0.5, abs=1e-6)
    with pytest.raises(ValueError, match="max_roll_deg"):
        match_skylines(q, ref[None], max_roll_deg=-1.0)


def test_matching_rejects_mismatched_grids():
    with pytest.raises(ValueError, match="references must have shape"):
        match_skylines(np.zeros(81), np.zeros((3, 75)))


def _route_of_profiles(count: int, n: int, seed: int) -> np.ndarray:
    """``count`` reference profiles of ``n`` bins along a route: windows of one long random-walk
    panorama, each a few bins on from the one before and slowly changing, as route views are."""
    rng = np.random.default_rng(seed)
    pano = np.cumsum(rng.normal(0, 0.4, 3 * count + n))
    drift = np.cumsum(rng.normal(0, 0.05, (count, n)), axis=0)
    return np.stack([pano[3 * i : 3 * i + n] + drift[i] for i in range(count)])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_two_stage_match_keeps_the_full_matchs_best(seed):
    """Roll fitted only for the best ``roll_candidates`` of a roll-free pass: on a seeded route of
    400 references, the best 5 are the one-stage match's, in its order (further down the order
    may differ: a reference outside the roll-free best 64 keeps its roll-free error), the
    candidates have its errors and shifts, the other references their roll-free results."""
    rng = np.random.default_rng(100 + seed)
    n = 81
    refs = _route_of_profiles(400, n, seed)
    az = profile_azimuths(n)
    j = int(rng.integers(20, 380))
    q = np.roll(refs[j], 3) - 0.4 - math.tan(math.radians(1.5)) * az + rng.normal(0, 0.1, n)
    q[:3] = np.nan
    full = match_skylines(q, refs, roll_candidates=None)
    two = match_skylines(q, refs, roll_candidates=64)
    flat = match_skylines(q, refs, max_roll_deg=0.0)
    best_full = np.argsort(full.error, kind="stable")[:5]
    assert np.array_equal(np.argsort(two.error, kind="stable")[:5], best_full)
    assert best_full[0] == j
    cand = np.argsort(flat.error, kind="stable")[:64]
    rest = np.setdiff1d(np.arange(len(refs)), cand)
    for f in ("error", "heading_deg", "pitch_deg", "overlap", "roll_deg"):
        assert np.array_equal(getattr(two, f)[cand], getattr(full, f)[cand])
        assert np.array_equal(getattr(two, f)[rest], getattr(flat, f)[rest])
    assert two.roll_deg[j] == pytest.approx(1.5, abs=0.3)
    with pytest.raises(ValueError, match="roll_candidates"):
        match_skylines(q, refs, roll_candidates=0)


@pytest.mark.parametrize("max_roll_deg", [0.0, 3.0])
def test_matching_in_blocks_of_references_gives_the_same_match(monkeypatch, max_roll_deg) -> None:
    """References are matched a block at a time (temporaries that stay in cache): the result is
    the one-block match's, bit for bit, whatever the block."""
    import models.skyline as sky

    rng = np.random.default_rng(23)
    refs = np.cumsum(rng.standard_normal((50, 90)) * 0.3, axis=1) + 2.0
    refs[rng.random(refs.shape) < 0.05] = np.nan
    refs[7, 30:] = np.nan
    query = np.roll(refs[31] + 0.5, 4)
    query[:5] = np.nan
    kw = {"max_roll_deg": max_roll_deg, "roll_candidates": 8}
    monkeypatch.setattr(sky, "_BLOCK", 10**6)
    whole = match_skylines(query, refs, **kw)
    monkeypatch.setattr(sky, "_BLOCK", 7)
    blocks = match_skylines(query, refs, **kw)
    for field in ("error", "heading_deg", "pitch_deg", "overlap", "roll_deg"):
        assert np.array_equal(getattr(whole, field), getattr(blocks, field)), field
    assert int(np.argmin(blocks.error)) == 31


def _camera_profile(refs: np.ndarray, j: int, rng: np.random.Generator, *, outliers: bool) -> np.ndarray:
    """Reference ``j`` as a camera would see it: turned by 3 bins, pitched, rolled, noisy, its
    first bins missing, and (``outliers``) a run of wrong columns (a failed stretch of horizon)."""
    n = refs.shape[1]
    az = profile_azimuths(n)
    q = np.roll(refs[j], 3) - 0.4 - math.tan(math.radians(1.5)) * az + rng.normal(0, 0.1, n)
    q[:3] = np.nan
    if outliers:
        start = int(rng.integers(5, n - 30))
        q[start : start + 25] += rng.uniform(4.0, 8.0)
    return q


@pytest.mark.parametrize("outliers", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_coarse_candidates_contain_the_full_rankings_best(seed, outliers):
    """On a seeded route of 1,500 references (115 bins, the scenario camera's), the coarse stage's
    best 100 hold the full ranking's first, also with a fifth of the camera's horizon wrong; the
    fine stage gives the candidates the full match's results (roll fitted for every one, so the
    results do not depend on the other references) and so the same first."""
    from models.skyline_coarse import CoarseSkylines, coarse_candidates, ranked_references

    rng = np.random.default_rng(200 + seed)
    refs = _route_of_profiles(1500, 115, seed)
    refs[rng.random(refs.shape) < 0.01] = np.nan  # a few invalid bins
    j = int(rng.integers(20, 1480))
    q = _camera_profile(refs, j, rng, outliers=outliers)
    coarse = CoarseSkylines.prepare(refs)
    full = match_skylines(q, refs, roll_candidates=None)
    best = int(np.lexsort((np.arange(len(refs)), full.error))[0])
    assert best == j
    cand = coarse_candidates(q, coarse, 100)
    assert len(cand) == 100 and np.all(np.diff(cand) > 0) and best in cand
    idx, sub = ranked_references(q, refs, coarse, candidates=100, roll_candidates=None)
    assert np.array_equal(idx, cand)
    for f in ("error", "heading_deg", "pitch_deg", "overlap", "roll_deg"):
        assert np.array_equal(getattr(sub, f), getattr(full, f)[idx]), f
    assert int(idx[np.argmin(sub.error)]) == best


@pytest.mark.parametrize("count", [40, 41, 1000])
@pytest.mark.parametrize("roll_candidates", [None, 8])
def test_with_as_many_candidates_as_references_the_ranking_is_the_full_one(count, roll_candidates):
    """M >= N (or no coarse stage) is the full ranking, bit for bit, whatever the roll settings."""
    from models.skyline_coarse import CoarseSkylines, ranked_references

    rng = np.random.default_rng(31)
    refs = _route_of_profiles(41, 115, 7)
    q = _camera_profile(refs, 17, rng, outliers=True)
    full = match_skylines(q, refs, roll_candidates=roll_candidates)
    coarse = CoarseSkylines.prepare(refs)
    runs = [ranked_references(q, refs, None, candidates=count, roll_candidates=roll_candidates)]
    runs.append(ranked_references(q, refs, coarse, candidates=None, roll_candidates=roll_candidates))
    if count >= len(refs):
        runs.append(ranked_references(q, refs, coarse, candidates=count, roll_candidates=roll_candidates))
    for idx, m in runs:
        assert np.array_equal(idx, np.arange(len(refs)))
        for f in ("error", "heading_deg", "pitch_deg", "overlap", "roll_deg"):
            assert np.array_equal(getattr(m, f), getattr(full, f)), f
    idx, m = ranked_references(q, refs, coarse, candidates=count, roll_candidates=roll_candidates)
    assert len(idx) == min(count, len(refs))


def test_the_coarse_stage_rejects_bad_input():
    from models.skyline_coarse import CoarseSkylines, coarse_candidates, coarse_errors, ranked_references

    refs = _route_of_profiles(10, 115, 1)
    coarse = CoarseSkylines.prepare(refs)
    with pytest.raises(ValueError, match="count must be >= 1"):
        coarse_candidates(refs[0], coarse, 0)
    with pytest.raises(ValueError, match="query has 81 bins, the references 115"):
        coarse_errors(np.zeros(81), coarse)
    with pytest.raises(ValueError, match="factor must be in"):
        CoarseSkylines.prepare(refs, factor=0)
    with pytest.raises(ValueError, match="coarse holds 10 references, not the 9 given"):
        ranked_references(refs[0], refs[:9], coarse, candidates=3)
    # a camera profile without a valid bin: every reference scores the truncation, none is preferred
    e = coarse_errors(np.full(115, np.nan), coarse)
    assert np.array_equal(e, np.full(10, 2.0))


def test_the_coarse_errors_of_a_window_are_the_whole_routes():
    """The ranker compares a track window's references: ``rows`` gives the same errors."""
    from models.skyline_coarse import CoarseSkylines, coarse_errors

    refs = _route_of_profiles(300, 115, 3)
    refs[40:60, :30] = np.nan
    q = _camera_profile(refs, 50, np.random.default_rng(3), outliers=False)
    coarse = CoarseSkylines.prepare(refs)
    whole = coarse_errors(q, coarse)
    assert np.array_equal(coarse_errors(q, coarse.rows(30, 90)), whole[30:90])
    assert int(np.argmin(whole)) in (49, 50)  # neighbours, 3 bins apart on one panorama: the camera's 3-bin turn


@pytest.mark.parametrize("share", [0.04, 0.08])
def test_the_seeds_sky_model_trimmed_leaves_out_a_little_snow(share):
    # a sky seed (top rows) of smooth blue with a few pixels of grey-white snow in it: fitted on
    # all of them the model's covariance is broad and snow costs little more than sky; trimmed of
    # its worst-fitting pixels the model is the blue sky's alone, and snow costs far more
    rng = np.random.default_rng(5)
    h, w = 96, 128
    img = np.empty((h, w, 3), np.float32)
    img[:] = (0.35, 0.55, 0.90)
    snowy = rng.random((h, w)) < share
    img[snowy] = (0.82, 0.84, 0.88)
    img = np.clip(img + rng.normal(0, 0.01, img.shape), 0, 1).astype(np.float32)
    px = skyline._Pixels(skyline._features(img))
    seed = np.zeros((h, w), bool)
    seed[: h // 12] = True
    untrimmed = skyline._sky_cost(px, seed)
    trimmed = skyline._sky_cost(px, seed, trim_rounds=skyline._SEED_TRIM_ROUNDS)
    snow, blue = seed & snowy, seed & ~snowy
    gap = {
        k: float(np.median(c[snow]) - np.median(c[blue])) for k, c in (("untrimmed", untrimmed), ("trimmed", trimmed))
    }
    assert gap["trimmed"] > 3 * gap["untrimmed"] and gap["trimmed"] > 20  # nats
    # where the seed is clean the trimmed fit is the same model
    clean = skyline._sky_cost(px, seed & ~snowy)
    np.testing.assert_allclose(np.median(trimmed[blue]), np.median(clean[blue]), atol=1.0)


def test_the_sky_fields_spline_reproduces_a_linear_gradient_and_goes_on_below_it():
    # the hat functions sum to one on every row; a sky whose colour changes linearly with the row
    # is fitted exactly from its top third (the second differences of a line are zero), and its
    # lower rows, never fitted, cost as little as the fitted ones: the spline goes on linearly
    h, w = 96, 128
    design, penalty = skyline._sky_design(h, w)
    assert design.shape == (h * w, skyline._SKY_KNOTS + 1) and penalty.shape == (
        skyline._SKY_KNOTS - 2,
        design.shape[1],
    )
    np.testing.assert_allclose(design[:, :-1].sum(1), 1.0)
    rows = np.arange(h)[:, None, None] / h
    # features (Lab and texture) that change linearly down the rows, with a little noise
    feat = np.broadcast_to(np.array([70.0, -2.0, -30.0, 0.5]) + rows * np.array([20.0, 1.0, 25.0, 0.0]), (h, w, 4))
    rng = np.random.default_rng(2)
    px = skyline._Pixels((feat + rng.normal(0, 0.5, feat.shape)).astype(np.float32))
    fitted = np.zeros((h, w), bool)
    fitted[: h // 3] = True
    cost = skyline._sky_cost(px, fitted)
    assert np.median(cost[2 * h // 3 :]) < np.median(cost[: h // 3]) + 1.0  # nats


def test_the_quadratic_field_is_the_rule_before(monkeypatch):
    monkeypatch.setattr(skyline, "_SKY_FIELD", "quadratic")
    design, penalty = skyline._sky_design(4, 3)
    assert design.shape == (12, 4) and penalty.shape == (0, 4)
    np.testing.assert_allclose(design[:, 0], 1.0)
    np.testing.assert_allclose(design[5], [1.0, 0.25, 0.0625, 2 / 3 - 0.5])
