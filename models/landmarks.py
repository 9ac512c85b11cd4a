"""Landmarks: boxes standing on the terrain, and the environment model F* = T(F, L).

A landmark is a box: footprint centre (x, y), ``width`` along its local x axis, ``depth``
along its local y axis, rotated by ``yaw_deg`` counterclockwise from +x. Its base z0 is the
minimum of F at the footprint's four corners and centre; its top is z0 + height. World
coordinates (x, y, z), metres, x east, y north, z up.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from models.terrain import Terrain

__all__ = ["Landmark", "place_landmarks", "raised_dem"]


@dataclass(frozen=True)
class Landmark:
    """A placed box landmark (see the module docstring for the geometry)."""

    id: str
    kind: str
    x: float
    y: float
    width: float
    depth: float
    height: float
    yaw_deg: float
    z0: float

    @property
    def top(self) -> float:
        """Height of the roof, z0 + height (metres)."""
        return self.z0 + self.height

    @property
    def centre(self) -> np.ndarray:
        """Centre of the box, ndarray (3,) as (x, y, z)."""
        return np.array([self.x, self.y, self.z0 + self.height / 2])

    def corners(self) -> np.ndarray:
        """Footprint corners, ndarray of shape (4, 2) as (x, y), counterclockwise."""
        a = math.radians(self.yaw_deg)
        ux = np.array([math.cos(a), math.sin(a)]) * self.width / 2
        uy = np.array([-math.sin(a), math.cos(a)]) * self.depth / 2
        c = np.array([self.x, self.y])
        return np.stack([c - ux - uy, c + ux - uy, c + ux + uy, c - ux + uy])

    def box_vertices(self) -> np.ndarray:
        """The 8 box corners, ndarray of shape (8, 3): base (z0) first, then the top."""
        xy = self.corners()
        return np.concatenate([np.column_stack([xy, np.full(4, self.z0)]), np.column_stack([xy, np.full(4, self.top)])])


def place_landmarks(terrain: Terrain, specs: Iterable) -> list[Landmark]:
    """Stand each landmark spec (id, kind, x, y, width, depth, height, yaw_deg) on ``terrain``."""
    out = []
    for s in specs:
        probe = Landmark(s.id, s.kind, s.x, s.y, s.width, s.depth, s.height, s.yaw_deg, 0.0)
        pts = np.vstack([probe.corners(), [[s.x, s.y]]])
        z0 = float(np.min(terrain.height_at(pts[:, 0], pts[:, 1])))
        out.append(
            Landmark(
                s.id,
                s.kind,
                float(s.x),
                float(s.y),
                float(s.width),
                float(s.depth),
                float(s.height),
                float(s.yaw_deg),
                z0,
            )
        )
    return out


def raised_dem(terrain: Terrain, landmarks: Iterable[Landmark]) -> Terrain:
    """F*: the DEM with every cell whose centre lies inside a footprint raised to the box top."""
    h = terrain.heights.copy()
    rows, cols = h.shape
    cs = terrain.cell_size
    for lm in landmarks:
        xy = lm.corners()
        c0, r0 = np.maximum(np.floor(xy.min(0) / cs).astype(int), 0)
        c1, r1 = np.minimum(np.ceil(xy.max(0) / cs).astype(int), [cols - 1, rows - 1])
        if c1 < c0 or r1 < r0:
            continue
        rr, cc = np.mgrid[r0 : r1 + 1, c0 : c1 + 1]
        dx, dy = cc * cs - lm.x, rr * cs - lm.y  # DEM (row, col) centre = (y, x) / cell_size
        a = math.radians(lm.yaw_deg)
        u = dx * math.cos(a) + dy * math.sin(a)  # along the box's width
        v = -dx * math.sin(a) + dy * math.cos(a)  # along its depth
        inside = (np.abs(u) <= lm.width / 2 + 1e-9) & (np.abs(v) <= lm.depth / 2 + 1e-9)
        block = h[r0 : r1 + 1, c0 : c1 + 1]
        block[inside] = np.maximum(block[inside], lm.top)
    return Terrain(heights=h, cell_size=terrain.cell_size, frame=terrain.frame)
