"""The viewframe index: one pipeline (preprocess, K-GEN, store, rank) with a scenario's memory settings."""

from __future__ import annotations

import numpy as np
import pytest

from models.associative import BankedMemory
from models.errors import AssociativeMemoryError
from models.index import ViewframeIndex, memory_settings
from models.preprocess import preprocess
from models.scenario import MemorySpec
from models.synthetic import scene

SETTINGS = [
    {},
    {
        "size": 64,
        "edge": "canny",
        "blur_sigma": 3.0,
        "whiten": False,
        "bank_size": 3,
        "max_shift": (1, 4),
        "key": "quantized",
    },
]


@pytest.mark.parametrize("settings", SETTINGS)
def test_the_index_reads_every_memory_setting(settings) -> None:
    spec = MemorySpec(**settings)
    for given in (spec, spec.model_dump()):  # a spec, or the plain data the map hypothesis carries
        index = ViewframeIndex(given, seed=5)
        mem = index.memory
        assert (mem.size, mem.bank_size, mem.key_method, mem.max_shift, mem.seed) == (
            spec.size,
            spec.bank_size,
            spec.key,
            tuple(spec.max_shift),
            5,
        )
        assert index.settings == spec


@pytest.mark.parametrize("settings", SETTINGS)
def test_patterns_are_preprocess_with_the_settings(settings) -> None:
    spec = MemorySpec(**settings)
    image = np.random.default_rng(3).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    expected = preprocess(image, size=spec.size, edge=spec.edge, blur_sigma=spec.blur_sigma, whiten=spec.whiten)
    got = ViewframeIndex(spec).pattern(image)
    # two identical preprocess calls may differ in the last bits (~1e-9): compare to 1e-6, far
    # below what a different size, edge method or blur changes (unit-energy patterns)
    assert got.shape == expected.shape
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-6)


def test_ranking_equals_the_memory_built_by_hand() -> None:
    rng = np.random.default_rng(11)
    images = [scene(rng) for _ in range(7)]
    spec = MemorySpec(size=64, bank_size=3, max_shift=(1, 3))
    index = ViewframeIndex(spec, seed=2)
    index.add(images, [10, 11, 12, 13, 14, 15, 16])
    assert len(index) == 7 and index.viewframes.tolist() == [10, 11, 12, 13, 14, 15, 16]
    by_hand = BankedMemory(64, bank_size=3, seed=2, key_method="phase", max_shift=(1, 3))
    by_hand.write_many([preprocess(im, size=64, blur_sigma=spec.blur_sigma) for im in images], range(10, 17))
    query = np.roll(images[4], 2, axis=1)
    got, want = index.rank(query), by_hand.rank(preprocess(query, size=64, blur_sigma=spec.blur_sigma))
    assert got.best == 14
    assert got.viewframes.tolist() == want.viewframes.tolist()
    np.testing.assert_allclose(got.variances, want.variances, rtol=1e-5)
    assert index.rank_pattern(index.pattern(query)).viewframes.tolist() == got.viewframes.tolist()


@pytest.mark.parametrize(
    ("settings", "field"),
    [
        ({"size": 100}, "size"),
        ({"max_shift": [2, 40]}, "max_shift"),
        ({"key": "linear"}, "key"),
        ({"bank_size": 0}, "bank_size"),
        ({"colour": True}, "colour"),
    ],
)
def test_malformed_settings_name_the_field(settings, field) -> None:
    with pytest.raises(AssociativeMemoryError, match=rf"memory settings: {field}"):
        ViewframeIndex({**MemorySpec().model_dump(), **settings})


def test_missing_settings_take_the_schema_defaults() -> None:
    assert memory_settings({"size": 64}) == MemorySpec(size=64)
    assert memory_settings(None) == MemorySpec()


def test_whiten_is_a_setting_that_changes_the_pattern() -> None:
    image = np.random.default_rng(4).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    on, off = ViewframeIndex(MemorySpec()).pattern(image), ViewframeIndex(MemorySpec(whiten=False)).pattern(image)
    np.testing.assert_allclose(on, preprocess(image), rtol=0, atol=1e-6)  # preprocess' defaults are the schema's
    assert np.abs(on - off).max() > 1e-3
