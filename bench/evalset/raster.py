"""A second evaluation renderer: a numpy triangle-mesh rasteriser with a z-buffer.

Independent of the viewframes' pyrender path and of :mod:`bench.evalset.raycast`'s ray caster:
nothing here calls pyrender, OpenGL, :mod:`models.camera_emulator` or the ray caster (only the
last step, the sensor, ends in :func:`bench.evalset.raycast.sensor_effects`, after effects of its
own). It shares the pinhole convention of :mod:`models.camera_emulator` so that truth poses mean
the same thing: world (x, y, z) metres, x east, y north, z up; heading counterclockwise from +x,
pitch up; image (row, col), row 0 at the top, pixel centres at integers, principal point at
the centre ``(cx, cy) = ((W - 1) / 2, (H - 1) / 2)``, ``f = (H / 2) / tan(fov_y / 2)``; a camera
point (right, up, forward) = (xc, yc, zc) lands at ``col = cx + f xc / zc``,
``row = cy - f yc / zc``. Roll turns the camera about its forward axis after the pitch, as in
:mod:`bench.evalset.raycast` (:func:`camera_axes`).

How a frame is made
-------------------
1. **Mesh.** The DEM is a triangle mesh, two triangles a cell, each cell split along the diagonal
   that keeps both triangles at or below the bilinear surface (so the camera, which stands above
   it, is never under the drawn ground), grouped in square tiles of ``tile_cells`` cells.
   Landmark boxes (:class:`Block`) are meshes of four walls and a roof. Every triangle keeps its
   plane and its flat (per-face) lighting.
2. **Culling.** Tiles whose bounding box lies outside the view frustum (or beyond ``far``) are
   skipped; triangles facing away from the camera are dropped (exact for a height field seen
   from above it, and for convex boxes); triangles crossing the near plane are clipped against
   it (one or two triangles each), so the ground under the camera is drawn without holes.
3. **Rasterisation with a z-buffer** at ``supersample`` times the output resolution: each
   triangle's pixel centres are found by barycentric (edge) tests inside its bounding box,
   vectorised over triangles of similar size; depth is 1/z, affine in the image, and the
   nearest triangle wins per pixel (``numpy.maximum.at``). The result is the id of the visible
   triangle at every pixel, or none (sky, or beyond ``far``, or beyond the DEM).
4. **Deferred shading** per pixel: the viewing ray meets the visible triangle's plane (an exact
   world point). Ground colour is a palette of its own (:data:`PALETTES`) driven by procedural
   value noise in world space (vegetation patches, soil grain, accents), the face's steepness
   (rock), strata bands (palettes that have them), a snow line and flat water at a level;
   shading is per-face Lambert with a sun of its own direction plus an ambient term, no cast
   shadows. Boxes take their kind's colours (:data:`KIND_COLOURS`, walls and roof) under the
   same light. Distance haze blends towards a haze colour.
5. **Sky**: uniform colour above a hazy band at the horizon, with a cloud layer (value-noise
   cover on a plane 1.8 km above the camera, fixed in the world).
6. The image is area-averaged to the output size; the horizon (first non-sky row per column)
   and every landmark's visible pixels are read from the same buffers.
7. **Sensor** (:func:`sensor_effects`): a white-balance cast and lateral chromatic aberration of
   its own, then vignetting, gain, gamma, blur, noise as :func:`bench.evalset.raycast.sensor_effects`.

Coordinates in docstrings: world (x, y, z), images (row, col).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields

import cv2
import numpy as np

from bench.evalset import raycast

__all__ = [
    "VERSION",
    "Look",
    "Block",
    "Sensor",
    "RasterFrame",
    "Rasteriser",
    "PALETTES",
    "KIND_COLOURS",
    "camera_axes",
    "sensor_effects",
]

#: ground palettes: soil, vegetation, rock, accent (RGB in [0, 1]) and whether walls show strata
PALETTES: dict[
    str,
    tuple[
        tuple[float, float, float],
        tuple[float, float, float],
        tuple[float, float, float],
        tuple[float, float, float],
        bool,
    ],
] = {
    "desert": ((0.80, 0.67, 0.47), (0.60, 0.55, 0.38), (0.56, 0.42, 0.31), (0.88, 0.79, 0.62), False),
    "canyon": ((0.70, 0.46, 0.31), (0.46, 0.45, 0.30), (0.63, 0.37, 0.25), (0.80, 0.62, 0.45), True),
    "meadow": ((0.44, 0.39, 0.27), (0.25, 0.44, 0.17), (0.52, 0.51, 0.49), (0.13, 0.26, 0.11), False),
    "volcanic": ((0.30, 0.28, 0.27), (0.36, 0.40, 0.23), (0.21, 0.20, 0.20), (0.46, 0.27, 0.20), True),
    "tundra": ((0.53, 0.51, 0.43), (0.43, 0.46, 0.33), (0.47, 0.47, 0.48), (0.63, 0.61, 0.47), False),
    "alpine": ((0.38, 0.41, 0.27), (0.15, 0.27, 0.15), (0.51, 0.51, 0.53), (0.45, 0.47, 0.30), True),
    "steppe": ((0.66, 0.59, 0.41), (0.51, 0.55, 0.30), (0.55, 0.50, 0.45), (0.73, 0.67, 0.43), False),
}

#: landmark colours of this renderer by kind: (walls, roof) RGB in [0, 1] (unlike the ray
#: caster's and the viewframes')
KIND_COLOURS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "house": ((0.70, 0.74, 0.78), (0.26, 0.28, 0.32)),
    "tower": ((0.56, 0.31, 0.22), (0.30, 0.21, 0.17)),
    "silo": ((0.80, 0.82, 0.84), (0.62, 0.64, 0.66)),
    "barn": ((0.47, 0.34, 0.24), (0.52, 0.52, 0.48)),
}

#: bump when what this renderer draws changes (its cases' cache keys include it)
VERSION = "1"

_SNOW = np.array([0.92, 0.93, 0.96])
_WATER = np.array([0.09, 0.19, 0.26])
_CLOUD_ALTITUDE_M = 1800.0


@dataclass(frozen=True)
class Look:
    """Photometry of one camera and day: colours RGB in [0, 1], angles in degrees, metres.

    ``palette``: a key of :data:`PALETTES`; ``vegetation``: share of the ground in vegetation
    patches (0-1); ``texture``: strength of the world-space grain; ``cloud_cover``: share of the
    sky in cloud (0-1); ``haze_m``: distance at which 1/e of the surface light is left;
    ``water_level``: ground at or below this height (m, flat) is water (None: no water);
    ``snow_line``: share of the map's relief above which the ground is snow (None: none).
    """

    palette: str = "meadow"
    sun_azimuth_deg: float = 220.0  # direction the sun is in, ccw from +x
    sun_elevation_deg: float = 35.0
    sun_rgb: tuple[float, float, float] = (1.0, 0.93, 0.80)
    ambient_rgb: tuple[float, float, float] = (0.30, 0.33, 0.40)
    sky_rgb: tuple[float, float, float] = (0.52, 0.66, 0.86)
    haze_rgb: tuple[float, float, float] = (0.76, 0.79, 0.83)
    cloud_rgb: tuple[float, float, float] = (0.94, 0.94, 0.96)
    cloud_cover: float = 0.3
    haze_m: float = 3500.0
    vegetation: float = 0.5
    texture: float = 0.3
    water_level: float | None = None
    snow_line: float | None = None

    def __post_init__(self) -> None:
        if self.palette not in PALETTES:
            raise ValueError(f"palette must be one of {', '.join(PALETTES)}, got {self.palette!r}")
        if not self.haze_m > 0:
            raise ValueError(f"haze_m must be > 0, got {self.haze_m}")


@dataclass(frozen=True)
class Block:
    """A landmark box: centre (x, y), ``width`` along its yaw axis, ``depth`` across, from z0 up to
    z1 (metres), yaw ccw from +x (degrees), wall and roof colours, ``name`` its landmark id."""

    x: float
    y: float
    width: float
    depth: float
    yaw_deg: float
    z0: float
    z1: float
    wall_rgb: tuple[float, float, float]
    roof_rgb: tuple[float, float, float]
    name: str = ""


@dataclass(frozen=True)
class Sensor(raycast.Sensor):
    """:class:`bench.evalset.raycast.Sensor` plus this renderer's own effects: a white-balance
    cast (each channel's gain within 1 +- ``white_balance``) and lateral chromatic aberration
    (red and blue scaled about the centre apart by ``aberration_px`` pixels at the corners)."""

    white_balance: float = 0.0
    aberration_px: float = 0.0


@dataclass(frozen=True)
class RasterFrame:
    """One rendered frame before sensor effects.

    ``image``: ndarray (H, W, 3) float in [0, 1]; ``horizon``: ndarray (W,) float, the first
    non-sky row of each column (H where none); ``visible``: visible pixels per landmark name;
    ``landmarks``: ndarray (H, W) int, the index into the blocks of the landmark covering most
    of each pixel (-1 none); ``depth``: ndarray (H, W) float32, forward distance (metres) at each
    pixel centre, 0 for sky.
    """

    image: np.ndarray
    horizon: np.ndarray
    visible: dict[str, int]
    landmarks: np.ndarray
    depth: np.ndarray


def camera_axes(heading_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """(3, 3): rows are the camera's right, up and forward axes in world (x, y, z).

    Heading ccw from +x, pitch up, then roll about the forward axis (positive turns the right
    axis up, so that the horizon drops towards the right of the image), the convention of
    :mod:`bench.evalset.raycast`; with no roll the rows are those of
    :meth:`models.camera_emulator.Pose.rotation`.
    """
    h, p, r = (math.radians(a) for a in (heading_deg, pitch_deg, roll_deg))
    fwd0 = np.array([math.cos(h), math.sin(h), 0.0])
    right0 = np.array([math.sin(h), -math.cos(h), 0.0])
    up0 = np.array([0.0, 0.0, 1.0])
    fwd = math.cos(p) * fwd0 + math.sin(p) * up0
    up1 = math.cos(p) * up0 - math.sin(p) * fwd0
    right = math.cos(r) * right0 + math.sin(r) * up1
    up = -math.sin(r) * right0 + math.cos(r) * up1
    return np.stack([right, up, fwd])


# ---------------------------------------------------------------------------------------------
# world-space value noise


_LATTICE = 1024  # lattice cells of the noise along each axis (it repeats after that many features)


class _Noise:
    """Smooth value noise in world space: a random lattice of :data:`_LATTICE` squared values,
    sampled bicubically (``cv2.remap``, wrapping) at world points divided by a feature size;
    ``k`` picks one of several independent offsets into it, so one lattice gives many fields."""

    def __init__(self, rng: np.random.Generator, fields: int = 16) -> None:
        self.lattice = rng.random((_LATTICE, _LATTICE), dtype=np.float32)
        self.offsets = rng.uniform(0.0, _LATTICE, (fields, 2))

    def value(self, x: np.ndarray, y: np.ndarray, scale: float, k: int) -> np.ndarray:
        """Noise in [0, 1] (float64, the shape of x) at world (x, y) with features ``scale`` apart."""
        n = x.size
        if n == 0:
            return np.zeros(x.shape)
        width = 1024
        pad = (-n) % width
        u = np.concatenate([(x.ravel() / scale + self.offsets[k, 0]) % _LATTICE, np.zeros(pad)])
        v = np.concatenate([(y.ravel() / scale + self.offsets[k, 1]) % _LATTICE, np.zeros(pad)])
        out = cv2.remap(
            self.lattice,
            u.astype(np.float32).reshape(-1, width),
            v.astype(np.float32).reshape(-1, width),
            cv2.INTER_CUBIC,
            borderMode=cv2.BORDER_WRAP,
        )
        return np.clip(out.ravel()[:n].astype(np.float64), 0.0, 1.0).reshape(x.shape)

    def fbm(
        self,
        x: np.ndarray,
        y: np.ndarray,
        scale: float,
        k: int,
        octaves: int = 3,
        *,
        footprint: np.ndarray | None = None,
    ) -> np.ndarray:
        """``octaves`` of :meth:`value` (each half the feature size and amplitude) around 0.5,
        in [0, 1]. ``footprint`` (metres a pixel spans at each point): an octave fades out where
        its features shrink below about two pixels (a mip-map's filtering: no aliasing far away)."""
        out = np.zeros(x.shape)
        amp, total = 1.0, 0.0
        for o in range(octaves):
            size = scale / 2**o
            w = 1.0 if footprint is None else np.clip(size / footprint / 2.0 - 0.5, 0.0, 1.0)
            if np.any(w):
                out += amp * w * (self.value(x, y, size, (k + o) % len(self.offsets)) - 0.5)
            total += amp
            amp *= 0.5
        return 0.5 + out / total


def _smoothstep(a: float, b: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# ---------------------------------------------------------------------------------------------
# meshes


def _dem_triangles(heights: np.ndarray) -> np.ndarray:
    """Two triangles per cell, (m, 3) vertex indices (row-major vertices), each cell split along
    the diagonal that keeps both at or below the bilinear surface through its corners."""
    rows, cols = heights.shape
    r, c = np.mgrid[0 : rows - 1, 0 : cols - 1]
    a = (r * cols + c).ravel()
    b, d, e = a + 1, a + cols, a + cols + 1  # (r, c+1), (r+1, c), (r+1, c+1)
    twist = (heights[:-1, :-1] - heights[:-1, 1:] - heights[1:, :-1] + heights[1:, 1:]).ravel()
    split_bd = twist > 0  # the bilinear patch bulges up along a-e: cut along b-d, below it
    t1 = np.where(split_bd[:, None], np.stack([a, b, d], 1), np.stack([a, b, e], 1))
    t2 = np.where(split_bd[:, None], np.stack([b, e, d], 1), np.stack([a, e, d], 1))
    return np.stack([t1, t2], 1).reshape(-1, 3)  # the two triangles of a cell next to each other


def _block_mesh(b: Block) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (8, 3), triangles (10, 3) (indices into them), outward normals (10, 3), roof flags (10,)."""
    a = math.radians(b.yaw_deg)
    u = np.array([math.cos(a), math.sin(a), 0.0]) * b.width / 2
    v = np.array([-math.sin(a), math.cos(a), 0.0]) * b.depth / 2
    base = np.array([b.x, b.y, b.z0])
    top = np.array([0.0, 0.0, b.z1 - b.z0])
    ring = [base - u - v, base + u - v, base + u + v, base - u + v]
    verts = np.array(ring + [p + top for p in ring])
    faces = [(0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7), (4, 5, 6, 7)]
    tris, normals, roof = [], [], []
    for k, (p, q, s, t) in enumerate(faces):
        n = np.cross(verts[q] - verts[p], verts[t] - verts[p])
        n /= np.linalg.norm(n)
        centre = verts[[p, q, s, t]].mean(0)
        if np.dot(n, centre - verts.mean(0)) < 0:
            n = -n
        tris += [(p, q, s), (p, s, t)]
        normals += [n, n]
        roof += [k == 4, k == 4]
    return verts, np.array(tris), np.array(normals), np.array(roof)


# ---------------------------------------------------------------------------------------------
# rasterisation


def _clip_near(tri: np.ndarray, ids: np.ndarray, near: float) -> tuple[np.ndarray, np.ndarray]:
    """Clip camera-space triangles (n, 3, 3) against the plane zc = ``near``; returns the
    triangles in front of it (m, 3, 3) and their ids (m,)."""
    front = tri[..., 2] >= near
    count = front.sum(1)
    keep = [tri[count == 3]]
    keep_ids = [ids[count == 3]]

    def cut(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        t = (near - p[:, 2]) / (q[:, 2] - p[:, 2])
        out = p + t[:, None] * (q - p)
        out[:, 2] = near
        return out

    one = count == 1
    if one.any():  # the vertex in front first, cyclic order kept
        k = np.argmax(front[one], 1)
        order = (k[:, None] + np.arange(3)[None, :]) % 3
        t = np.take_along_axis(tri[one], order[..., None], 1)
        a, b, c = t[:, 0], t[:, 1], t[:, 2]
        keep.append(np.stack([a, cut(a, b), cut(a, c)], 1))
        keep_ids.append(ids[one])
    two = count == 2
    if two.any():  # the vertex behind last: a quad a, b, b', a'
        k = np.argmin(front[two], 1)
        order = (k[:, None] + np.arange(1, 4)[None, :]) % 3
        t = np.take_along_axis(tri[two], order[..., None], 1)
        a, b, c = t[:, 0], t[:, 1], t[:, 2]
        p, q = cut(b, c), cut(a, c)
        keep += [np.stack([a, b, p], 1), np.stack([a, p, q], 1)]
        keep_ids += [ids[two], ids[two]]
    return np.concatenate(keep), np.concatenate(keep_ids)


def _rasterise(
    tri: np.ndarray, ids: np.ndarray, *, f: float, width: int, height: int, far: float, chunk: int = 1 << 21
) -> np.ndarray:
    """Z-buffer camera-space triangles (n, 3, 3), all in front of the near plane, at pixel centres:
    the id of the nearest triangle per pixel, ndarray (height, width) int64, -1 where none (or
    only surfaces beyond ``far``).

    Scanline form, vectorised over every row of every triangle: on a row the three barycentric
    weights, affine in the column, bound the covered columns to one span; the spans are expanded
    to pixels, and the nearest (largest 1 / depth) wins per pixel."""
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    zbuf = np.zeros(height * width)  # 1 / forward depth; 0 = infinitely far
    idbuf = np.full(height * width, -1, np.int64)
    if len(tri) == 0:
        return idbuf.reshape(height, width)
    col = cx + f * tri[..., 0] / tri[..., 2]
    row = cy - f * tri[..., 1] / tri[..., 2]
    iz = 1.0 / tri[..., 2]
    c0, c1, c2 = col.T
    r0, r1, r2 = row.T
    area = (c1 - c0) * (r2 - r0) - (c2 - c0) * (r1 - r0)
    cmin = np.maximum(np.ceil(col.min(1)), 0.0)
    cmax = np.minimum(np.floor(col.max(1)), width - 1.0)
    rmin = np.maximum(np.ceil(row.min(1)), 0.0)
    rmax = np.minimum(np.floor(row.max(1)), height - 1.0)
    ok = (np.abs(area) > 1e-12) & (cmin <= cmax) & (rmin <= rmax)
    sel = np.flatnonzero(ok)
    if len(sel) == 0:
        return idbuf.reshape(height, width)
    c0, c1, c2, r0, r1, r2, a = c0[sel], c1[sel], c2[sel], r0[sel], r1[sel], r2[sel], area[sel]
    # barycentric weights as affine functions of the pixel (col, row): w_i = A_i col + B_i row + C_i
    a0, b0, k0 = (r1 - r2) / a, (c2 - c1) / a, (c1 * r2 - c2 * r1) / a
    a1, b1, k1 = (r2 - r0) / a, (c0 - c2) / a, (c2 * r0 - c0 * r2) / a
    a2, b2, k2 = -a0 - a1, -b0 - b1, 1.0 - k0 - k1
    iz0, iz1, iz2 = iz[sel].T
    za, zb, zk = (
        a0 * (iz0 - iz2) + a1 * (iz1 - iz2),
        b0 * (iz0 - iz2) + b1 * (iz1 - iz2),
        iz2 + k0 * (iz0 - iz2) + k1 * (iz1 - iz2),
    )
    edges = ((a0, b0, k0), (a1, b1, k1), (a2, b2, k2))
    eps, iz_far = 1e-7, 1.0 / far
    rmin, cmin, cmax, ids = rmin[sel], cmin[sel], cmax[sel], ids[sel]
    nrows = (rmax[sel] - rmin + 1).astype(np.int64)
    # triangles in chunks of about ``chunk`` bounding-box pixels
    work = np.cumsum(nrows * (cmax - cmin + 1))
    cuts = np.searchsorted(work, chunk * np.arange(1, int(work[-1] // chunk) + 1))
    for lo_t, hi_t in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [len(sel)]])):
        if hi_t <= lo_t:
            continue
        n = nrows[lo_t:hi_t]
        t = np.repeat(np.arange(lo_t, hi_t), n)  # one entry per (triangle, row)
        first = np.cumsum(n) - n
        py = rmin[t] + (np.arange(len(t)) - np.repeat(first, n))
        lo = cmin[t]
        hi = cmax[t]
        with np.errstate(divide="ignore", invalid="ignore"):
            for ea, eb, ek in edges:
                ca, k = ea[t], eb[t] * py + ek[t]
                bound = (-eps - k) / ca  # w = ca col + k >= -eps
                lo = np.where(ca > 0, np.maximum(lo, np.ceil(bound)), lo)
                hi = np.where(ca < 0, np.minimum(hi, np.floor(bound)), hi)
                hi = np.where((ca == 0) & (k < -eps), lo - 1, hi)
        length = np.maximum(hi - lo + 1, 0).astype(np.int64)
        keep = length > 0
        t, py, lo, length = t[keep], py[keep], lo[keep], length[keep]
        start = np.cumsum(length) - length
        tt = np.repeat(t, length)
        px = np.repeat(lo, length) + (np.arange(int(length.sum())) - np.repeat(start, length))
        pyy = np.repeat(py, length)
        z = za[tt] * px + zb[tt] * pyy + zk[tt]
        near_enough = z >= iz_far
        pix = (pyy * width + px).astype(np.int64)[near_enough]
        z, who = z[near_enough], ids[tt[near_enough]]
        np.maximum.at(zbuf, pix, z)
        win = z >= zbuf[pix]
        idbuf[pix[win]] = who[win]
    return idbuf.reshape(height, width)


# ---------------------------------------------------------------------------------------------
# the renderer


class Rasteriser:
    """Renders camera frames of a height field and its landmark boxes (module docstring).

    ``heights``: ndarray (rows, cols) metres, cell (r, c) at world (x, y) = (c * cell, r * cell)
    (the grid convention of :mod:`models.terrain`); ``blocks``: the landmark boxes; ``rng``
    seeds the world-space noise (ground and clouds), so one seed gives one world.

    Example::

        cam = Rasteriser(heights, 10.0, look=Look(palette="desert"), rng=np.random.default_rng(1))
        image, horizon, visible = cam.render(500.0, 400.0, z, heading_deg=30.0, pitch_deg=0.0,
                                             roll_deg=0.0, width=320, height=240, fov_y_deg=45.0)
    """

    def __init__(
        self,
        heights: np.ndarray,
        cell: float,
        *,
        look: Look,
        rng: np.random.Generator,
        blocks: Sequence[Block] = (),
        tile_cells: int = 16,
    ) -> None:
        h = np.asarray(heights, np.float64)
        if h.ndim != 2 or min(h.shape) < 2:
            raise ValueError(f"heights must be a 2-D grid of at least 2x2 cells, got shape {h.shape}")
        if not np.isfinite(h).all():
            raise ValueError("heights must be finite")
        if not cell > 0:
            raise ValueError(f"cell must be > 0, got {cell}")
        if tile_cells < 1:
            raise ValueError(f"tile_cells must be >= 1, got {tile_cells}")
        self.heights, self.cell, self.look = h, float(cell), look
        self.blocks = list(blocks)
        rows, cols = h.shape
        yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float64) * self.cell
        verts = [np.stack([xx, yy, h], -1).reshape(-1, 3)]
        tris = _dem_triangles(h)
        # terrain triangles in tile order: tile (tr, tc) holds cells [tr*T, tr*T+T) x [tc*T, tc*T+T)
        cr, cc = np.mgrid[0 : rows - 1, 0 : cols - 1]
        n_tc = -(-(cols - 1) // tile_cells)
        tile_of_cell = ((cr // tile_cells) * n_tc + cc // tile_cells).ravel()
        order = np.argsort(np.repeat(tile_of_cell, 2), kind="stable")
        tris = tris[order]
        n_tiles = int(tile_of_cell.max()) + 1
        counts = np.bincount(np.repeat(tile_of_cell, 2), minlength=n_tiles)
        self._tile_start = np.concatenate([[0], np.cumsum(counts)])
        boxes = []
        for t in range(n_tiles):
            tr, tc = divmod(t, n_tc)
            r0, r1 = tr * tile_cells, min((tr + 1) * tile_cells, rows - 1)
            c0, c1 = tc * tile_cells, min((tc + 1) * tile_cells, cols - 1)
            z = h[r0 : r1 + 1, c0 : c1 + 1]
            boxes.append((c0 * cell, c1 * cell, r0 * cell, r1 * cell, float(z.min()), float(z.max())))
        lo_hi = np.array(boxes)
        self._tile_corners = np.stack(
            [lo_hi[:, [i, 2 + j, 4 + k]] for i in (0, 1) for j in (0, 1) for k in (0, 1)], 1
        )  # (tiles, 8, 3)
        v0 = verts[0][tris[:, 0]]
        n = np.cross(verts[0][tris[:, 1]] - v0, verts[0][tris[:, 2]] - v0)
        n *= np.where(n[:, 2:3] < 0, -1.0, 1.0)
        normals = [n / np.linalg.norm(n, axis=1, keepdims=True)]
        owner = [np.full(len(tris), -1, np.int64)]
        colour = [np.zeros((len(tris), 3))]
        all_tris = [tris]
        offset = len(verts[0])
        for k, b in enumerate(self.blocks):
            bv, bt, bn, roof = _block_mesh(b)
            verts.append(bv)
            all_tris.append(bt + offset)
            offset += len(bv)
            normals.append(bn)
            owner.append(np.full(len(bt), k, np.int64))
            colour.append(np.where(roof[:, None], np.asarray(b.roof_rgb), np.asarray(b.wall_rgb)))
        self._verts = np.concatenate(verts)
        self._tris = np.concatenate(all_tris).astype(np.int64)
        self._normals = np.concatenate(normals)
        self._owner = np.concatenate(owner)
        self._colour = np.concatenate(colour)
        self._plane = np.einsum("ij,ij->i", self._normals, self._verts[self._tris[:, 0]])
        self._n_terrain = len(tris)
        self._block_tris = np.arange(self._n_terrain, len(self._tris))
        az, el = math.radians(look.sun_azimuth_deg), math.radians(look.sun_elevation_deg)
        self._sun = np.array([math.cos(az) * math.cos(el), math.sin(az) * math.cos(el), math.sin(el)])
        lambert = np.clip(self._normals @ self._sun, 0.0, None)
        self._light = np.asarray(look.ambient_rgb)[None, :] + lambert[:, None] * np.asarray(look.sun_rgb)[None, :]
        self._zmin, self._relief = float(h.min()), float(np.ptp(h)) or 1.0
        self._noise = _Noise(rng)

    # ------------------------------------------------------------------ geometry
    def _visible_triangles(
        self, eye: np.ndarray, axes: np.ndarray, *, tan_x: float, tan_y: float, near: float, far: float
    ) -> np.ndarray:
        """Ids of the triangles in tiles that may be in view, facing the camera."""
        cam = (self._tile_corners - eye) @ axes.T  # (tiles, 8, 3)
        x, y, z = cam[..., 0], cam[..., 1], cam[..., 2]
        out = (
            np.all(x > tan_x * z, 1)
            | np.all(-x > tan_x * z, 1)
            | np.all(y > tan_y * z, 1)
            | np.all(-y > tan_y * z, 1)
            | np.all(z < near, 1)
            | np.all(z > far, 1)
        )
        starts, stops = self._tile_start[:-1][~out], self._tile_start[1:][~out]
        lengths = stops - starts
        idx = np.repeat(starts - np.concatenate([[0], np.cumsum(lengths)[:-1]]), lengths) + np.arange(lengths.sum())
        idx = np.concatenate([idx, self._block_tris])
        facing = np.einsum("ij,ij->i", self._normals[idx], eye - self._verts[self._tris[idx, 0]]) > 0
        return idx[facing]

    # ------------------------------------------------------------------ shading
    def _ground_colour(self, p: np.ndarray, normal: np.ndarray, footprint: np.ndarray) -> np.ndarray:
        """Albedo (n, 3) of ground points p (n, 3) on faces of unit normals (n, 3), seen with
        pixels spanning ``footprint`` (n,) metres."""
        soil, veg, rock, accent, strata = PALETTES[self.look.palette]
        nz = self._noise
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        wx, wy = x + 0.7 * z, y - 0.7 * z  # texture coordinates that also vary up a wall
        u = (z - self._zmin) / self._relief
        patch = nz.fbm(x, y, 140.0, 0, 3)
        v = _smoothstep(0.45, 0.55, patch + (self.look.vegetation - 0.5) * 0.5 - 0.15 * u)
        albedo = np.asarray(soil) * (1 - v[:, None]) + np.asarray(veg) * v[:, None]
        acc = _smoothstep(0.62, 0.72, nz.fbm(x, y, 45.0, 3, 2))
        albedo = albedo * (1 - acc[:, None]) + np.asarray(accent) * acc[:, None]
        steep = np.sqrt(np.clip(1.0 - normal[:, 2] ** 2, 0.0, None)) / np.maximum(normal[:, 2], 1e-3)
        rocky = _smoothstep(0.5, 0.95, steep + 0.3 * (nz.value(wx, wy, 12.0, 5) - 0.5))
        albedo = albedo * (1 - rocky[:, None]) + np.asarray(rock) * rocky[:, None]
        if strata:
            band = np.sin(2.0 * math.pi * z / 9.0 + 2.0 * nz.value(x, y, 300.0, 6))
            albedo = albedo * (1.0 + 0.22 * band * (0.3 + 0.7 * rocky))[:, None]
        if self.look.snow_line is not None:
            snow = _smoothstep(self.look.snow_line - 0.03, self.look.snow_line + 0.03, u + 0.06 * (patch - 0.5))
            snow *= 1.0 - 0.8 * rocky
            albedo = albedo * (1 - snow[:, None]) + _SNOW * snow[:, None]
        grain = nz.fbm(wx, wy, 4.0, 7, 5, footprint=footprint) - 0.5
        albedo = albedo * (1.0 + 2.0 * self.look.texture * grain)[:, None]
        if self.look.water_level is not None:
            wet = (z <= self.look.water_level) & (normal[:, 2] > 0.9999)
            albedo[wet] = _WATER
        return np.clip(albedo, 0.0, 1.0)

    def _sky(self, d: np.ndarray, eye: np.ndarray) -> np.ndarray:
        """Sky colour (n, 3) along unit world directions d (n, 3) from ``eye``."""
        lk = self.look
        elev = np.arcsin(np.clip(d[:, 2], -1.0, 1.0))
        t = _smoothstep(0.0, 0.3, elev) ** 0.8
        col = np.asarray(lk.haze_rgb) * (1 - t[:, None]) + np.asarray(lk.sky_rgb) * t[:, None]
        up = elev > 0.01
        if lk.cloud_cover > 0 and up.any():
            dist = _CLOUD_ALTITUDE_M / np.sin(elev[up])
            q = eye[None, :2] + d[up, :2] * dist[:, None]
            dens = self._noise.fbm(q[:, 0], q[:, 1], 1500.0, 10, 4)
            cover = _smoothstep(1.0 - lk.cloud_cover - 0.08, 1.0 - lk.cloud_cover + 0.12, dens)
            cover *= np.exp(-dist / 25000.0)
            shade = 0.78 + 0.22 * self._noise.value(q[:, 0], q[:, 1], 400.0, 14)
            cloud = np.asarray(lk.cloud_rgb)[None, :] * shade[:, None]
            col[up] = col[up] * (1 - cover[:, None]) + cloud * cover[:, None]
        return col

    # ------------------------------------------------------------------ output
    def render_frame(
        self,
        x: float,
        y: float,
        z: float,
        *,
        heading_deg: float,
        pitch_deg: float,
        roll_deg: float,
        width: int,
        height: int,
        fov_y_deg: float,
        far: float = 5000.0,
        near: float = 0.5,
        supersample: int | None = None,
    ) -> RasterFrame:
        """The frame seen from camera position (x, y, z) (world metres) at the given heading,
        pitch and roll (degrees), ``width`` x ``height`` pixels, vertical field of view
        ``fov_y_deg``; ``supersample`` (default 4 below 100 rows, 2 below 400, else 1) pixels per
        output pixel along each axis."""
        if width < 8 or height < 8:
            raise ValueError(f"width and height must be >= 8, got {width}x{height}")
        if not 0 < fov_y_deg < 180:
            raise ValueError(f"fov_y_deg must be in (0, 180), got {fov_y_deg}")
        if not 0 < near < far:
            raise ValueError(f"near and far must satisfy 0 < near < far, got {near}, {far}")
        ss = (4 if height < 100 else 2 if height < 400 else 1) if supersample is None else int(supersample)
        if ss < 1:
            raise ValueError(f"supersample must be >= 1, got {supersample}")
        ws, hs = width * ss, height * ss
        f = (hs / 2.0) / math.tan(math.radians(fov_y_deg) / 2.0)
        eye = np.array([x, y, z], np.float64)
        axes = camera_axes(heading_deg, pitch_deg, roll_deg)
        tan_x, tan_y = (ws / 2.0 + 1.0) / f, (hs / 2.0 + 1.0) / f
        idx = self._visible_triangles(eye, axes, tan_x=tan_x, tan_y=tan_y, near=near, far=far)
        cam = (self._verts[self._tris[idx]] - eye) @ axes.T  # (n, 3, 3) right, up, forward
        tri, ids = _clip_near(cam, idx, near)
        ids_img = _rasterise(tri, ids, f=f, width=ws, height=hs, far=far)
        # deferred shading: each pixel's ray meets its triangle's plane
        cx, cy = (ws - 1) / 2.0, (hs - 1) / 2.0
        rr, cc = np.mgrid[0:hs, 0:ws]
        d_cam = np.stack([(cc - cx) / f, (cy - rr) / f, np.ones((hs, ws))], -1).reshape(-1, 3)
        d_world = d_cam @ axes  # forward component 1 along the camera axis
        flat = ids_img.ravel()
        hit = flat >= 0
        tid = flat[hit]
        dw = d_world[hit]
        nrm = self._normals[tid]
        denom = np.einsum("ij,ij->i", nrm, dw)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self._plane[tid] - nrm @ eye) / denom
        t = np.clip(np.nan_to_num(t, nan=far, posinf=far, neginf=near), near, far)
        p = eye + t[:, None] * dw
        owner = self._owner[tid]
        on_ground = owner < 0
        albedo = self._colour[tid].copy()
        dist = t * np.linalg.norm(dw, axis=1)
        albedo[on_ground] = self._ground_colour(p[on_ground], nrm[on_ground], dist[on_ground] / f)
        colour = albedo * self._light[tid]
        if self.look.water_level is not None:  # water mirrors some sky, more at grazing angles
            wet = on_ground & (p[:, 2] <= self.look.water_level) & (nrm[:, 2] > 0.9999)
            if wet.any():
                du = dw[wet] / np.linalg.norm(dw[wet], axis=1, keepdims=True)
                refl = du * np.array([1.0, 1.0, -1.0])
                fres = (0.1 + 0.7 * (1.0 - np.abs(du[:, 2])) ** 5)[:, None]
                colour[wet] = colour[wet] * (1 - fres) + self._sky(refl, eye) * fres
        trans = np.exp(-dist / self.look.haze_m)[:, None]
        colour = colour * trans + np.asarray(self.look.haze_rgb) * (1 - trans)
        img = np.empty((hs * ws, 3))
        img[hit] = colour
        sky_d = d_world[~hit]
        img[~hit] = self._sky(sky_d / np.linalg.norm(sky_d, axis=1, keepdims=True), eye)
        depth = np.zeros(hs * ws)
        depth[hit] = t
        lm = np.full(hs * ws, -1, np.int64)
        lm[hit] = owner
        # to the output size
        img_out = cv2.resize(img.reshape(hs, ws, 3).astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
        sky_frac = cv2.resize((~hit).reshape(hs, ws).astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
        ground = sky_frac < 0.5
        horizon = np.where(ground.any(0), np.argmax(ground, axis=0), height).astype(np.float64)
        lm2 = lm.reshape(hs, ws)
        landmarks = np.full((height, width), -1, np.int64)
        visible: dict[str, int] = {}
        for k, b in enumerate(self.blocks):
            share = cv2.resize((lm2 == k).astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
            m = share > 0.5
            visible[b.name] = int(m.sum())
            landmarks[m] = k
        # depth at the output pixel centres (the supersampled pixel nearest each centre)
        rows_out = np.clip(np.round(np.arange(height) * ss + (ss - 1) / 2.0), 0, hs - 1).astype(np.intp)
        cols_out = np.clip(np.round(np.arange(width) * ss + (ss - 1) / 2.0), 0, ws - 1).astype(np.intp)
        depth_out = depth.reshape(hs, ws)[np.ix_(rows_out, cols_out)].astype(np.float32)
        return RasterFrame(np.clip(img_out, 0.0, 1.0), horizon, visible, landmarks, depth_out)

    def render(
        self,
        x: float,
        y: float,
        z: float,
        *,
        heading_deg: float,
        pitch_deg: float,
        roll_deg: float,
        width: int,
        height: int,
        fov_y_deg: float,
        far: float = 5000.0,
        supersample: int | None = None,
    ) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
        """(image (height, width, 3) float in [0, 1], horizon row per column (width,), visible
        pixels per landmark name): :meth:`render_frame`'s, in the form of
        :meth:`bench.evalset.raycast.RayCaster.render`."""
        fr = self.render_frame(
            x,
            y,
            z,
            heading_deg=heading_deg,
            pitch_deg=pitch_deg,
            roll_deg=roll_deg,
            width=width,
            height=height,
            fov_y_deg=fov_y_deg,
            far=far,
            supersample=supersample,
        )
        return fr.image, fr.horizon, fr.visible


def sensor_effects(image: np.ndarray, *, sensor: Sensor, rng: np.random.Generator) -> np.ndarray:
    """A camera's sensor on a linear image (H, W, 3) float in [0, 1]: this renderer's white-balance
    cast and chromatic aberration, then :func:`bench.evalset.raycast.sensor_effects` (vignetting,
    gain, gamma, blur, noise); uint8 RGB (H, W, 3)."""
    img = np.asarray(image, np.float32)
    if sensor.white_balance > 0:
        gains = 1.0 + rng.uniform(-sensor.white_balance, sensor.white_balance, 3)
        img = np.clip(img * gains.astype(np.float32), 0.0, 1.0)
    if sensor.aberration_px > 0:
        h, w = img.shape[:2]
        centre = ((w - 1) / 2.0, (h - 1) / 2.0)
        half_diag = 0.5 * math.hypot(w, h)
        out = img.copy()
        for ch, sign in ((0, 1.0), (2, -1.0)):
            scale = 1.0 + sign * 0.5 * sensor.aberration_px / half_diag
            m = cv2.getRotationMatrix2D(centre, 0.0, scale)
            out[..., ch] = cv2.warpAffine(
                img[..., ch], m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
            )
        img = out
    base = raycast.Sensor(**{f.name: getattr(sensor, f.name) for f in fields(raycast.Sensor)})
    return raycast.sensor_effects(img, sensor=base, rng=rng)
