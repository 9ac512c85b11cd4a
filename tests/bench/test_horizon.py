"""bench/horizon.py: the horizon extraction measured against an evaluation case's true horizons."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench import horizon
from models import skyline


def test_a_frame_of_a_known_horizon_is_measured_and_its_rounds_counted():
    h, w = 120, 160
    rows = np.arange(h)[:, None]
    truth = np.full(w, 50.0)
    img = np.where((rows < truth[None, :])[..., None], [180, 200, 235], [90, 80, 50]).astype(np.uint8)
    img = np.broadcast_to(img, (h, w, 3)).copy()
    err, rounds, cpu = horizon.frame_errors(img, truth, fov_y_deg=45.0)
    assert err.size > 0.9 * skyline.profile_bins(w, h, fov_y_deg=45.0)
    assert float(np.median(err)) < 45.0 / h  # within a pixel
    assert 1 <= rounds <= skyline._ROUNDS and cpu >= 0
    # a horizon 20 rows off is measured as such (about 7 degrees at 45 degrees over 120 rows)
    off, _, _ = horizon.frame_errors(img, truth + 20, fov_y_deg=45.0)
    assert abs(float(np.median(off)) - math.degrees(math.atan(20 / (60 / math.tan(math.radians(22.5)))))) < 0.5


@pytest.mark.parametrize("rounds", [1, 3])
def test_fixed_rounds_run_exactly_that_many_and_restore_the_rule(rounds):
    before = skyline._ROUNDS, skyline._SETTLED
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (60, 80, 3), dtype=np.uint8)
    with horizon.fixed_rounds(rounds):
        _, got, _ = horizon.frame_errors(img, np.full(80, 30.0), fov_y_deg=45.0)
    assert got == rounds
    assert (skyline._ROUNDS, skyline._SETTLED) == before


def test_an_evaluation_case_is_measured_under_both_rules(tmp_path):
    got = horizon.run(
        "heldout", names=["h-fbm-rough"], kinds=["sweep"], rules=(None, 3), max_frames=2, out_dir=tmp_path
    )
    assert list(got["cases"]) == ["h-fbm-rough/sweep"]
    assert set(got["all"]) == {"default", "3 rounds"}
    for m in got["all"].values():
        assert m["frames"] == 2 and m["median_deg"] is not None and 0 <= m["frames_off"] <= 1
    assert got["all"]["3 rounds"]["rounds"] == 3.0
    assert "h-fbm-rough/sweep" in horizon.table(got)


@pytest.mark.parametrize("rounds", [0, 1])
def test_seed_trim_sets_the_rounds_and_restores_the_default(rounds):
    before = skyline._SEED_TRIM_ROUNDS
    with horizon.seed_trim(rounds):
        assert skyline._SEED_TRIM_ROUNDS == rounds
    with horizon.seed_trim(None):
        assert skyline._SEED_TRIM_ROUNDS == before
    assert skyline._SEED_TRIM_ROUNDS == before


def test_snow_beside_the_sky_in_the_top_rows_is_not_taken_for_sky(tmp_path):
    # the first frames of a tuning-snow sweep (raster renderer: ridged mountains whose snow reaches
    # into the top rows beside a blue sky): the trimmed seed finds the horizon, the untrimmed one
    # (the rule before session 15) took the snowfield for sky and put the horizon at the snow line
    run = horizon.run("tuning-snow", names=["tn-ridged"], kinds=["sweep"], max_frames=3, out_dir=tmp_path)
    with horizon.seed_trim(0):
        before = horizon.run("tuning-snow", names=["tn-ridged"], kinds=["sweep"], max_frames=3, out_dir=tmp_path)
    assert run["all"]["default"]["frames"] == 3
    assert run["all"]["default"]["frames_off"] == 0.0 and run["all"]["default"]["median_deg"] < 0.5
    assert before["all"]["default"]["frames_off"] == 1.0 and before["all"]["default"]["median_deg"] > 2.0


@pytest.mark.parametrize("kind", ["quadratic", "spline"])
def test_sky_field_sets_the_field_and_restores_the_default(kind):
    before = skyline._SKY_FIELD
    with horizon.sky_field(kind):
        assert skyline._SKY_FIELD == kind
    assert skyline._SKY_FIELD == before
    with pytest.raises(ValueError, match="sky field"):
        with horizon.sky_field("cubic"):
            pass
