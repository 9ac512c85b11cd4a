"""Preprocessing: shape, normalisation, invariance to brightness, validation."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from models.preprocess import EDGE_METHODS, normalise, preprocess


def _scene(seed: int, shape: tuple[int, int] = (120, 160)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.full(shape, 100, np.uint8)
    for _ in range(8):
        x, y = int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0]))
        cv2.rectangle(
            img, (x, y), (x + int(rng.integers(8, 50)), y + int(rng.integers(8, 40))), int(rng.integers(0, 256)), -1
        )
    return img


@pytest.mark.parametrize("edge", EDGE_METHODS)
@pytest.mark.parametrize("whiten", [True, False])
@pytest.mark.parametrize("size", [32, 64])
def test_output_is_zero_mean_unit_energy(edge: str, whiten: bool, size: int) -> None:
    p = preprocess(_scene(1), size=size, edge=edge, whiten=whiten)
    assert p.shape == (size, size) and p.dtype == np.float32
    assert abs(float(p.mean())) < 1e-6
    assert float(np.sum(p.astype(np.float64) ** 2)) == pytest.approx(1.0, rel=1e-5)


@pytest.mark.parametrize("edge", ["sobel", "scharr", "laplacian", "canny"])
def test_brightness_gain_and_offset_do_not_matter(edge: str) -> None:
    img = _scene(2).astype(np.float32)
    p = preprocess(img, edge=edge)
    q = preprocess(img * 0.6 + 40.0, edge=edge)
    assert float(np.sum(p * q)) > 0.999


def test_rgb_and_gray_agree() -> None:
    gray = _scene(3)
    rgb = np.repeat(gray[:, :, None], 3, axis=2)
    assert np.allclose(preprocess(gray), preprocess(rgb), atol=1e-5)


def test_featureless_image_gives_zeros() -> None:
    assert not preprocess(np.full((50, 70), 128, np.uint8)).any()
    assert not normalise(np.ones((4, 4))).any()


def test_different_scenes_are_far_apart() -> None:
    a, b = preprocess(_scene(4)), preprocess(_scene(5))
    assert abs(float(np.sum(a * b))) < 0.3


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"size": 4}, "size"),
        ({"size": 12.5}, "size"),
        ({"edge": "prewitt"}, "edge"),
        ({"blur_sigma": -1.0}, "blur_sigma"),
        ({"blur_sigma": float("nan")}, "blur_sigma"),
    ],
)
def test_bad_arguments_name_the_parameter(kwargs: dict, name: str) -> None:
    with pytest.raises(ValueError, match=name):
        preprocess(_scene(6), **kwargs)


@pytest.mark.parametrize("image", [np.zeros(5), np.zeros((4, 4, 2)), np.array([["a", "b"], ["c", "d"]])])
def test_bad_images_are_rejected(image: np.ndarray) -> None:
    with pytest.raises(ValueError, match="image"):
        preprocess(image)
