"""The environment model F* = T(F, L): terrain plus landmark boxes, as meshes for rendering.

The terrain is cut into square tiles of ``tile_cells`` DEM cells; each tile carries a mesh per
level of detail (vertex stride 1, 2, 4, ... cells) with a vertical *skirt* along its border
that hides the cracks where neighbouring tiles use different strides. Per view the camera
emulator shows, for each tile, the level whose stride suits the tile's distance, and hides
tiles outside the view frustum (:meth:`EnvironmentModel.tile_levels`). On Mesa's software
rasteriser the cost follows the triangle count, so this keeps rendering fast on large DEMs.

Everything here is plain numpy: pyrender objects are made by :class:`models.camera.CameraEmulator`,
because GL buffers belong to one renderer's context.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from blackboard.errors import ScenarioError
from models.landmarks import Landmark, place_landmarks, raised_dem
from models.terrain import Terrain, load_terrain

__all__ = ["TileMesh", "TerrainTile", "EnvironmentModel", "build_environment", "terrain_colors", "KIND_COLORS"]

log = logging.getLogger(__name__)

#: RGB in [0, 1] of landmark boxes by kind (others: ``KIND_COLORS["default"]``)
KIND_COLORS: dict[str, tuple[float, float, float]] = {
    "house": (0.72, 0.36, 0.26),
    "tower": (0.62, 0.64, 0.68),
    "silo": (0.85, 0.85, 0.78),
    "barn": (0.55, 0.18, 0.14),
    "default": (0.80, 0.70, 0.30),
}


@dataclass(frozen=True, eq=False)
class TileMesh:
    """One level of detail of a tile: arrays ready for a GL vertex buffer.

    positions, normals: float32 (n, 3) world (x, y, z); colors: float32 (n, 4) RGBA in [0, 1];
    indices: uint32 (m, 3) triangles.
    """

    stride: int
    positions: np.ndarray
    normals: np.ndarray
    colors: np.ndarray
    indices: np.ndarray


@dataclass(frozen=True, eq=False)
class TerrainTile:
    """A square of DEM cells with its meshes, finest first; ``bounds`` = (x0, x1, y0, y1, z0, z1)."""

    row0: int
    col0: int
    bounds: tuple[float, float, float, float, float, float]
    levels: list[TileMesh] = field(default_factory=list)


def terrain_colors(terrain: Terrain) -> np.ndarray:
    """Ground colour per DEM cell, float32 (rows, cols, 3) RGB in [0, 1].

    Meadow green in the valleys turning olive and then brown-grey on steep slopes and high
    ground, with a faint deterministic mottling so flat ground is not uniform.
    """
    h = terrain.heights
    dzdy, dzdx = np.gradient(h, terrain.cell_size)
    slope = np.clip(np.hypot(dzdx, dzdy) / 0.6, 0.0, 1.0)[..., None]
    t = ((h - h.min()) / (np.ptp(h) or 1.0))[..., None]
    low = np.array([0.36, 0.52, 0.24])
    high = np.array([0.55, 0.56, 0.34])
    rock = np.array([0.52, 0.45, 0.38])
    col = low * (1 - t) + high * t
    col = col * (1 - slope) + rock * slope
    r, c = np.mgrid[0 : h.shape[0], 0 : h.shape[1]]
    mottle = 0.06 * np.sin(r * 1.7 + np.sin(c * 0.9)) * np.cos(c * 1.3 + np.sin(r * 0.7))
    return np.clip(col * (1 + mottle[..., None]), 0, 1).astype(np.float32)


def _grid_indices(nr: int, nc: int) -> np.ndarray:
    i, j = np.mgrid[0 : nr - 1, 0 : nc - 1]
    v00 = (i * nc + j).ravel()
    v01, v10, v11 = v00 + 1, v00 + nc, v00 + nc + 1
    return np.concatenate([np.stack([v00, v01, v11], 1), np.stack([v00, v11, v10], 1)]).astype(np.uint32)


def _level_indices(start: int, stop: int, stride: int) -> np.ndarray:
    """Vertex indices start..stop (inclusive) every ``stride``, always keeping ``stop``."""
    idx = np.arange(start, stop, stride)
    return np.append(idx, stop)


class EnvironmentModel:
    """Terrain F, placed landmarks L, F* and the level-of-detail terrain tiles.

    ``lod_factor``: a tile at horizontal distance d uses the coarsest stride s with
    ``s * cell_size <= d / lod_factor`` (bigger is finer and slower).
    """

    def __init__(
        self,
        terrain: Terrain,
        landmarks: list[Landmark],
        *,
        tile_cells: int = 64,
        levels: int = 5,
        lod_factor: float = 8.0,
    ) -> None:
        if tile_cells < 2 or tile_cells & (tile_cells - 1):
            raise ValueError(f"tile_cells must be a power of two >= 2, got {tile_cells}")
        if levels < 1 or 2 ** (levels - 1) > tile_cells:
            raise ValueError(f"levels must be in 1..{int(math.log2(tile_cells)) + 1}, got {levels}")
        if not lod_factor > 0:
            raise ValueError(f"lod_factor must be > 0, got {lod_factor}")
        self.terrain = terrain
        self.landmarks = list(landmarks)
        self.tile_cells = tile_cells
        self.n_levels = levels
        self.lod_factor = float(lod_factor)
        self.tiles = self._build_tiles()
        self._bounds = np.array([t.bounds for t in self.tiles], dtype=np.float64).reshape(-1, 6)

    @cached_property
    def raised(self) -> Terrain:
        """F* = T(F, L): the DEM raised to each box top inside its footprint."""
        return raised_dem(self.terrain, self.landmarks)

    def landmark_index(self, landmark_id: str) -> int:
        """Index of a landmark (as used in rendered masks) by its id."""
        for i, lm in enumerate(self.landmarks):
            if lm.id == landmark_id:
                return i
        raise KeyError(landmark_id)

    @property
    def full_triangles(self) -> int:
        """Triangles of the terrain at full resolution (without skirts)."""
        rows, cols = self.terrain.shape
        return 2 * (rows - 1) * (cols - 1)

    def _skirt_depth(self) -> float:
        """Deeper than the worst height error of the coarsest level, so cracks stay covered."""
        h = self.terrain.heights
        rows, cols = h.shape
        s = 2 ** (self.n_levels - 1)
        ri, ci = _level_indices(0, rows - 1, s), _level_indices(0, cols - 1, s)
        interp = RegularGridInterpolator((ri, ci), h[np.ix_(ri, ci)])
        rr, cc = np.mgrid[0:rows, 0:cols]
        err = np.abs(interp(np.stack([rr.ravel(), cc.ravel()], 1)).reshape(h.shape) - h).max()
        return float(err) + 1.0

    def _build_tiles(self) -> list[TerrainTile]:
        t = self.terrain
        h = t.heights
        rows, cols = h.shape
        cs = t.cell_size
        dzdy, dzdx = np.gradient(h, cs)
        normals = np.stack([-dzdx, -dzdy, np.ones_like(h)], -1)
        normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
        colors = terrain_colors(t)
        skirt = self._skirt_depth()
        n = self.tile_cells
        tiles = []
        for r0 in range(0, rows - 1, n):
            for c0 in range(0, cols - 1, n):
                r1, c1 = min(r0 + n, rows - 1), min(c0 + n, cols - 1)
                block = h[r0 : r1 + 1, c0 : c1 + 1]
                bounds = (c0 * cs, c1 * cs, r0 * cs, r1 * cs, float(block.min()) - skirt, float(block.max()))
                tile = TerrainTile(r0, c0, bounds)
                for level in range(self.n_levels):
                    s = 2**level
                    ri, ci = _level_indices(r0, r1, s), _level_indices(c0, c1, s)
                    nr, nc = len(ri), len(ci)
                    R, C = np.meshgrid(ri, ci, indexing="ij")
                    pos = np.stack([C * cs, R * cs, h[R, C]], -1).reshape(-1, 3)
                    nor = normals[R, C].reshape(-1, 3)
                    col = colors[R, C].reshape(-1, 3)
                    tri = _grid_indices(nr, nc)
                    # skirt: the border ring, copied down by ``skirt`` metres
                    grid = np.arange(nr * nc).reshape(nr, nc)
                    ring = np.concatenate([grid[0, :], grid[1:, -1], grid[-1, -2::-1], grid[-2:0:-1, 0]])
                    low = np.arange(len(ring)) + nr * nc
                    a, b = ring, np.roll(ring, -1)
                    la, lb = low, np.roll(low, -1)
                    skirt_tri = np.concatenate([np.stack([a, b, lb], 1), np.stack([a, lb, la], 1)]).astype(np.uint32)
                    lowered = pos[ring].copy()
                    lowered[:, 2] -= skirt
                    tile.levels.append(
                        TileMesh(
                            stride=s,
                            positions=np.concatenate([pos, lowered]).astype(np.float32),
                            normals=np.concatenate([nor, nor[ring]]).astype(np.float32),
                            colors=np.concatenate(
                                [np.column_stack([col, np.ones(len(col))]),
                                 np.column_stack([col[ring] * 0.8, np.ones(len(ring))])]
                            ).astype(np.float32),
                            indices=np.concatenate([tri, skirt_tri]),
                        )
                    )
                tiles.append(tile)
        log.info("terrain: %d tiles x %d levels, skirt %.1f m", len(tiles), self.n_levels, skirt)
        return tiles

    def tile_levels(
        self,
        eye: np.ndarray,
        rotation: np.ndarray,
        *,
        tan_half_fov: tuple[float, float],
        far: float,
    ) -> np.ndarray:
        """Level of detail per tile for one view, int array (n_tiles,), -1 = outside the frustum.

        ``eye``: camera position (3,) world (x, y, z); ``rotation``: (3, 3) rows = the camera's
        right, up and forward axes in world coordinates; ``tan_half_fov``: (x, y) tangents of
        the half field of view. A tile is culled when all 8 corners of its bounding box lie
        outside one frustum plane; the level follows the horizontal distance to the tile.
        """
        b = self._bounds
        xs = b[:, [0, 1]]
        ys = b[:, [2, 3]]
        zs = b[:, [4, 5]]
        corners = np.stack(
            [np.stack([xs[:, i], ys[:, j], zs[:, k]], -1) for i in (0, 1) for j in (0, 1) for k in (0, 1)], 1
        )  # (n, 8, 3)
        cam = (corners - eye) @ rotation.T  # (n, 8, 3) camera (right, up, forward)
        tx, ty = tan_half_fov[0] * 1.05, tan_half_fov[1] * 1.05
        xc, yc, zc = cam[..., 0], cam[..., 1], cam[..., 2]
        outside = (
            np.all(zc < 0, 1)
            | np.all(xc > zc * tx, 1)
            | np.all(-xc > zc * tx, 1)
            | np.all(yc > zc * ty, 1)
            | np.all(-yc > zc * ty, 1)
        )
        dx = np.maximum(np.maximum(b[:, 0] - eye[0], eye[0] - b[:, 1]), 0)
        dy = np.maximum(np.maximum(b[:, 2] - eye[1], eye[1] - b[:, 3]), 0)
        d = np.hypot(dx, dy)
        ratio = d / (self.lod_factor * self.terrain.cell_size)
        level = np.floor(np.log2(np.maximum(ratio, 1.0))).astype(int)
        level = np.clip(level, 0, self.n_levels - 1)
        level[outside | (d > far)] = -1
        return level


def build_environment(scenario, *, terrain: Terrain | None = None, **lod) -> EnvironmentModel:
    """Load a scenario's terrain, place its landmarks and build the environment model.

    Raises :class:`ScenarioError` when a route point or a landmark lies outside the terrain.
    ``lod`` passes ``tile_cells``, ``levels`` and ``lod_factor`` to :class:`EnvironmentModel`.
    """
    if terrain is None:
        terrain = load_terrain(scenario.terrain, base_dir=scenario.base_dir, seed=scenario.seed)
    x0, x1, y0, y1 = terrain.extent
    where = f"outside the terrain (x {x0:g}..{x1:g}, y {y0:g}..{y1:g} m)"
    for i, (x, y) in enumerate(scenario.route):
        if not terrain.contains(x, y):
            raise ScenarioError(scenario.path, f"route[{i}]", f"({x:g}, {y:g}) is {where}")
    landmarks = place_landmarks(terrain, scenario.landmarks)
    for i, lm in enumerate(landmarks):
        if not all(terrain.contains(px, py) for px, py in lm.corners()):
            raise ScenarioError(scenario.path, f"landmarks[{i}]", f"footprint of {lm.id!r} is {where}")
    return EnvironmentModel(terrain, landmarks, **lod)
