"""Symbolic descriptions: visibility, occlusion by terrain and by boxes, relations, priors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from models.camera_emulator import CameraEmulator, Pose
from models.environment import EnvironmentModel
from models.landmarks import place_landmarks
from models.scenario import CameraSpec, LandmarkSpec
from models.symbolic import RELATIONS, SymbolicDescription, box_silhouette, describe, landmark_priors
from models.terrain import Terrain

CAMERA = CameraSpec(width=160, height=120, fov_y_deg=45.0, eye_height=2.0, near=1.0, far=3000.0)
EYE = Pose(100.0, 500.0, 2.0, 0.0)  # looking east


def _lm(id, x, y, w, d, h, kind="house"):
    return LandmarkSpec(id=id, kind=kind, x=x, y=y, width=w, depth=d, height=h)


@pytest.fixture(scope="module")
def world():
    """Flat ground except a 30 m ridge at x = 400..420; boxes in the open and behind the ridge."""
    h = np.zeros((101, 101))
    h[:, 40:43] = 30.0
    terrain = Terrain(heights=h, cell_size=10.0)
    specs = [
        _lm("A", 200, 500, 10, 20, 10),  # in the open, 100 m ahead
        _lm("B", 150, 505, 4, 10, 20, "tower"),  # in front of A's left (north) half
        _lm("C", 600, 500, 20, 20, 10),  # behind the ridge: hidden
        _lm("D", 140, 515, 6, 6, 1),  # low and near, to the left
        _lm("E", 450, 470, 10, 10, 6),  # far, right, also behind the ridge
    ]
    env = EnvironmentModel(terrain, place_landmarks(terrain, specs))
    with CameraEmulator(env, CAMERA) as cam:
        view = cam.render(EYE)
        yield cam, view, describe(view.mask, view.depth, env.landmarks, pose=EYE, emulator=cam)


def test_visible_and_hidden_landmarks(world):
    _, view, desc = world
    assert set(desc.visible) == {"A", "B", "D"}
    assert desc.visible[0] == "D"  # nearest first
    # the hidden ones project inside the image: they are hidden, not out of view
    cam = world[0]
    for lid in ("C", "E"):
        lm = cam.environment.landmarks[cam.environment.landmark_index(lid)]
        assert box_silhouette(lm, EYE, cam).sum() > 10


def test_occlusion_fraction(world):
    _, view, desc = world
    a, b = desc.graph.nodes["A"], desc.graph.nodes["B"]
    assert 0.3 < a["fraction"] < 0.75  # B hides about half of A
    assert b["fraction"] > 0.9
    assert a["pixels"] == int((view.mask == 0).sum())
    rows, cols = np.nonzero(view.mask == 1)
    assert b["bbox"] == (rows.min(), cols.min(), rows.max(), cols.max())
    assert b["centroid"] == pytest.approx((rows.mean(), cols.mean()))
    assert a["range_m"] == pytest.approx(np.linalg.norm([100, 0, 3]))


def test_relations(world):
    _, _, desc = world
    assert desc.has("B", "in_front_of", "A") and desc.has("A", "behind", "B")
    assert desc.has("B", "left_of", "A") and desc.has("A", "right_of", "B")
    assert desc.has("B", "near", "A") and desc.has("A", "near", "B")
    assert desc.has("A", "above", "D")  # distant A sits higher in the image than the low near D
    assert not desc.has("D", "above", "A")
    assert not desc.has("D", "near", "A")  # 62 m apart
    assert desc.has("D", "near", "B") and desc.has("D", "left_of", "B")
    for _, _, rels in desc.to_dict()["edges"]:
        assert set(rels) <= set(RELATIONS)


def test_min_pixels_threshold(world):
    cam, view, desc = world
    small = min(desc.visible, key=lambda n: desc.graph.nodes[n]["pixels"])
    n = desc.graph.nodes[small]["pixels"]
    stricter = describe(view.mask, view.depth, cam.environment.landmarks, pose=EYE, min_pixels=n + 1)
    assert small not in stricter.visible
    assert stricter.visible and all(stricter.graph.nodes[v]["fraction"] is None for v in stricter.visible)  # no camera


def test_round_trip_through_json(world):
    _, _, desc = world
    data = json.loads(json.dumps(desc.to_dict()))
    back = SymbolicDescription.from_dict(data)
    assert back == desc
    assert back.visible == desc.visible
    assert back.graph.nodes["A"]["bbox"] == desc.graph.nodes["A"]["bbox"]


@pytest.mark.parametrize(
    "data",
    [
        {"nodes": {}},
        {"nodes": {"A": {"kind": "house"}}, "edges": []},
        {"nodes": {}, "edges": [["A", "B", ["near"]]]},
    ],
)
def test_from_dict_rejects_malformed(data):
    with pytest.raises(ValueError):
        SymbolicDescription.from_dict(data)


def test_describe_validates_its_input(world):
    cam, view, _ = world
    with pytest.raises(ValueError, match="depth shape"):
        describe(view.mask, view.depth[:10], cam.environment.landmarks, pose=EYE)
    with pytest.raises(ValueError, match="only 2 landmarks"):
        describe(view.mask, view.depth, cam.environment.landmarks[:2], pose=EYE)


def test_landmark_priors_count_occurrences():
    def d(*ids):
        return SymbolicDescription.from_dict(
            {
                "nodes": {
                    i: {
                        "kind": "house",
                        "pixels": 9,
                        "fraction": 1.0,
                        "bbox": [0, 0, 2, 2],
                        "centroid": [1, 1],
                        "range_m": 10.0,
                    }
                    for i in ids
                },
                "edges": [],
            }
        )

    descs = [d("A"), d("A", "B"), d(), d("B", "C")]
    assert landmark_priors(descs) == {"A": 0.5, "B": 0.5, "C": 0.25}
    assert landmark_priors(descs, landmark_ids=["A", "B", "C", "Z"])["Z"] == 0.0
    with pytest.raises(ValueError, match="empty"):
        landmark_priors([])
