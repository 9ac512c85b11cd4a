"""Render-and-compare verification: the memory-pattern correlation of aligned views, and the re-ranking."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.index import ViewframeIndex
from models.scenario import MemorySpec, SimulateSpec, SkylineSpec
from models.sensor import degrade
from models.verify import (
    Alignment,
    memory_alignment,
    pattern_correlation,
    skyline_alignment,
    verified_ranking,
    verify_candidates,
)


def _match() -> dict[str, float]:
    sky = SkylineSpec()
    return {
        "step_deg": sky.step_deg,
        "max_heading_deg": sky.max_heading_deg,
        "max_pitch_deg": sky.max_pitch_deg,
        "truncate_deg": sky.truncate_deg,
    }


def test_pattern_correlation_is_one_for_a_shift_within_the_window_and_zero_without_energy():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(32, 32))
    a -= a.mean()
    a /= np.linalg.norm(a)
    shifted = np.roll(a, (2, -1), axis=(0, 1))
    assert pattern_correlation(a, shifted) == pytest.approx(1.0)
    assert pattern_correlation(a, np.roll(a, (6, 0), axis=(0, 1))) < 0.5  # beyond the window
    assert pattern_correlation(a, np.zeros_like(a)) == 0.0
    with pytest.raises(ValueError, match="one shape"):
        pattern_correlation(a, a[:16])


def test_verified_ranking_raises_the_worse_matches_and_sorts_again():
    ranking = [(7, 0.0), (3, 0.3), (5, 0.9), (1, 4.0)]
    out = verified_ranking(ranking, [7, 3, 5], [0.40, 0.60, 0.55], weight=2.8)
    assert [k for k, _ in out] == [3, 7, 5, 1]
    assert dict(out)[3] == pytest.approx(0.3) and dict(out)[7] == pytest.approx(2.8 * 0.2)
    assert dict(out)[1] == 4.0  # not verified: as it was
    assert verified_ranking(ranking, [7, 3], [0.5, 0.6], weight=0.0) == ranking  # no weight: no change
    with pytest.raises(ValueError, match="correlations"):
        verified_ranking(ranking, [7, 3], [0.5], weight=1.0)


def test_the_true_place_matches_its_aligned_view_better_than_a_wrong_first_candidate(emulator):
    """A camera frame 6 m off the true route point, turned 4 degrees and pitched 1 degree, with
    haze and noise (seeded): the candidate 40 m further along the heading ranks first by a small
    margin, and the verification puts the true one first."""
    true_point = emulator.pose_at(420.0, 380.0, 60.0)
    th = math.radians(true_point.heading_deg)
    camera = emulator.pose_at(true_point.x + 6.0 * math.cos(th), true_point.y + 6.0 * math.sin(th), 64.0, pitch_deg=1.0)
    view = emulator.render(camera, light_intensity=1.2, light_direction=(0.3, -0.5, -0.8))
    image = degrade(view.image, depth=view.depth, spec=SimulateSpec(haze=0.3, noise=5.0), rng=11)
    wrong = emulator.pose_at(true_point.x + 40.0 * math.cos(th), true_point.y + 40.0 * math.sin(th), 60.0)
    index = ViewframeIndex(MemorySpec(), seed=0)
    r = verify_candidates(image, emulator, [wrong, true_point], pattern=index.pattern, **_match())
    # each candidate: its own view, then one aligned view, or two when the memory's and the
    # skyline's alignments disagree
    assert 4 <= r.renders <= 6
    assert r.correlations[1] > r.correlations[0] + 0.05, r.correlations
    # the best-matching view's heading: 6 m from the camera's place the near ground's parallax moves it
    assert r.headings_deg[1] == pytest.approx(64.0, abs=1.5)
    ranking = [(1, 0.0), (0, 0.2)]  # the wrong one (viewframe 1) first, within the margin
    out = verified_ranking(ranking, [1, 0], r.correlations, weight=2.8)
    assert out[0][0] == 0


def test_the_roll_search_recovers_the_correlation_of_a_rolled_camera(emulator):
    from models.derotate import rolled

    place = emulator.pose_at(420.0, 380.0, 60.0)
    image = rolled(emulator.render(place).image, -3.0)  # the camera rolled by 3 degrees
    index = ViewframeIndex(MemorySpec(), seed=0)
    plain = verify_candidates(image, emulator, [place], pattern=index.pattern, **_match())
    searched = verify_candidates(
        image, emulator, [place], pattern=index.pattern, rolls_deg=(-3.0, 0.0, 3.0), max_roll_deg=3.0, **_match()
    )
    assert searched.correlations[0] > plain.correlations[0] + 0.1, (plain.correlations, searched.correlations)
    assert searched.correlations[0] > 0.8


def _per_deg(emulator, n: int) -> dict[str, float]:
    f = emulator.intrinsics[0] * math.radians(1.0)
    return {"rows_per_deg": f * n / emulator.height, "cols_per_deg": f * n / emulator.width}


@pytest.mark.parametrize(("turn", "lift"), [(3.0, 1.0), (-4.5, -0.8), (0.0, 0.0)])
def test_the_memory_alignment_finds_a_known_turn_of_the_camera(emulator, turn, lift):
    """The camera at a route point's place turned ``turn`` degrees left and pitched ``lift`` up:
    the memory's shift search gives the turn back to a fraction of a degree (to the pixel of the
    128-pattern: about half a degree)."""
    place = emulator.pose_at(420.0, 380.0, 60.0)
    camera = emulator.render_image(emulator.pose_at(place.x, place.y, 60.0 + turn, pitch_deg=lift))
    index = ViewframeIndex(MemorySpec(), seed=0)
    view = index.pattern(emulator.render_image(place))
    al, corr = memory_alignment(
        {0.0: index.pattern(camera)}, view, max_shift=MemorySpec().max_shift, **_per_deg(emulator, 128)
    )
    assert al.heading_deg == pytest.approx(turn, abs=0.5)
    assert al.pitch_deg == pytest.approx(lift, abs=0.5)
    assert al.roll_deg == 0.0 and corr > 0.5


def test_the_memory_alignment_of_a_featureless_view_is_no_turn():
    flat = np.zeros((32, 32), np.float32)
    al, corr = memory_alignment({0.0: flat}, flat, max_shift=(2, 2), rows_per_deg=1.0, cols_per_deg=1.0)
    assert (al, corr) == (Alignment(0.0, 0.0, 0.0), 0.0)


@pytest.mark.parametrize("roll", [-2.5, 2.0])
def test_the_skyline_alignment_finds_the_roll_that_levels_the_camera_image(emulator, roll):
    """A camera image turned by ``-roll`` (the camera rolled): the skyline alignment's roll is
    the turn that levels it again, ``roll`` (the convention of models.derotate.rolled)."""
    from models.derotate import rolled
    from models.skyline import skyline_from_image

    sky = SkylineSpec()
    place = emulator.pose_at(420.0, 380.0, 60.0)
    view = emulator.render(place)
    image = rolled(emulator.render_image(emulator.pose_at(place.x, place.y, 62.0)), -roll)
    q = skyline_from_image(image, fov_y_deg=emulator.camera.fov_y_deg, step_deg=sky.step_deg)
    al = skyline_alignment(q, view.depth, fov_y_deg=emulator.camera.fov_y_deg, max_roll_deg=3.0, **_match())
    assert al is not None
    assert al.roll_deg == pytest.approx(roll, abs=0.75)
    assert al.heading_deg == pytest.approx(2.0, abs=1.0)
    blind = np.full_like(q, np.nan)  # no horizon found in the camera image: no alignment offered
    assert (
        skyline_alignment(blind, view.depth, fov_y_deg=emulator.camera.fov_y_deg, max_roll_deg=3.0, **_match()) is None
    )


def test_a_turned_and_rolled_camera_matches_its_place_better_than_the_places_beside_it(emulator):
    """A camera 12 m along from a place, turned 6 degrees, pitched 1.5 degrees up and rolled 2:
    the view rendered turned as the camera was matches at the camera's place better than at the
    places 20 m behind and ahead, and the aligned heading is the camera's."""
    from models.derotate import rolled

    th = math.radians(60.0)
    at = lambda d: emulator.pose_at(420.0 + d * math.cos(th), 380.0 + d * math.sin(th), 60.0)  # noqa: E731
    truth = at(12.0)
    image = rolled(emulator.render_image(emulator.pose_at(truth.x, truth.y, 66.0, pitch_deg=1.5)), -2.0)
    index = ViewframeIndex(MemorySpec(), seed=0)
    r = verify_candidates(
        image,
        emulator,
        [at(-8.0), truth, at(32.0)],
        pattern=index.pattern,
        rolls_deg=(-3.0, -1.5, 0.0, 1.5, 3.0),
        max_roll_deg=3.0,
        **_match(),
    )
    assert r.correlations[1] > max(r.correlations[0], r.correlations[2]) + 0.05, r.correlations
    assert r.headings_deg[1] == pytest.approx(66.0, abs=0.75)
    assert r.pitches_deg[1] == pytest.approx(1.5, abs=0.75)
    assert r.rolls_deg is not None and r.rolls_deg[1] == pytest.approx(2.0, abs=0.8)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_skyline_alignment_is_the_skyline_match_over_heading_shifts(emulator, seed):
    """The alignment's one vectorised pass over the view's shifted profiles gives what
    models.skyline.match_skylines gives searching the heading shifts itself (heading, pitch,
    roll), on a camera profile of a turned, pitched view with noise and a few bins lost."""
    from models.skyline import match_skylines, skyline_from_depth

    sky = SkylineSpec()
    rng = np.random.default_rng(seed)
    place = emulator.pose_at(420.0, 380.0, 60.0 + 20.0 * seed)
    view = emulator.render(place)
    fov = emulator.camera.fov_y_deg
    cam = emulator.render(emulator.pose_at(place.x, place.y, place.heading_deg + rng.uniform(-6, 6), pitch_deg=1.0))
    q = skyline_from_depth(cam.depth, fov_y_deg=fov, step_deg=sky.step_deg).astype(np.float64)
    q += rng.normal(0.0, 0.1, q.shape)
    q[rng.integers(0, q.size, 5)] = np.nan
    q = q.astype(np.float32)  # a camera profile's type (models.skyline.skyline_from_image)
    ref = skyline_from_depth(view.depth, fov_y_deg=fov, step_deg=sky.step_deg)
    m = match_skylines(q, ref[None], max_roll_deg=3.0, **_match())
    al = skyline_alignment(q, view.depth, fov_y_deg=fov, max_roll_deg=3.0, **_match())
    assert al is not None
    assert al.heading_deg == pytest.approx(float(m.heading_deg[0]), abs=1e-9)
    assert al.pitch_deg == pytest.approx(float(m.pitch_deg[0]), abs=1e-9)
    assert m.roll_deg is not None and al.roll_deg == pytest.approx(float(m.roll_deg[0]), abs=1e-9)
