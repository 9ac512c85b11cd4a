"""Synthetic viewframe-like images for tests and benchmarks of the image-side models.

Images are ``(H, W)`` uint8 arrays indexed ``(row, col)``.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["scene"]


def scene(rng: np.random.Generator, shape: tuple[int, int] = (120, 160)) -> np.ndarray:
    """An edge-rich gray image of ``shape``: random rectangles, lines and discs on a flat ground."""
    h, w = shape
    img = np.full(shape, rng.uniform(60, 190), np.float32)
    for _ in range(int(rng.integers(6, 12))):
        c = float(rng.uniform(0, 255))
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        kind = int(rng.integers(3))
        if kind == 0:
            cv2.rectangle(img, (x, y), (x + int(rng.integers(8, 60)), y + int(rng.integers(8, 50))), c, -1)
        elif kind == 1:
            cv2.line(img, (x, y), (int(rng.integers(0, w)), int(rng.integers(0, h))), c, int(rng.integers(1, 4)))
        else:
            cv2.circle(img, (x, y), int(rng.integers(4, 25)), c, -1)
    return img.astype(np.uint8)
