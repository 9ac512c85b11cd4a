"""Terrain: grid convention, bilinear F(x, y), procedural hills, sample DEM, DEM files."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib import cbook

from models.errors import InputError
from models.scenario import TerrainSpec
from models.terrain import Terrain, procedural_terrain, sample_terrain
from models.terrain_sources import load_terrain


@pytest.fixture
def ramp() -> Terrain:
    rng = np.random.default_rng(0)
    return Terrain(heights=rng.uniform(0, 100, (5, 7)), cell_size=10.0)


def test_grid_posts_are_cell_centres(ramp):
    h = ramp.heights
    for r, c in [(0, 0), (2, 3), (4, 6), (1, 5)]:
        assert ramp.height_at(c * 10.0, r * 10.0) == pytest.approx(h[r, c])
    assert ramp.extent == (0.0, 60.0, 0.0, 40.0)


def test_bilinear_between_posts(ramp):
    h = ramp.heights
    # a quarter of the way east and three quarters north inside cell (1, 2)
    x, y = 2 * 10 + 2.5, 1 * 10 + 7.5
    expected = h[1, 2] * 0.75 * 0.25 + h[1, 3] * 0.25 * 0.25 + h[2, 2] * 0.75 * 0.75 + h[2, 3] * 0.25 * 0.75
    assert ramp.height_at(x, y) == pytest.approx(expected)
    # on an edge, linear between the two posts
    assert ramp.height_at(35.0, 40.0) == pytest.approx((h[4, 3] + h[4, 4]) / 2)


def test_vectorised_and_clamped(ramp):
    xs = np.array([[-50.0, 0.0], [60.0, 1e6]])
    ys = np.array([[-1.0, 40.0], [-5.0, 20.0]])
    z = ramp.height_at(xs, ys)
    assert z.shape == (2, 2)
    h = ramp.heights
    np.testing.assert_allclose(z, [[h[0, 0], h[4, 0]], [h[0, 6], h[2, 6]]])
    assert isinstance(ramp.height_at(1.0, 2.0), float)


@pytest.mark.parametrize("heights", [np.zeros(5), np.zeros((1, 4)), np.array([[0, 1], [np.nan, 2]])])
def test_bad_heights_rejected(heights):
    with pytest.raises(ValueError, match="heights"):
        Terrain(heights=heights, cell_size=1.0)


def test_procedural_is_seeded_hills_and_valleys():
    a = procedural_terrain(size=128, relief=80.0, cell_size=10.0, rng=5)
    b = procedural_terrain(size=128, relief=80.0, cell_size=10.0, rng=5)
    c = procedural_terrain(size=128, relief=80.0, cell_size=10.0, rng=6)
    np.testing.assert_array_equal(a.heights, b.heights)
    assert not np.allclose(a.heights, c.heights)
    assert a.heights.min() == pytest.approx(0.0) and a.heights.max() == pytest.approx(80.0)
    # smooth: slopes a vehicle can drive, no cell-to-cell spikes
    slope = np.hypot(*np.gradient(a.heights, 10.0))
    assert np.percentile(slope, 99) < 1.0
    # second differences are small next to first ones (white noise: ~1.7 times larger)
    d1 = np.abs(np.diff(a.heights, axis=0)).mean()
    d2 = np.abs(np.diff(a.heights, 2, axis=0)).mean()
    assert d2 < 0.7 * d1
    # several hills: more than one local maximum well above the valleys
    from scipy.ndimage import maximum_filter

    peaks = (a.heights == maximum_filter(a.heights, size=15)) & (a.heights > 40)
    assert peaks.sum() >= 2


def test_sample_dem_is_flipped_so_row_zero_is_south():
    t = sample_terrain("jacksboro", cell_size=80.0)
    with cbook.get_sample_data("jacksboro_fault_dem.npz") as raw:
        elevation = raw["elevation"]
        assert raw["ymin"] > raw["ymax"]  # the file stores the northern row first
    assert t.shape == elevation.shape
    np.testing.assert_array_equal(t.heights[0], elevation[-1])
    assert t.cell_size == 80.0


def test_load_dem_file_and_errors(tmp_path):
    good = np.arange(12, dtype=np.float32).reshape(3, 4)
    np.save(tmp_path / "good.npy", good)
    t = load_terrain(TerrainSpec(cell_size=2.0, dem=tmp_path / "good.npy"), base_dir=tmp_path, seed=0)
    np.testing.assert_array_equal(t.heights, good)
    assert t.height_at(2.0, 2.0) == pytest.approx(good[1, 1])
    np.save(tmp_path / "flat.npy", np.zeros(5))
    (tmp_path / "junk.npy").write_bytes(b"not numpy")
    for name, message in [("flat.npy", "2-D array"), ("junk.npy", "cannot read DEM")]:
        with pytest.raises(InputError, match=message) as info:
            load_terrain(TerrainSpec(cell_size=2.0, dem=tmp_path / name), base_dir=tmp_path, seed=0)
        assert info.value.path == tmp_path / name


def test_procedural_spec_without_seed_uses_the_scenario_seed(tmp_path):
    spec = TerrainSpec(cell_size=5.0, procedural={"size": 32, "relief": 10.0})
    a = load_terrain(spec, base_dir=tmp_path, seed=1)
    b = load_terrain(spec, base_dir=tmp_path, seed=2)
    assert not np.allclose(a.heights, b.heights)
