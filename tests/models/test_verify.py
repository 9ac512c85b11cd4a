"""Render-and-compare verification: the memory-pattern correlation of aligned views, and the re-ranking."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.index import ViewframeIndex
from models.scenario import MemorySpec, SimulateSpec, SkylineSpec
from models.sensor import degrade
from models.verify import pattern_correlation, verified_ranking, verify_candidates


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
    assert r.renders == 4  # each candidate: its own view, then the aligned one
    assert r.correlations[1] > r.correlations[0] + 0.05, r.correlations
    assert r.headings_deg[1] == pytest.approx(64.0, abs=1.0)
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
