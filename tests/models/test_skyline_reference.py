"""The faster horizon extraction of :mod:`models.skyline` gives the reference's (the code before it
was made faster, tests/models/skyline_reference.py) bit for bit: rendered views degraded like camera
images (clear, hazy, noisy, bright), synthetic skies, a padded camera frame, and the chain-MRF's
dynamic programme on its own (ties included)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.camera_emulator import CameraEmulator
from models.environment import build_environment
from models.scenario import SimulateSpec
from models.sensor import degrade
from models.skyline import _viterbi, image_boundary
from tests.models import skyline_reference as reference
from tests.models.test_skyline import _scenario

FOV = 45.0


def _same(image: np.ndarray) -> None:
    want_b, want_rows = reference.image_boundary(image)
    got_b, got_rows = image_boundary(image)
    assert got_rows == want_rows
    np.testing.assert_array_equal(got_b, want_b)


SPECS = [
    SimulateSpec(haze=0.0, noise=0.0, gain=0.0),
    SimulateSpec(haze=0.6, noise=4.0, gain=0.2, gamma=0.2, blur=0.8, texture=0.4),
    SimulateSpec(haze=0.3, noise=12.0, gain=0.4, gamma=0.2, blur=0.8, texture=0.4),
    SimulateSpec(haze=0.8, noise=20.0, gain=0.6),
]


@pytest.mark.parametrize("size", [(160, 120), (320, 240)])
def test_rendered_degraded_views_give_the_references_boundary(size):
    s = _scenario(*size)
    with CameraEmulator(build_environment(s), s.camera) as cam:
        for i, heading in enumerate((20.0, 80.0, 150.0, 230.0, 310.0)):
            view = cam.render(cam.pose_at(420.0, 380.0, heading))
            for j, spec in enumerate(SPECS):
                image = degrade(view.image, depth=view.depth, spec=spec, rng=10 * i + j)
                _same(image)
                if j == 1:  # a narrower camera frame's columns (skyline_from_image's ``columns``)
                    w = image.shape[1]
                    _same(image[:, w // 8 : w - w // 8])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_synthetic_skies_and_gray_images_give_the_references_boundary(seed):
    rng = np.random.default_rng(seed)
    h, w = (96, 96) if seed == 0 else (150, 200)
    cols = np.arange(w)
    horizon = (0.45 * h + 0.12 * h * np.sin(cols / w * 2 * math.pi * (1 + seed))).round()
    sky = np.arange(h)[:, None] < horizon[None, :]
    img = np.where(sky[..., None], [0.7, 0.8, 0.92], [0.35, 0.45, 0.22] * (1 + 0.25 * rng.standard_normal((h, w, 1))))
    haze = 0.2 * seed
    img = np.clip((img * (1 - haze) + 0.8 * haze) * 255 + rng.normal(0, 6, img.shape), 0, 255).astype(np.uint8)
    _same(img)
    _same(img[..., 1])  # gray
    _same(np.full((h, w, 3), 128, np.uint8))  # no boundary at all


@pytest.mark.parametrize("seed", range(6))
def test_the_dynamic_programme_gives_the_references_path(seed):
    rng = np.random.default_rng(seed)
    w = int(rng.integers(2, 200))
    unary = rng.normal(0, 3, (int(rng.integers(20, 140)), w)).cumsum(0)
    if seed % 2:
        unary = np.round(unary)  # ties between states and with the truncated jump
    for lam, jump in ((0.6, 8), (1.5, 3), (0.0, 1)):
        np.testing.assert_array_equal(
            _viterbi(unary, lam=lam, jump=jump), reference._viterbi(unary, lam=lam, jump=jump)
        )


def test_the_class_costs_and_the_contrast_are_the_references_bit_for_bit():
    from models.skyline import _contrast, _features, _Pixels, _sky_cost, _terrain_cost

    s = _scenario(160, 120)
    with CameraEmulator(build_environment(s), s.camera) as cam:
        view = cam.render(cam.pose_at(420.0, 380.0, 80.0))
    image = degrade(view.image, depth=view.depth, spec=SPECS[2], rng=5)
    feat = _features(np.ascontiguousarray(image.astype(np.float32) / 255.0))
    px = _Pixels(feat)
    np.testing.assert_array_equal(_contrast(feat), reference._contrast(feat))
    rows = np.arange(feat.shape[0])[:, None]
    horizon = 40 + (np.arange(feat.shape[1]) // 10)
    for sel in (np.broadcast_to(rows < 10, feat.shape[:2]), rows < horizon[None, :], rows >= horizon[None, :]):
        np.testing.assert_array_equal(_sky_cost(px, sel), reference._sky_cost(feat, sel))
        got = _terrain_cost(px, sel, np.random.default_rng(1))
        np.testing.assert_array_equal(got, reference._terrain_cost(feat, sel, np.random.default_rng(1)))


@pytest.mark.parametrize("seed", range(4))
def test_the_coarse_errors_are_the_references_bit_for_bit(seed):
    """Routes of references with invalid bins and runs, against camera profiles with invalid runs
    at the border and inside, over more references than a block."""
    from models.skyline_coarse import _BLOCK, CoarseSkylines, coarse_errors

    rng = np.random.default_rng(300 + seed)
    n = 115
    refs = np.cumsum(rng.normal(0, 0.4, (_BLOCK + 300, n)), axis=1) + rng.normal(0, 2, (_BLOCK + 300, 1))
    refs[rng.random(refs.shape) < 0.02] = np.nan
    for k in rng.integers(0, len(refs), 40):
        start = int(rng.integers(0, n))
        refs[k, start : start + int(rng.integers(1, 60))] = np.nan
    coarse = CoarseSkylines.prepare(refs.astype(np.float32))
    for _ in range(4):
        q = refs[rng.integers(len(refs))] + rng.normal(0, 0.3, n)
        q = np.roll(q, int(rng.integers(-10, 11)))
        q[: int(rng.integers(0, 30))] = np.nan
        start = int(rng.integers(0, n))
        q[start : start + int(rng.integers(0, 20))] = np.nan
        for kw in ({}, {"max_pitch_deg": 1.0, "truncate_deg": 1.0, "stride": 1}):
            np.testing.assert_array_equal(coarse_errors(q, coarse, **kw), reference.coarse_errors(q, coarse, **kw))


@pytest.mark.parametrize("m", [1, 2, 7, 90, 91, 115])
def test_the_row_medians_are_the_references(m):
    from models.skyline import _row_nanmedian

    rng = np.random.default_rng(m)
    d = np.round(rng.normal(0, 2, (300, m)), 1)  # ties
    d[rng.random(d.shape) < 0.3 * (np.arange(300) % 3 == 0)[:, None]] = np.nan
    d[:, 0][np.isnan(d).all(1)] = 0.5
    cnt = np.isfinite(d).sum(1)
    np.testing.assert_array_equal(_row_nanmedian(d, cnt), reference._row_nanmedian(d, cnt))


@pytest.mark.parametrize("max_roll_deg", [0.0, 3.0])
def test_the_full_match_is_the_references(monkeypatch, max_roll_deg):
    """The full match with the faster medians gives what it gives with the reference's (every field)."""
    import models.skyline as skyline

    rng = np.random.default_rng(7)
    refs = np.cumsum(rng.normal(0, 0.4, (400, 115)), axis=1)
    refs[rng.random(refs.shape) < 0.02] = np.nan
    q = np.roll(refs[123], 5) + rng.normal(0, 0.2, 115) + 1.0
    q[:10] = np.nan
    got = skyline.match_skylines(q, refs, max_roll_deg=max_roll_deg, roll_candidates=64)
    monkeypatch.setattr(skyline, "_row_nanmedian", reference._row_nanmedian)
    want = skyline.match_skylines(q, refs, max_roll_deg=max_roll_deg, roll_candidates=64)
    for f in ("error", "heading_deg", "pitch_deg", "overlap", "roll_deg"):
        np.testing.assert_array_equal(getattr(got, f), getattr(want, f), err_msg=f)
