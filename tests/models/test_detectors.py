from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from models.detectors import (
    LR_FEATURES,
    Calibration,
    CandidateView,
    DetectorRegistry,
    EdgeTemplateDetector,
    LandmarkDetector,
    align_pixels,
    default_registry,
    edge_image,
    orientation_field,
    orientation_fields,
)
from models.scenario import SchedulerSpec

SPEC = SchedulerSpec()


def _registry(**kw) -> DetectorRegistry:
    """The registry with the scenario schema's defaults (thresholds, calibration)."""
    opts = {
        "threshold": SPEC.detector_threshold,
        "absent_threshold": SPEC.absent_threshold,
        "calibration": SPEC.calibration,
        "align_px": align_pixels(height=120, fov_y_deg=45.0, tolerance_deg=SPEC.align_deg),
    }
    return default_registry(**{**opts, **kw})


H, W = 120, 160


def _scene(
    rng: np.random.Generator,
    *,
    box: tuple[int, int, int, int] | None,
    noise: float = 3.0,
    sky: float = 180.0,
    wall: float = 90.0,
    shift: tuple[int, int] = (0, 0),
) -> np.ndarray:
    """A gray sky over ground with an optional dark box (row0, col0, row1, col1), as RGB uint8."""
    img = np.full((H, W), sky, np.float32)
    img[80:, :] = 120.0
    if box is not None:
        r0, c0, r1, c1 = box
        img[r0 + shift[0] : r1 + shift[0], c0 + shift[1] : c1 + shift[1]] = wall
    img += rng.normal(0.0, noise, img.shape)
    img = np.clip(img, 0, 255).astype(np.uint8)
    return np.repeat(img[..., None], 3, axis=2)


BOX = (50, 60, 80, 90)


def _view(rng) -> CandidateView:
    sil = np.zeros((H, W), bool)
    sil[BOX[0] : BOX[2], BOX[1] : BOX[3]] = True
    return CandidateView(_scene(rng, box=BOX, noise=0.0), sil)


@pytest.mark.parametrize(
    "case, expected",
    [
        ({"box": BOX}, True),
        ({"box": BOX, "shift": (3, -5)}, True),  # a few pixels off the expected place
        ({"box": BOX, "sky": 150.0, "wall": 110.0, "noise": 6.0}, True),  # other lighting, more noise
        ({"box": None}, False),  # only sky and ground where the box should be
        ({"box": None, "noise": 12.0}, False),  # noisy empty sky must not look like the outline
    ],
)
def test_edge_template_present_and_absent(case, expected):
    rng = np.random.default_rng(4)
    det = EdgeTemplateDetector(threshold=0.55, absent_threshold=0.35)
    result = det.detect(_scene(rng, **case), view=_view(rng))
    assert result.present is expected, result
    assert -1.0 <= result.score <= 1.0
    # the cautious defaults never call an absent landmark present, nor a present one absent
    default = EdgeTemplateDetector().detect(_scene(np.random.default_rng(4), **case), view=_view(rng))
    assert default.present is not (not expected), default


def test_found_location_follows_the_shift():
    rng = np.random.default_rng(5)
    det = EdgeTemplateDetector()
    at = det.detect(_scene(rng, box=BOX), view=_view(rng)).location
    moved = det.detect(_scene(rng, box=BOX, shift=(2, 6)), view=_view(rng)).location
    assert (moved[0] - at[0], moved[1] - at[1]) == (2, 6)


def test_tiny_silhouette_is_undecided():
    rng = np.random.default_rng(6)
    sil = np.zeros((H, W), bool)
    sil[60:63, 70:72] = True
    result = EdgeTemplateDetector(min_pixels=24).detect(
        _scene(rng, box=BOX), view=CandidateView(_scene(rng, box=BOX), sil)
    )
    assert result.present is None
    assert "pixels" in result.reason


def test_shape_mismatch_names_the_problem():
    rng = np.random.default_rng(7)
    with pytest.raises(ValueError, match="must equal the viewframe"):
        EdgeTemplateDetector().detect(np.zeros((60, 80, 3), np.uint8), view=_view(rng))


@pytest.mark.parametrize("axis", ["both", "x", "y"])
def test_edge_image_range_and_orientation(axis):
    img = np.zeros((40, 40), np.uint8)
    img[:, 20:] = 200  # one vertical edge
    e = edge_image(img, axis=axis)
    assert e.shape == (40, 40) and e.dtype == np.float32
    assert 0.0 <= e.min() and e.max() <= 1.0
    col_energy, row_energy = e[:, 18:22].sum(), e[18:22, :].sum()
    if axis == "y":
        assert e.max() < 1e-6  # a vertical edge has no vertical gradient
    else:
        assert col_energy > 0.9 * e.sum() > 0 and row_energy < col_energy


def test_orientation_field_keeps_the_direction_whatever_the_contrast_and_polarity():
    """A vertical edge of 200 gray levels, the same edge of 20 and its reverse (light on dark)
    give nearly the same soft-normalised direction field, where the edge magnitude differs tenfold;
    a horizontal edge points the other way in the doubled angle and is absent from the vertical
    field."""
    strong = np.zeros((40, 40), np.uint8)
    strong[:, 20:] = 200
    faint = np.full((40, 40), 100, np.uint8)
    faint[:, 20:] = 120
    reverse = 200 - strong
    f_strong, f_faint, f_reverse = (orientation_field(im) for im in (strong, faint, reverse))
    assert f_strong.shape == (40, 40, 2) and f_strong.dtype == np.float32
    assert np.abs(f_strong).max() <= 1.0
    edge = (slice(5, 35), slice(19, 21))
    assert f_strong[edge][..., 0].mean() > 0.8  # cos 2 theta = 1 for a vertical edge (gradient along x)
    assert np.abs(f_faint[edge] - f_strong[edge]).max() < 0.1
    assert np.abs(f_reverse - f_strong).max() < 1e-5
    e_strong, e_faint = edge_image(strong, blur_sigma=0), edge_image(faint, blur_sigma=0)
    assert e_strong.max() == e_faint.max() == 1.0  # edge_image scales each image to its own top...
    assert orientation_field(faint, axis="x")[edge].mean() > 0.8  # ...the field needs no such scaling
    horizontal = strong.T.copy()
    f_h = orientation_fields(horizontal)
    assert f_h["both"][19:21, 5:35, 0].mean() < -0.8  # cos 2 theta = -1
    assert f_h["x"].max() < 1e-6
    with pytest.raises(ValueError, match="axis"):
        orientation_field(strong, axis="y")


def test_registry_protocol_and_fallback():
    reg = _registry()
    assert {"house", "barn", "tower", "silo"} <= set(reg.kinds)  # every kind of the bundled scenarios
    assert isinstance(reg.for_kind("house"), LandmarkDetector)
    assert reg.for_kind("windmill").name == "box-outline"  # no own detector: the box fallback
    with pytest.raises(KeyError, match="silo"):
        DetectorRegistry().for_kind("silo")
    with pytest.raises(TypeError, match="LandmarkDetector"):
        reg.register("barn", object())


@pytest.mark.slow
def test_rendered_house_found_from_its_viewframe_and_not_elsewhere():
    """Real pyrender views: the camera near the viewframe sees the house; far past it, not."""
    from models.camera_emulator import CameraEmulator
    from models.environment import build_environment
    from models.scenario import scenario_from_dict
    from models.sensor import degrade

    data = {
        "name": "detector-test",
        "seed": 1,
        "terrain": {"cell_size": 10.0, "procedural": {"size": 64, "relief": 30.0, "seed": 3}},
        "landmarks": [{"id": "H1", "kind": "house", "x": 300, "y": 300, "width": 20, "depth": 12, "height": 8}],
        "route": [[240, 300], [300, 240]],
        "camera": {"width": W, "height": H, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 5000.0},
        "sensor": {"simulate": {}},
    }
    scenario = scenario_from_dict(data, path=Path("/nonexistent/detector-test.yaml"))
    env = build_environment(scenario)
    with CameraEmulator(env, scenario.camera) as cam:
        vf = cam.render(cam.pose_at(240, 300, 0.0))  # looking east at the house, 60 m away
        assert (vf.mask == 0).sum() > 100
        near = cam.render(cam.pose_at(242, 301, 2.0), light_intensity=2.2)  # a camera frame near it
        away = cam.render(cam.pose_at(240, 300, 180.0))  # looking west: the house is behind
    rng = np.random.default_rng(2)
    spec = scenario.sensor.simulate
    det = _registry().for_kind("house")
    view = CandidateView.from_mask(vf.image, vf.mask, 0)
    found = det.detect(degrade(near.image, depth=near.depth, spec=spec, rng=rng), view=view)
    missed = det.detect(degrade(away.image, depth=away.depth, spec=spec, rng=rng), view=view)
    assert found.present is True, found
    assert missed.present is not True, missed
    assert found.score > missed.score + 0.2


def test_align_pixels_follow_the_field_of_view_and_size():
    small = align_pixels(height=120, fov_y_deg=45.0, tolerance_deg=(2.0, 5.0), margin=0)
    big = align_pixels(height=480, fov_y_deg=45.0, tolerance_deg=(2.0, 5.0), margin=0)
    assert small == (6, 13)  # f = 60 / tan(22.5°) = 144.9 px: 2° -> 5.06, 5° -> 12.7
    assert big[0] >= 4 * small[0] - 4 and big[1] >= 4 * small[1] - 4
    with pytest.raises(ValueError, match="tolerance_deg"):
        align_pixels(height=120, fov_y_deg=45.0, tolerance_deg=(50.0, 5.0))


def test_calibration_is_affine_in_the_features_and_checks_its_size():
    cal = Calibration.from_sequence([0.5, 2.0, -1.0, 0.25, 3.0, -2.0])
    assert cal.llr((1.0, 0.5, 2.0, 0.1, 0.5)) == pytest.approx(0.5 + 2.0 - 0.5 + 0.5 + 0.3 - 1.0)
    with pytest.raises(ValueError, match="numbers"):
        Calibration.from_sequence([1.0, 2.0, 3.0, 4.0, 5.0])
    assert LR_FEATURES == ("statistic", "orientation", "vertical", "contrast", "context")
    # every family and kind the schema calibrates builds
    for values in SPEC.calibration.values():
        Calibration.from_sequence(values)


def test_without_view_needs_a_background_of_the_same_shape():
    rng = np.random.default_rng(8)
    view = _view(rng)
    mask = np.where(view.silhouette, 0, -1)
    with pytest.raises(ValueError, match="background shape"):
        CandidateView.from_mask(view.image, mask, 0, background=np.zeros((10, 10, 3), np.uint8))
    bg = np.full_like(view.image, 200)
    cv = CandidateView.from_mask(view.image, mask, 0, background=bg)
    assert (cv.without[view.silhouette] == 200).all()
    assert (cv.without[~view.silhouette] == view.image[~view.silhouette]).all()


def _red(image: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """``image`` with the box's red channel raised: the with/without colour statistic needs a colour."""
    out = image.copy()
    out[box[0] : box[2], box[1] : box[3], 0] = 150
    return out


def _red_view(rng) -> CandidateView:
    """A viewframe with a red box at :data:`BOX` and its view without it (both drawn from ``rng``)."""
    sil = np.zeros((H, W), bool)
    sil[BOX[0] : BOX[2], BOX[1] : BOX[3]] = True
    image = _red(_scene(rng, box=BOX, noise=0.0), BOX)
    return CandidateView.from_mask(image, np.where(sil, 0, -1), 0, background=_scene(rng, box=None, noise=0.0))


def test_scale_search_finds_a_landmark_nearer_than_its_viewframe_shows_it():
    """A camera frame taken nearer the landmark than the viewframe shows it 1.3 times larger: the
    likelihood ratio's edge score and contrast searched over template scales find it better than
    at the viewframe's scale alone, and the view without it scores lower than both."""

    rng = np.random.default_rng(9)
    view = _red_view(rng)
    r0, c0, r1, c1 = BOX
    big = (r0 - 4, c0 - 5, r1 + 5, c1 + 4)  # 39 x 39 pixels instead of 30 x 30
    frame = _red(_scene(np.random.default_rng(10), box=big, noise=3.0), big)
    empty = _scene(np.random.default_rng(10), box=None, noise=3.0)
    align = align_pixels(height=H, fov_y_deg=45.0, tolerance_deg=SPEC.align_deg)
    scaled = EdgeTemplateDetector(align_px=align, scales=SPEC.detector_scales)
    fixed = EdgeTemplateDetector(align_px=align, scales=(1.0,))
    s_scaled, s_fixed, s_empty = (
        d.evidence(im, view=view) for d, im in [(scaled, frame), (fixed, frame), (scaled, empty)]
    )
    assert s_scaled is not None and s_fixed is not None and s_empty is not None
    assert s_scaled[1] > s_fixed[1] + 0.05, (s_scaled, s_fixed)  # the edge score
    assert s_scaled[2] >= s_fixed[2]  # the contrast
    assert s_empty[1] < s_fixed[1] and s_empty[2] < s_fixed[2]


@pytest.mark.parametrize("scales", [(1.0,), (0.5, 1.0, 2.0)])
def test_scaled_templates_near_the_border_keep_their_shape(scales):
    """A silhouette cut by the image border, searched over scales, still gives finite evidence."""
    rng = np.random.default_rng(11)
    sil = np.zeros((H, W), bool)
    sil[40:90, 140:] = True
    image = _red(_scene(rng, box=(40, 140, 90, W), noise=0.0), (40, 140, 90, W))
    view = CandidateView.from_mask(image, np.where(sil, 0, -1), 0, background=_scene(rng, box=None, noise=0.0))
    frame = _red(_scene(rng, box=(42, 136, 92, W)), (42, 136, 92, W))
    ev = EdgeTemplateDetector(scales=scales).evidence(frame, view=view)
    assert ev is not None and all(np.isfinite(ev))


#: landmark sizes of the render tests (metres)
_SIZES = {
    "house": {"width": 20, "depth": 12, "height": 8},
    "tower": {"width": 4, "depth": 4, "height": 30},
    "silo": {"width": 7, "depth": 7, "height": 16},
    "barn": {"width": 30, "depth": 16, "height": 10},
}


def _one_landmark(kind: str, name: str, *, y: float, start: list[float], **more: object):
    """A small terrain with one landmark ``L1`` of ``kind`` at (300, ``y``), a route from ``start``."""
    from models.scenario import scenario_from_dict

    data = {
        "name": name,
        "seed": 1,
        "terrain": {"cell_size": 10.0, "procedural": {"size": 64, "relief": 30.0, "seed": 3}},
        "landmarks": [{"id": "L1", "kind": kind, "x": 300, "y": y, **_SIZES[kind]}],
        "route": [start, [300, 240]],
        "camera": {"width": W, "height": H, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 5000.0},
        **more,
    }
    return scenario_from_dict(data, path=Path(f"/nonexistent/{name}.yaml"))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["house", "tower", "silo", "barn"])
def test_likelihood_ratio_on_real_renders_with_and_without_the_landmark(kind):
    """Real pyrender views: the camera frame near the viewframe, once with the landmark and once
    the same view without it (the emulator leaves the boxes out), degraded like a camera, with
    heading and pitch errors. The calibrated log-likelihood ratio must favour the landmark in the
    first and its absence in the second."""
    from models.camera_emulator import CameraEmulator
    from models.environment import build_environment
    from models.sensor import degrade

    scenario = _one_landmark(kind, "lr-test", y=300, start=[240, 300], sensor={"simulate": {}})
    env = build_environment(scenario)
    spec = scenario.sensor.simulate
    det = _registry().for_kind(kind)
    with CameraEmulator(env, scenario.camera) as cam:
        pose = cam.pose_at(240, 300, 0.0)
        vf = cam.render(pose)
        view = CandidateView.from_mask(vf.image, vf.mask, 0, background=cam.render_background(pose))
        assert (vf.mask == 0).sum() > 60
        results = []
        for i, (dh, dp) in enumerate([(0.0, 0.0), (3.5, 1.5), (-4.0, -1.5)]):
            near = cam.pose_at(242, 301, dh, pitch_deg=dp)
            rng = np.random.default_rng(20 + i)
            with_lm = cam.render(near, light_intensity=1.3)
            without_lm = cam.render_background(near, light_intensity=1.3)
            d_with = det.detect(degrade(with_lm.image, depth=with_lm.depth, spec=spec, rng=rng), view=view)
            d_without = det.detect(degrade(without_lm, depth=with_lm.depth, spec=spec, rng=rng), view=view)
            results.append((d_with.llr, d_without.llr))
    for llr_with, llr_without in results:
        assert llr_with is not None and llr_without is not None
        assert llr_with > 0.0 > llr_without, results


@pytest.mark.slow
def test_likelihood_ratio_rejects_a_look_alike_of_half_the_size():
    """Real pyrender views: the viewframe shows house L1 (20 x 12 x 8 m) 60 m ahead; camera frames
    near it (with heading and pitch errors, degraded like a camera) show it, show nothing there,
    or show a house of half its size in its place. The likelihood ratio must favour the first
    and disfavour the other two; the edge-direction features must score the look-alike lower
    than the landmark itself (the edge magnitude score of session 4 gave the look-alike a positive
    log-likelihood ratio, +0.1 to +0.3)."""
    from models.camera_emulator import CameraEmulator
    from models.environment import build_environment
    from models.sensor import degrade

    house = {"width": 20, "depth": 12, "height": 8}
    true = _one_landmark("house", "lookalike-true", y=300, start=[240, 300], sensor={"simulate": {}})
    small = _one_landmark("house", "lookalike-small", y=300, start=[240, 300], sensor={"simulate": {}})
    small = small.model_copy(
        update={"landmarks": [small.landmarks[0].model_copy(update={k: v / 2 for k, v in house.items()})]}
    )
    assert true.landmarks[0].width == 20 and small.landmarks[0].width == 10
    spec = true.sensor.simulate
    det = _registry().for_kind("house")
    with (
        CameraEmulator(build_environment(true), true.camera) as cam,
        CameraEmulator(build_environment(small), small.camera) as cam_small,
    ):
        pose = cam.pose_at(240, 300, 0.0)
        vf = cam.render(pose)
        view = CandidateView.from_mask(vf.image, vf.mask, 0, background=cam.render_background(pose))
        assert (vf.mask == 0).sum() > 300
        for i, (dh, dp) in enumerate([(0.0, 0.0), (3.5, 1.5), (-4.0, -1.5)]):
            near = cam.pose_at(242, 301, dh, pitch_deg=dp)
            with_lm, look_alike = cam.render(near, light_intensity=1.3), cam_small.render(near, light_intensity=1.3)
            assert 0 < (look_alike.mask == 0).sum() < 0.5 * (with_lm.mask == 0).sum()
            frames = {
                "landmark": degrade(with_lm.image, depth=with_lm.depth, spec=spec, rng=np.random.default_rng(30 + i)),
                "look-alike": degrade(
                    look_alike.image, depth=look_alike.depth, spec=spec, rng=np.random.default_rng(30 + i)
                ),
                "nothing": degrade(
                    cam.render_background(near, light_intensity=1.3),
                    depth=with_lm.depth,
                    spec=spec,
                    rng=np.random.default_rng(30 + i),
                ),
            }
            llr = {k: det.detect(im, view=view).llr for k, im in frames.items()}
            ev = {k: det.evidence(im, view=view) for k, im in frames.items()}
            assert llr["landmark"] > 1.0 and llr["look-alike"] < 0.0 and llr["nothing"] < 0.0, llr
            for f in ("orientation", "vertical", "context"):
                j = LR_FEATURES.index(f)
                assert ev["landmark"][j] > ev["look-alike"][j] + 0.15, (f, ev)
            j = LR_FEATURES.index("context")
            assert ev["landmark"][j] > ev["nothing"][j] + 0.1, ev


def test_context_is_the_landmarks_surroundings():
    """The same box at the same place, once against the viewframe's surroundings (the horizon
    along its foot) and once against others (the ground 20 rows lower, a look-alike standing
    elsewhere): the edge directions on the box itself agree alike, the context ring only in the
    first."""
    rng = np.random.default_rng(15)
    view = _red_view(rng)
    same = _red(_scene(np.random.default_rng(16), box=BOX, noise=3.0), BOX)
    elsewhere = same.copy()
    elsewhere[80:100] = _scene(np.random.default_rng(17), box=None, noise=3.0)[40:60]  # sky down to row 100
    elsewhere[BOX[0] : BOX[2], BOX[1] : BOX[3]] = same[BOX[0] : BOX[2], BOX[1] : BOX[3]]
    det = _registry().for_kind("house")
    ev_same, ev_elsewhere = det.evidence(same, view=view), det.evidence(elsewhere, view=view)
    assert ev_same is not None and ev_elsewhere is not None
    o, c = LR_FEATURES.index("orientation"), LR_FEATURES.index("context")
    assert ev_same[c] > ev_elsewhere[c] + 0.2, (ev_same, ev_elsewhere)
    assert abs(ev_same[o] - ev_elsewhere[o]) < 0.15, (ev_same, ev_elsewhere)


@pytest.mark.parametrize(
    "box, scale",
    [
        (BOX, 1.0),
        ((53, 53, 83, 83), 1.0),  # 3 rows down, 7 columns left
        ((46, 70, 76, 100), 1.0),  # 4 rows up, 10 columns right
        ((46, 55, 85, 94), 1.3),  # nearer: 39 x 39 pixels instead of 30 x 30, its centre 1.5 px up-left
        ((52, 66, 76, 90), 0.8),  # farther: 24 x 24, and off to the right
    ],
)
def test_the_match_reports_where_and_how_large_the_landmark_is(box, scale):
    """The detector's best match (``Detection.where``): the centroid of the landmark in the camera
    image within a pixel, and its scale against the viewframe's silhouette within one step of the
    scale search."""
    rng = np.random.default_rng(12)
    view = _red_view(rng)
    frame = _red(_scene(np.random.default_rng(13), box=box, noise=3.0), box)
    det = _registry().for_kind("house")
    found = det.detect(frame, view=view)
    assert found.where is not None and found.where == det.match(frame, view=view)
    row, col, s = found.where
    assert abs(row - (box[0] + box[2] - 1) / 2) <= 1.0 and abs(col - (box[1] + box[3] - 1) / 2) <= 1.0, found.where
    assert abs(np.log(s / scale)) <= 0.1, found.where


def test_no_place_without_a_likelihood_ratio():
    rng = np.random.default_rng(14)
    found = EdgeTemplateDetector().detect(_scene(rng, box=BOX), view=_view(rng))  # no calibration, no background
    assert found.llr is None and found.where is None


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["house", "silo"])
def test_the_match_on_real_renders_follows_a_known_turn_and_approach(kind):
    """Real pyrender views: the camera frame taken 12 m nearer the landmark than its viewframe and
    turned 2 degrees clockwise. The detector's found place, as a placement (models.placement), is where
    the landmark's mask rendered at the frame's pose puts it (within a degree and 15% of size), and
    further from where the viewframe shows it."""
    from models.camera_emulator import CameraEmulator
    from models.environment import build_environment
    from models.placement import found_placement, placement

    scenario = _one_landmark(kind, "where-test", y=310, start=[230, 300])
    env = build_environment(scenario)
    det = _registry().for_kind(kind)
    with CameraEmulator(env, scenario.camera) as cam:
        pose = cam.pose_at(230, 300, 0.0)
        vf = cam.render(pose)
        view = CandidateView.from_mask(vf.image, vf.mask, 0, background=cam.render_background(pose))
        near = cam.render(cam.pose_at(242, 300, -2.0), light_intensity=1.3)
    found = det.detect(near.image, view=view)
    assert found.llr is not None and found.llr > 0 and found.where is not None
    obs = found_placement(found.where, pixels=int(view.silhouette.sum()), shape=near.image.shape, fov_y_deg=45.0)

    def place(mask):
        rows, cols = np.nonzero(mask == 0)
        return placement(rows.mean(), cols.mean(), len(rows), shape=mask.shape, fov_y_deg=45.0)

    truth, predicted = place(near.mask), place(vf.mask)
    assert abs(obs[0] - truth[0]) < 1.0 and abs(obs[1] - truth[1]) < 1.0, (obs, truth)
    assert abs(np.log(obs[2] / truth[2])) < 0.15, (obs, truth)
    assert abs(obs[1] - predicted[1]) > abs(obs[1] - truth[1]) + 1.0 and obs[2] > 1.1 * predicted[2]
