"""Fixtures shared by the model tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from models.camera_emulator import CameraEmulator
from models.environment import build_environment
from models.scenario import scenario_from_dict


@pytest.fixture(scope="module")
def emulator() -> Iterator[CameraEmulator]:
    """A camera emulator of a procedural hill terrain (128 x 128 cells of 10 m, seed 4) with one
    house, 160 x 120, 45 degrees (the pose refinement's and the verification's tests; a test
    module may define its own ``emulator``)."""
    s = scenario_from_dict(
        {
            "name": "hill",
            "terrain": {"cell_size": 10.0, "procedural": {"size": 128, "relief": 120.0, "seed": 4}},
            "landmarks": [{"id": "H1", "kind": "house", "x": 470, "y": 420, "width": 18, "depth": 12, "height": 8}],
            "route": [[300, 300], [400, 400]],
            "camera": {"width": 160, "height": 120, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 5000.0},
        }
    )
    with CameraEmulator(build_environment(s), s.camera) as cam:
        yield cam
