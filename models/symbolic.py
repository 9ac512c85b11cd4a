"""Symbolic descriptions S2D of viewframes: visible landmarks and their relations.

A :class:`SymbolicDescription` wraps a ``networkx.DiGraph``. Nodes are the ids of the visible
landmarks (at least ``min_pixels`` pixels in the rendered mask) with attributes

- ``kind``: the landmark kind (``"house"``, ``"tower"``, ...);
- ``pixels``: visible pixel count;
- ``fraction``: visible pixels over the pixels the box would cover without occlusion
  (None when no camera was given to project it). The unoccluded area is the box's
  silhouette: the convex hull of its 8 corners (clipped at the near plane) projected and
  filled with ``cv2.fillConvexPoly`` - exact for a box, with no second render;
- ``bbox``: (row0, col0, row1, col1) of the visible pixels, inclusive;
- ``centroid``: (row, col) of the visible pixels;
- ``range_m``: distance from the camera to the box centre, metres.

Each ordered pair of visible landmarks (a, b) gets an edge when some relation holds; its
``relations`` attribute is the sorted list of those that do, read as "a REL b":

- ``left_of`` / ``right_of``: a's centroid column is left/right of b's by more than 2 px;
- ``in_front_of`` / ``behind``: their column spans overlap or touch (an occluder ends where
  the occluded part begins) and a is nearer/farther by more
  than 5 % of the range;
- ``above``: a's lowest visible row is above b's highest visible row;
- ``near``: their footprint centres are less than ``near_m`` (default 60 m) apart.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import cv2
import networkx as nx
import numpy as np

from models.landmarks import Landmark

if TYPE_CHECKING:
    from models.camera_emulator import CameraEmulator, Pose

__all__ = ["RELATIONS", "SymbolicDescription", "describe", "landmark_priors", "box_silhouette"]

#: every relation name an edge may carry
RELATIONS: tuple[str, ...] = ("left_of", "right_of", "in_front_of", "behind", "above", "near")

# box edges as index pairs into Landmark.box_vertices()
_BOX_EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]


class SymbolicDescription:
    """The landmarks seen in one viewframe and their relations (see the module docstring)."""

    def __init__(self, graph: nx.DiGraph | None = None) -> None:
        self.graph = graph if graph is not None else nx.DiGraph()

    @property
    def visible(self) -> list[str]:
        """Ids of the visible landmarks, nearest first."""
        return sorted(self.graph.nodes, key=lambda n: (self.graph.nodes[n]["range_m"], n))

    def relations(self, a: str, b: str) -> list[str]:
        """Relations "a REL b" (empty when none or either is not visible)."""
        if not self.graph.has_edge(a, b):
            return []
        return list(self.graph.edges[a, b]["relations"])

    def has(self, a: str, relation: str, b: str) -> bool:
        """True when "a relation b" holds, e.g. ``desc.has("H1", "left_of", "T1")``."""
        return relation in self.relations(a, b)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (lists, dicts, str, int, float, None) for JSON or msgpack."""
        nodes = {}
        for n in self.visible:
            a = self.graph.nodes[n]
            nodes[n] = {
                "kind": a["kind"],
                "pixels": int(a["pixels"]),
                "fraction": None if a["fraction"] is None else float(a["fraction"]),
                "bbox": [int(v) for v in a["bbox"]],
                "centroid": [float(v) for v in a["centroid"]],
                "range_m": float(a["range_m"]),
            }
        edges = [[a, b, list(d["relations"])] for a, b, d in sorted(self.graph.edges(data=True))]
        return {"visible": self.visible, "nodes": nodes, "edges": edges}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SymbolicDescription:
        """Inverse of :meth:`to_dict`; raises ValueError on malformed data."""
        try:
            g = nx.DiGraph()
            for n, a in data["nodes"].items():
                g.add_node(
                    str(n),
                    kind=str(a["kind"]),
                    pixels=int(a["pixels"]),
                    fraction=None if a["fraction"] is None else float(a["fraction"]),
                    bbox=tuple(int(v) for v in a["bbox"]),
                    centroid=tuple(float(v) for v in a["centroid"]),
                    range_m=float(a["range_m"]),
                )
            for a, b, rels in data["edges"]:
                if a not in g or b not in g:
                    raise ValueError(f"edge {a!r} -> {b!r} names a landmark that is not a node")
                bad = set(rels) - set(RELATIONS)
                if bad:
                    raise ValueError(f"unknown relations {sorted(bad)}")
                g.add_edge(str(a), str(b), relations=sorted(rels))
        except (KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"malformed symbolic description: {exc!r}") from None
        return cls(g)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SymbolicDescription) and self.to_dict() == other.to_dict()

    def __repr__(self) -> str:
        return f"SymbolicDescription(visible={self.visible}, edges={self.graph.number_of_edges()})"


def box_silhouette(landmark: Landmark, pose: Pose, emulator: CameraEmulator) -> np.ndarray:
    """Pixels the box would cover with nothing in front: bool ndarray of shape (H, W).

    The box is clipped at the near plane, its corners projected, and their convex hull filled.
    """
    v = emulator.camera_frame(landmark.box_vertices(), pose)  # (8, 3) right, up, forward
    near = emulator.camera.near
    pts = [v[i] for i in range(8) if v[i, 2] >= near]
    for i, j in _BOX_EDGES:
        a, b = v[i], v[j]
        if (a[2] - near) * (b[2] - near) < 0:
            t = (near - a[2]) / (b[2] - a[2])
            pts.append(a + t * (b - a))
    out = np.zeros((emulator.height, emulator.width), np.uint8)
    if len(pts) < 3:
        return out.astype(bool)
    p = np.array(pts)
    fx, fy, cx, cy = emulator.intrinsics
    col = cx + fx * p[:, 0] / p[:, 2]
    row = cy - fy * p[:, 1] / p[:, 2]
    xy = np.clip(np.stack([col, row], 1), -1e6, 1e6)  # cv2 points are (x=col, y=row)
    hull = cv2.convexHull(np.round(xy * 16).astype(np.int32))
    cv2.fillConvexPoly(out, hull, 1, lineType=cv2.LINE_8, shift=4)
    return out.astype(bool)


def describe(
    mask: np.ndarray,
    depth: np.ndarray,
    landmarks: Sequence[Landmark],
    *,
    pose: Pose,
    emulator: CameraEmulator | None = None,
    min_pixels: int = 4,
    near_m: float = 60.0,
) -> SymbolicDescription:
    """Symbolic description of one rendered view.

    ``mask``: int ndarray (H, W), -1 or an index into ``landmarks``; ``depth``: float ndarray
    (H, W) metres (0 = sky; used to check the shapes agree and kept for future relations);
    ``pose``: the camera pose; ``emulator`` (optional) projects unoccluded silhouettes for
    ``fraction``. A landmark is visible with at least ``min_pixels`` pixels.
    """
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask must be 2-D (H, W), got shape {mask.shape}")
    if np.shape(depth) != mask.shape:
        raise ValueError(f"depth shape {np.shape(depth)} must equal mask shape {mask.shape}")
    if min_pixels < 1:
        raise ValueError(f"min_pixels must be >= 1, got {min_pixels}")
    counts = np.bincount(mask[mask >= 0].ravel(), minlength=len(landmarks))
    if len(counts) > len(landmarks):
        raise ValueError(f"mask holds landmark index {len(counts) - 1} but only {len(landmarks)} landmarks given")
    g = nx.DiGraph()
    eye = np.array([pose.x, pose.y, pose.z])
    for i in np.nonzero(counts >= min_pixels)[0].tolist():
        lm = landmarks[i]
        rows, cols = np.nonzero(mask == i)
        fraction = None
        if emulator is not None:
            full = int(box_silhouette(lm, pose, emulator).sum())
            fraction = min(1.0, counts[i] / full) if full > 0 else 1.0
        g.add_node(
            lm.id,
            kind=lm.kind,
            pixels=int(counts[i]),
            fraction=fraction,
            bbox=(int(rows.min()), int(cols.min()), int(rows.max()), int(cols.max())),
            centroid=(float(rows.mean()), float(cols.mean())),
            range_m=float(np.linalg.norm(lm.centre - eye)),
            _xy=(lm.x, lm.y),
        )
    for a in g.nodes:
        for b in g.nodes:
            if a == b:
                continue
            na, nb = g.nodes[a], g.nodes[b]
            rels = []
            if na["centroid"][1] + 2 < nb["centroid"][1]:
                rels.append("left_of")
            if na["centroid"][1] > nb["centroid"][1] + 2:
                rels.append("right_of")
            overlap = na["bbox"][1] <= nb["bbox"][3] + 1 and nb["bbox"][1] <= na["bbox"][3] + 1
            margin = 0.05 * max(na["range_m"], nb["range_m"])
            if overlap and na["range_m"] + margin < nb["range_m"]:
                rels.append("in_front_of")
            if overlap and na["range_m"] > nb["range_m"] + margin:
                rels.append("behind")
            if na["bbox"][2] < nb["bbox"][0]:
                rels.append("above")
            if math.dist(na["_xy"], nb["_xy"]) < near_m:
                rels.append("near")
            if rels:
                g.add_edge(a, b, relations=sorted(rels))
    for n in g.nodes:
        del g.nodes[n]["_xy"]
    return SymbolicDescription(g)


def landmark_priors(
    descriptions: Sequence[SymbolicDescription], *, landmark_ids: Sequence[str] | None = None
) -> dict[str, float]:
    """A-priori landmark probabilities P(L) = (viewframes where L is visible) / (viewframes).

    ``landmark_ids`` lists every landmark (never-seen ones get 0.0); by default the ids seen.
    """
    if len(descriptions) == 0:
        raise ValueError("descriptions must not be empty")
    counts: dict[str, int] = {i: 0 for i in (landmark_ids or [])}
    for d in descriptions:
        for lid in d.visible:
            counts[lid] = counts.get(lid, 0) + 1
    return {lid: c / len(descriptions) for lid, c in counts.items()}
