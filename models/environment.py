"""The environment model F* = T(F, L): terrain plus landmark boxes, as meshes for rendering.

The terrain is cut into square tiles of ``tile_cells`` DEM cells; each tile has a mesh per
level of detail (vertex stride 1, 2, 4, ... cells), built on first use, with a vertical
*skirt* along its border that hides the cracks where neighbouring tiles use different strides.
Per view the camera emulator shows, for each tile, the level whose stride suits the tile's
distance, and hides tiles outside the view frustum (:meth:`EnvironmentModel.tile_levels`).
On Mesa's software rasteriser the cost follows the triangle count (and, through pyrender's
Python overhead, the number of draw calls; BENCHMARKS.md has the measurements), so big tiles with
coarse distant levels keep rendering fast on large DEMs.

The drawn ground approximates the bilinear F: it matches F at the DEM posts and lies at most
|twist| / 4 below it inside a cell (never above, so the camera is never under the ground).
Landmark boxes are drawn reaching ``ground_margin`` metres below their base z0 so that they do
not float where the drawn ground dips under F.

Everything here is plain numpy: pyrender objects are made by :class:`models.camera_emulator.CameraEmulator`,
because GL buffers belong to one renderer's context.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from models.errors import ScenarioError
from models.landmarks import Landmark, place_landmarks, raised_dem
from models.terrain import Terrain
from models.terrain_sources import scenario_terrain

__all__ = [
    "TileMesh",
    "TerrainTile",
    "EnvironmentModel",
    "build_environment",
    "outside_frustum",
    "check_extents",
    "terrain_colors",
    "KIND_COLORS",
]

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

    stride: float  # vertex spacing in DEM cells
    positions: np.ndarray
    normals: np.ndarray
    colors: np.ndarray
    indices: np.ndarray


@dataclass(frozen=True, eq=False)
class TerrainTile:
    """A square of DEM cells, rows row0..row1 and cols col0..col1 (vertex indices, inclusive);
    ``bounds`` = (x0, x1, y0, y1, z0, z1) in metres, z0 including the skirt."""

    row0: int
    col0: int
    row1: int
    col1: int
    bounds: tuple[float, float, float, float, float, float]


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


def _grid_indices(z: np.ndarray) -> np.ndarray:
    """Two triangles per quad of a vertex grid with heights ``z`` (nr, nc), uint32 (m, 3).

    Each quad is split along the diagonal that keeps both triangles at or *below* the
    bilinear surface through its corners: the bilinear patch is the plane through three
    corners plus ``d * u * v`` with twist ``d = z00 - z01 - z10 + z11``; splitting along
    00-11 lies above it when d > 0, along 01-10 below it. So the camera, which stands
    ``eye_height`` above the bilinear F, never ends up under the drawn ground.
    """
    nr, nc = z.shape
    i, j = np.mgrid[0 : nr - 1, 0 : nc - 1]
    v00 = (i * nc + j).ravel()
    v01, v10, v11 = v00 + 1, v00 + nc, v00 + nc + 1
    twist = (z[:-1, :-1] - z[:-1, 1:] - z[1:, :-1] + z[1:, 1:]).ravel()
    pos = twist > 0  # split along 01-10
    t1 = np.where(pos[:, None], np.stack([v00, v01, v10], 1), np.stack([v00, v01, v11], 1))
    t2 = np.where(pos[:, None], np.stack([v01, v11, v10], 1), np.stack([v00, v11, v10], 1))
    return np.concatenate([t1, t2]).astype(np.uint32)


def _level_positions(start: int, stop: int, spacing: float) -> np.ndarray:
    """Grid positions start..stop (inclusive, in cells) every ``spacing`` cells, keeping ``stop``."""
    n = max(1, int(math.ceil((stop - start) / spacing - 1e-9)))
    pos = start + np.arange(n) * spacing
    return np.append(pos, float(stop))


def _bilinear(field: np.ndarray, rr: np.ndarray, cc: np.ndarray) -> np.ndarray:
    """Sample ``field`` (rows, cols, ...) at fractional (row, col) grids ``rr``, ``cc``."""
    rows, cols = field.shape[:2]
    r0 = np.minimum(np.floor(rr).astype(np.intp), rows - 2)
    c0 = np.minimum(np.floor(cc).astype(np.intp), cols - 2)
    fr, fc = rr - r0, cc - c0
    if field.ndim == 3:
        fr, fc = fr[..., None], fc[..., None]
    return (
        field[r0, c0] * (1 - fr) * (1 - fc)
        + field[r0, c0 + 1] * (1 - fr) * fc
        + field[r0 + 1, c0] * fr * (1 - fc)
        + field[r0 + 1, c0 + 1] * fr * fc
    )


class EnvironmentModel:
    """Terrain F, placed landmarks L, F* and the level-of-detail terrain tiles.

    Level ``l`` of a tile has its vertices every ``2**l / refine`` cells (``refine`` > 1
    subdivides the finest level with bilinear heights, to follow F more closely near the camera;
    the default 1 uses the DEM posts, triangulated to stay below F, see ``_grid_indices``).
    A tile at horizontal distance d uses the coarsest level whose vertex spacing is at most
    ``d / lod_factor`` (bigger ``lod_factor`` is finer and slower). Tile meshes are built on
    first use and cached.
    """

    def __init__(
        self,
        terrain: Terrain,
        landmarks: list[Landmark],
        *,
        tile_cells: int = 64,
        levels: int | None = None,
        lod_factor: float = 8.0,
        refine: int = 1,
    ) -> None:
        if tile_cells < 2 or tile_cells & (tile_cells - 1):
            raise ValueError(f"tile_cells must be a power of two >= 2, got {tile_cells}")
        if not lod_factor > 0:
            raise ValueError(f"lod_factor must be > 0, got {lod_factor}")
        self.refine = int(refine)
        if self.refine not in (1, 2, 4, 8):
            raise ValueError(f"refine must be 1, 2, 4 or 8, got {refine}")
        max_levels = int(math.log2(tile_cells * self.refine)) + 1
        self.n_levels = max_levels if levels is None else int(levels)
        if not 1 <= self.n_levels <= max_levels:
            raise ValueError(f"levels must be in 1..{max_levels}, got {levels}")
        self.terrain = terrain
        self.landmarks = list(landmarks)
        self.tile_cells = tile_cells
        self.lod_factor = float(lod_factor)
        h = terrain.heights
        dzdy, dzdx = np.gradient(h, terrain.cell_size)
        normals = np.stack([-dzdx, -dzdy, np.ones_like(h)], -1)
        self._normals = normals / np.linalg.norm(normals, axis=-1, keepdims=True)
        self._colors = terrain_colors(terrain)
        self.skirt_m = self._skirt_depth()
        self.tiles = self._build_tiles()
        self._bounds = np.array([t.bounds for t in self.tiles], dtype=np.float64).reshape(-1, 6)
        self._cache: dict[tuple[int, int], TileMesh] = {}

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
        """Triangles of the terrain at full DEM resolution (without skirts)."""
        rows, cols = self.terrain.shape
        return 2 * (rows - 1) * (cols - 1)

    def ground_margin(self, landmark: Landmark) -> float:
        """How far below z0 a box must reach to meet the drawn ground (metres, >= 0.5)."""
        h = self.terrain.heights
        xy = landmark.corners() / self.terrain.cell_size
        c0, r0 = np.floor(xy.min(0)).astype(int) - 1
        c1, r1 = np.ceil(xy.max(0)).astype(int) + 1
        rows, cols = h.shape
        block = h[max(r0, 0) : min(r1, rows - 1) + 1, max(c0, 0) : min(c1, cols - 1) + 1]
        if min(block.shape) < 2:
            return 0.5
        twist = np.abs(block[:-1, :-1] - block[:-1, 1:] - block[1:, :-1] + block[1:, 1:])
        return float(twist.max()) / 4 + 0.5

    def spacing(self, level: int) -> float:
        """Vertex spacing of ``level`` in DEM cells."""
        return 2.0**level / self.refine

    def _skirt_depth(self) -> float:
        """Deeper than the worst height error of the coarsest level, so cracks stay covered."""
        h = self.terrain.heights
        rows, cols = h.shape
        s = max(1.0, self.spacing(self.n_levels - 1))
        ri, ci = _level_positions(0, rows - 1, s), _level_positions(0, cols - 1, s)
        interp = RegularGridInterpolator((ri, ci), _bilinear(h, *np.meshgrid(ri, ci, indexing="ij")))
        rr, cc = np.mgrid[0:rows, 0:cols]
        err = np.abs(interp(np.stack([rr.ravel(), cc.ravel()], 1)).reshape(h.shape) - h).max()
        return float(err) + 1.0

    def _build_tiles(self) -> list[TerrainTile]:
        h = self.terrain.heights
        rows, cols = h.shape
        cs = self.terrain.cell_size
        n = self.tile_cells
        tiles = []
        for r0 in range(0, rows - 1, n):
            for c0 in range(0, cols - 1, n):
                r1, c1 = min(r0 + n, rows - 1), min(c0 + n, cols - 1)
                block = h[r0 : r1 + 1, c0 : c1 + 1]
                bounds = (c0 * cs, c1 * cs, r0 * cs, r1 * cs, float(block.min()) - self.skirt_m, float(block.max()))
                tiles.append(TerrainTile(r0, c0, r1, c1, bounds))
        log.info(
            "terrain: %d tiles of %d cells, %d levels, refine %d, skirt %.1f m",
            len(tiles),
            n,
            self.n_levels,
            self.refine,
            self.skirt_m,
        )
        return tiles

    def tile_mesh(self, tile: int, level: int) -> TileMesh:
        """The mesh of tile ``tile`` at ``level`` (built on first use), with its skirt."""
        key = (tile, level)
        if key in self._cache:
            return self._cache[key]
        t = self.tiles[tile]
        cs = self.terrain.cell_size
        s = self.spacing(level)
        ri, ci = _level_positions(t.row0, t.row1, s), _level_positions(t.col0, t.col1, s)
        nr, nc = len(ri), len(ci)
        R, C = np.meshgrid(ri, ci, indexing="ij")
        pos = np.stack([C * cs, R * cs, _bilinear(self.terrain.heights, R, C)], -1).reshape(-1, 3)
        nor = _bilinear(self._normals, R, C).reshape(-1, 3)
        nor /= np.linalg.norm(nor, axis=1, keepdims=True)
        col = _bilinear(self._colors, R, C).reshape(-1, 3)
        tri = _grid_indices(pos[:, 2].reshape(nr, nc))
        # skirt: the border ring, copied down by skirt_m metres
        grid = np.arange(nr * nc).reshape(nr, nc)
        ring = np.concatenate([grid[0, :], grid[1:, -1], grid[-1, -2::-1], grid[-2:0:-1, 0]])
        low = np.arange(len(ring)) + nr * nc
        a, b = ring, np.roll(ring, -1)
        la, lb = low, np.roll(low, -1)
        skirt_tri = np.concatenate([np.stack([a, b, lb], 1), np.stack([a, lb, la], 1)]).astype(np.uint32)
        lowered = pos[ring].copy()
        lowered[:, 2] -= self.skirt_m
        mesh = TileMesh(
            stride=s,
            positions=np.concatenate([pos, lowered]).astype(np.float32),
            normals=np.concatenate([nor, nor[ring]]).astype(np.float32),
            colors=np.concatenate(
                [np.column_stack([col, np.ones(len(col))]), np.column_stack([col[ring] * 0.8, np.ones(len(ring))])]
            ).astype(np.float32),
            indices=np.concatenate([tri, skirt_tri]),
        )
        self._cache[key] = mesh
        return mesh

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
        outside = outside_frustum(corners, eye, rotation, tan_half_fov=tan_half_fov)
        dx = np.maximum(np.maximum(b[:, 0] - eye[0], eye[0] - b[:, 1]), 0)
        dy = np.maximum(np.maximum(b[:, 2] - eye[1], eye[1] - b[:, 3]), 0)
        d = np.hypot(dx, dy)
        ratio = d / (self.lod_factor * self.terrain.cell_size) * self.refine
        level = np.floor(np.log2(np.maximum(ratio, 1.0))).astype(int)
        level = np.clip(level, 0, self.n_levels - 1)
        level[outside | (d > far)] = -1
        return level


def outside_frustum(
    corners: np.ndarray, eye: np.ndarray, rotation: np.ndarray, *, tan_half_fov: tuple[float, float]
) -> np.ndarray:
    """True for each convex body, given by its corners (n, k, 3) world (x, y, z), that lies wholly
    outside one plane of the view frustum (behind the camera or beyond a side); bool (n,).
    Conservative: a body reported inside may still be out of view. ``rotation`` as in
    :meth:`EnvironmentModel.tile_levels`; the side planes are widened by 5 %."""
    cam = (np.asarray(corners, dtype=np.float64) - eye) @ rotation.T  # camera (right, up, forward)
    tx, ty = tan_half_fov[0] * 1.05, tan_half_fov[1] * 1.05
    xc, yc, zc = cam[..., 0], cam[..., 1], cam[..., 2]
    return (
        np.all(zc < 0, -1)
        | np.all(xc > zc * tx, -1)
        | np.all(-xc > zc * tx, -1)
        | np.all(yc > zc * ty, -1)
        | np.all(-yc > zc * ty, -1)
    )


def build_environment(scenario, *, terrain: Terrain | None = None, **lod) -> EnvironmentModel:
    """Load a scenario's terrain, place its landmarks and build the environment model.

    Raises :class:`ScenarioError` when a route point or a landmark lies outside the terrain.
    ``lod`` passes ``tile_cells``, ``levels`` and ``lod_factor`` to :class:`EnvironmentModel`.
    """
    if terrain is None:
        terrain = scenario_terrain(scenario)
    landmarks = check_extents(scenario, terrain)
    return EnvironmentModel(terrain, landmarks, **lod)


def check_extents(scenario, terrain: Terrain) -> list[Landmark]:
    """Every route point and every landmark footprint inside ``terrain``; returns the landmarks
    placed on it. Raises :class:`ScenarioError` naming the first one outside."""
    x0, x1, y0, y1 = terrain.extent
    where = f"outside the terrain (x {x0:g}..{x1:g}, y {y0:g}..{y1:g} m)"
    frame = getattr(scenario, "map_frame", None)
    if frame is not None:
        (mx0, mx1), (my0, my1) = frame.to_map([x0, x1], [y0, y1])
        where = (
            f"outside the terrain ({frame.name}: x {float(mx0):.7g}..{float(mx1):.7g}, "
            f"y {float(my0):.7g}..{float(my1):.7g}; is the scenario's crs: right?)"
        )
    for i, (x, y) in enumerate(scenario.route):
        if not terrain.contains(x, y):
            shown = f"({x:g}, {y:g})" if frame is None else "({:.7g}, {:.7g})".format(*map(float, frame.to_map(x, y)))
            raise ScenarioError(scenario.path, f"route[{i}]", f"{shown} is {where}")
    for i, spec in enumerate(scenario.landmarks):
        if not terrain.contains(spec.x, spec.y):
            shown = (
                f"({spec.x:g}, {spec.y:g})"
                if frame is None
                else "({:.7g}, {:.7g})".format(*map(float, frame.to_map(spec.x, spec.y)))
            )
            raise ScenarioError(scenario.path, f"landmarks[{i}]", f"{spec.id!r} at {shown} is {where}")
    landmarks = place_landmarks(terrain, scenario.landmarks)
    for i, lm in enumerate(landmarks):
        if not all(terrain.contains(px, py) for px, py in lm.corners()):
            raise ScenarioError(scenario.path, f"landmarks[{i}]", f"footprint of {lm.id!r} is {where}")
    return landmarks
