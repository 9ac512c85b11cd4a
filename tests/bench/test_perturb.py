"""The camera-image perturbations of bench/perturb.py: what each changes, and the true sky they use."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

_BENCH = str(Path(__file__).resolve().parents[2] / "bench")
sys.path.insert(0, _BENCH)
import perturb  # noqa: E402  (it takes bench/ off the path again: bench/blackboard.py would shadow the package)

assert _BENCH not in sys.path

SKY_ONLY = ("overcast", "clouds")


def _frame() -> tuple[np.ndarray, np.ndarray]:
    """A blue sky over a brown textured slope, (60, 80, 3) uint8, and its sky mask."""
    rng = np.random.default_rng(3)
    rows, cols = np.mgrid[0:60, 0:80]
    sky = rows < 20 + cols // 8
    img = np.where(sky[..., None], [110, 150, 210], [120, 95, 70]).astype(np.float64)
    img[~sky] += rng.normal(0, 8, (int((~sky).sum()), 3))
    return np.clip(img, 0, 255).astype(np.uint8), sky


@pytest.mark.parametrize("name", [n for n, f in perturb.PERTURBATIONS.items() if f is not None])
def test_a_perturbation_keeps_the_frame_and_changes_it(name):
    img, sky = _frame()
    out = perturb.PERTURBATIONS[name](img, sky, np.random.default_rng(0))
    assert out.shape == img.shape and out.dtype == np.uint8
    assert np.abs(out.astype(int) - img).mean() > 1.0  # it does something
    if name in SKY_ONLY:  # the terrain is left as it was, the sky changed
        np.testing.assert_array_equal(out[~sky], img[~sky])
        assert np.abs(out[sky].astype(int) - img[sky]).mean() > 10


def test_the_sky_masks_follow_the_labelled_horizon(tmp_path):
    """labels.npz holds the horizon row per column of the native frame (here 2x the camera's)."""
    horizons = np.tile(np.linspace(40.0, 80.0, 160, dtype=np.float32), (2, 1))  # (frames, native cols)
    horizons[1, :80] = np.nan  # no horizon labelled there: interpolated from the rest
    np.savez(tmp_path / "labels.npz", horizons=horizons)
    masks = perturb.sky_masks(tmp_path, (60, 80))
    assert masks.shape == (2, 60, 80)
    sky_rows = masks[0].sum(axis=0)
    assert sky_rows[0] == pytest.approx(20, abs=1) and sky_rows[-1] == pytest.approx(40, abs=1)
    assert np.all(np.diff(sky_rows) >= 0)
    assert masks[1].sum(axis=0)[0] == pytest.approx(30, abs=1.5)  # the first labelled column's height
