"""An evaluation renderer independent of the viewframes' pyrender path: a height-field ray caster.

Nothing here calls pyrender, OpenGL or :mod:`models.camera`; it shares only the pinhole
convention of :mod:`models.camera` (world (x, y, z) metres, x east, y north, z up; heading
counterclockwise from +x; image (row, col), row 0 at the top, principal point at the centre,
``f = (H / 2) / tan(fov_y / 2)``) so that truth poses mean the same thing.

How a frame is made
-------------------
1. **Level canvas.** A camera with zero pitch and roll at the true position and heading, with a
   field of view 6 degrees wider on each side and ``supersample`` times the output resolution.
   Each canvas column is a vertical plane; the terrain along it is marched outwards at
   geometrically growing horizontal distances s (relative step ``eps`` ~ 1.5 canvas pixels)
   and projected to ``row = cy - f * (F(p) - z_eye) / (s cos a)``; the running minimum of
   those rows gives, for every pixel below it, the first sample that covers it (the classic
   "voxel space" occlusion, exact for a level pinhole as the step goes to zero). Beyond the DEM
   nothing is drawn (as in the viewframes).
2. **Surface colour** comes from a radiance grid on the DEM: an albedo palette of its own
   (height, slope and two octaves of world-space texture at 1/``texture_res`` of a cell),
   shaded by a sun of its own direction with cast shadows (a height-field horizon march) and a
   hemispherical sky light, plus exponential fog towards the horizon colour.
3. **Landmark boxes** are intersected per pixel (slab test) inside their projected bounding
   rectangle, shaded per face (walls, roof of another colour), and kept where nearer than the
   terrain.
4. **Sky**: a gradient from a horizon to a zenith colour by elevation angle, with a sun glow.
5. **Pitch and roll** are a rotation about the camera centre, hence a homography of the canvas:
   the output image (at ``supersample`` x) is remapped from it, then area-averaged to the output
   size.
6. **Sensor** (:func:`sensor_effects`): vignetting, gain, gamma, defocus and motion blur,
   Gaussian and shot noise, JPEG compression (when saved as .jpg).

Coordinates in docstrings: world (x, y, z), images (row, col).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["Look", "World", "Box", "RayCaster", "sensor_effects", "Sensor"]


@dataclass(frozen=True)
class Look:
    """Photometry of one camera and day: colours RGB in [0, 1], angles in degrees."""

    sun_azimuth_deg: float = 135.0  # direction the sun is in, ccw from +x
    sun_elevation_deg: float = 40.0
    sun_rgb: tuple[float, float, float] = (1.0, 0.96, 0.88)
    sky_light_rgb: tuple[float, float, float] = (0.38, 0.42, 0.50)
    horizon_rgb: tuple[float, float, float] = (0.82, 0.86, 0.90)
    zenith_rgb: tuple[float, float, float] = (0.35, 0.52, 0.80)
    fog_m: float = 4000.0  # distance at which 1/e of the surface light is left
    palette: str = "green"  # "green", "dry" or "alpine"
    texture: float = 0.25  # strength of the world-space albedo texture
    shadows: bool = True


@dataclass(frozen=True)
class Box:
    """A landmark box: centre (x, y), ``width`` along its yaw axis, ``depth`` across, from z0 to z1."""

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


_PALETTES = {
    "green": ((0.30, 0.45, 0.20), (0.48, 0.50, 0.30), (0.50, 0.47, 0.42)),
    "dry": ((0.62, 0.55, 0.38), (0.70, 0.62, 0.45), (0.58, 0.50, 0.44)),
    "alpine": ((0.26, 0.36, 0.22), (0.45, 0.45, 0.40), (0.62, 0.62, 0.64)),
}


@dataclass
class World:
    """The true world of a case: heights (rows, cols) float64 metres, ``cell`` metres, boxes."""

    heights: np.ndarray
    cell: float
    boxes: list[Box] = field(default_factory=list)

    def height_at(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray | float:
        """Bilinear F(x, y), clamped at the border (same convention as models.terrain)."""
        scalar = np.ndim(x) == 0 and np.ndim(y) == 0
        h = self.heights
        rows, cols = h.shape
        u = np.clip(np.asarray(x, np.float64) / self.cell, 0.0, cols - 1.0)
        v = np.clip(np.asarray(y, np.float64) / self.cell, 0.0, rows - 1.0)
        c0 = np.minimum(u.astype(np.intp), cols - 2)
        r0 = np.minimum(v.astype(np.intp), rows - 2)
        fu, fv = u - c0, v - r0
        z = (
            h[r0, c0] * (1 - fu) * (1 - fv)
            + h[r0, c0 + 1] * fu * (1 - fv)
            + h[r0 + 1, c0] * (1 - fu) * fv
            + h[r0 + 1, c0 + 1] * fu * fv
        )
        return float(z) if scalar else z


def _sun_vector(look: Look) -> np.ndarray:
    az, el = math.radians(look.sun_azimuth_deg), math.radians(look.sun_elevation_deg)
    return np.array([math.cos(az) * math.cos(el), math.sin(az) * math.cos(el), math.sin(el)])


def _shadow(heights: np.ndarray, cell: float, sun: np.ndarray, max_m: float = 1500.0) -> np.ndarray:
    """1 where a DEM post is lit, 0 in the shadow of the terrain (soft edge), (rows, cols)."""
    rows, cols = heights.shape
    horiz = math.hypot(sun[0], sun[1])
    if horiz < 1e-6:
        return np.ones_like(heights)
    tan_el = sun[2] / horiz
    dx, dy = sun[0] / horiz, sun[1] / horiz
    rr, cc = np.mgrid[0:rows, 0:cols].astype(np.float32)
    hf = heights.astype(np.float32)
    excess = np.full(heights.shape, -np.inf, np.float32)
    d = cell
    while d < max_m:
        mx = (cc + dx * d / cell).astype(np.float32)
        my = (rr + dy * d / cell).astype(np.float32)
        h = cv2.remap(hf, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        excess = np.maximum(excess, (h - hf - d * tan_el) / d)
        d *= 1.15
    # excess is the tangent by which the terrain towards the sun rises above the sun line
    return np.clip(0.5 - excess / 0.02, 0.0, 1.0).astype(np.float64)


class RayCaster:
    """Renders camera frames of a :class:`World` under a :class:`Look` (module docstring).

    ``texture_res`` albedo texels per DEM cell (world-space texture); ``rng`` seeds that texture.
    """

    def __init__(self, world: World, look: Look, *, rng: np.random.Generator, texture_res: int = 4) -> None:
        self.world = world
        self.look = look
        h = world.heights
        rows, cols = h.shape
        self.extent = ((cols - 1) * world.cell, (rows - 1) * world.cell)
        dzdy, dzdx = np.gradient(h, world.cell)
        n = np.stack([-dzdx, -dzdy, np.ones_like(h)], -1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        sun = _sun_vector(look)
        lit = _shadow(h, world.cell, sun) if look.shadows else np.ones_like(h)
        direct = np.clip(n @ sun, 0.0, None) * lit
        sky = 0.5 * (1.0 + n[..., 2])
        light = direct[..., None] * np.asarray(look.sun_rgb) + sky[..., None] * np.asarray(look.sky_light_rgb)
        low, high, rock = (np.asarray(c) for c in _PALETTES[look.palette])
        t = ((h - h.min()) / (np.ptp(h) or 1.0))[..., None]
        slope = np.clip(np.hypot(dzdx, dzdy) / 0.5, 0.0, 1.0)[..., None] ** 1.5
        albedo = (low * (1 - t) + high * t) * (1 - slope) + rock * slope
        # radiance grid at texture_res texels per cell, with world-space texture (fields, scrub)
        k = int(texture_res)
        size = ((cols - 1) * k + 1, (rows - 1) * k + 1)
        rad = cv2.resize((albedo * light).astype(np.float32), size, interpolation=cv2.INTER_LINEAR)
        tex = np.zeros(rad.shape[:2], np.float32)
        for period, amp in ((6.0 * k, 0.6), (1.5 * k, 0.4)):
            g = rng.standard_normal((int(rad.shape[0] / period) + 2, int(rad.shape[1] / period) + 2)).astype(np.float32)
            tex += (
                amp
                * cv2.resize(g, (int(g.shape[1] * period), int(g.shape[0] * period)), interpolation=cv2.INTER_CUBIC)[
                    : rad.shape[0], : rad.shape[1]
                ]
            )
        tex /= max(float(tex.std()), 1e-6)
        self._radiance = rad * np.clip(1.0 + look.texture * 0.5 * tex, 0.4, 1.6)[..., None]
        self._tex_per_m = k / world.cell
        self._heights32 = np.pad(h.astype(np.float32), 1, mode="constant", constant_values=-1e7)

    # ------------------------------------------------------------------ canvas
    def _sky(self, elev: np.ndarray, azim: np.ndarray) -> np.ndarray:
        """Sky colour for ray elevation/azimuth arrays (radians), (..., 3)."""
        lk = self.look
        t = np.clip(elev / math.radians(35.0), 0.0, 1.0) ** 0.7
        col = np.asarray(lk.horizon_rgb) * (1 - t[..., None]) + np.asarray(lk.zenith_rgb) * t[..., None]
        sa, se = math.radians(lk.sun_azimuth_deg), math.radians(lk.sun_elevation_deg)
        cosang = np.cos(elev) * math.cos(se) * np.cos(azim - sa) + np.sin(elev) * math.sin(se)
        glow = np.clip(cosang, 0.0, 1.0) ** 24
        return np.clip(col + 0.35 * glow[..., None], 0.0, 1.0)

    def _canvas(
        self, x: float, y: float, z: float, heading_deg: float, *, f: float, width: int, height: int, far: float
    ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Level view (image float (H, W, 3), depth (H, W), box masks by name)."""
        world = self.world
        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
        th = math.radians(heading_deg)
        fwd = np.array([math.cos(th), math.sin(th)])
        right = np.array([math.sin(th), -math.cos(th)])
        cols = np.arange(width, dtype=np.float64)
        a = np.arctan((cols - cx) / f)
        dirs = np.cos(a)[:, None] * fwd + np.sin(a)[:, None] * right  # (W, 2)
        eps = float(np.clip(2.0 / f, 0.002, 0.008))
        s = np.exp(np.arange(0.0, math.log(far), math.log1p(eps))).astype(np.float32)  # 1 m .. far, geometric
        # heights padded by a deep moat: rays leaving the DEM project far below the image
        u = (x / world.cell + s[:, None] * (dirs[:, 0] / world.cell).astype(np.float32)[None, :]).astype(np.float32)
        v = (y / world.cell + s[:, None] * (dirs[:, 1] / world.cell).astype(np.float32)[None, :]).astype(np.float32)
        hz = cv2.remap(
            self._heights32, u + 1.0, v + 1.0, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1e7
        )
        del u, v
        hz -= np.float32(z)
        hz *= (f / np.cos(a)).astype(np.float32)[None, :]
        hz /= s[:, None]
        rows_k = np.float32(cy) - hz  # cy - f (F(p) - z_eye) / (s cos a)
        del hz
        run = np.ascontiguousarray(np.minimum.accumulate(rows_k, axis=0).T)  # (W, K), nonincreasing
        del rows_k
        pix = -np.arange(height, dtype=np.float32)
        first = np.empty((height, width), np.int64)
        for c in range(width):
            # first step whose running top row is at or above pixel row i
            first[:, c] = np.searchsorted(-run[c], pix, side="left")
        sky = first >= len(s)
        k = np.minimum(first, len(s) - 1)
        sk = s[k].astype(np.float64)
        gx = x + sk * dirs[None, :, 0]
        gy = y + sk * dirs[None, :, 1]
        depth = np.where(sky, 0.0, sk * np.cos(a)[None, :])
        tx = (gx * self._tex_per_m).astype(np.float32)
        ty = (gy * self._tex_per_m).astype(np.float32)
        col = cv2.remap(self._radiance, tx, ty, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        # rays of the canvas in world terms (level camera: up = world z)
        rr = np.arange(height, dtype=np.float64)[:, None]
        yc = (cy - rr) / f
        xc = (cols[None, :] - cx) / f
        elev = np.arctan2(yc, np.sqrt(1.0 + xc**2)) * np.ones((1, width))
        azim = th - np.arctan(xc) * np.ones((height, 1))
        trans = np.exp(-sk / self.look.fog_m)[..., None]
        img = col * trans + np.asarray(self.look.horizon_rgb) * (1 - trans)
        img[sky] = self._sky(elev[sky], azim[sky])
        masks: dict[str, np.ndarray] = {}
        self._boxes(img, depth, masks, x=x, y=y, z=z, fwd=fwd, right=right, f=f, cx=cx, cy=cy, far=far)
        return img, depth, masks

    def _boxes(self, img, depth, masks, *, x, y, z, fwd, right, f, cx, cy, far) -> None:
        height, width = depth.shape
        eye = np.array([x, y, z])
        rot = np.array([[right[0], right[1], 0.0], [0.0, 0.0, 1.0], [fwd[0], fwd[1], 0.0]])  # rows: right, up, fwd
        sun = _sun_vector(self.look)
        for b in self.world.boxes:
            ca, sa = math.cos(math.radians(b.yaw_deg)), math.sin(math.radians(b.yaw_deg))
            ax_u, ax_v = np.array([ca, sa, 0.0]), np.array([-sa, ca, 0.0])
            centre = np.array([b.x, b.y, 0.5 * (b.z0 + b.z1)])
            half = np.array([b.width / 2, b.depth / 2, (b.z1 - b.z0) / 2])
            corners = np.array(
                [
                    centre + i * half[0] * ax_u + j * half[1] * ax_v + k * half[2] * np.array([0, 0, 1.0])
                    for i in (-1, 1)
                    for j in (-1, 1)
                    for k in (-1, 1)
                ]
            )
            cam = (corners - eye) @ rot.T
            if np.all(cam[:, 2] <= 0.5) or np.min(np.linalg.norm(corners - eye, axis=1)) > far:
                continue
            zc = np.maximum(cam[:, 2], 0.5)
            cols = cx + f * cam[:, 0] / zc
            rows = cy - f * cam[:, 1] / zc
            c0, c1 = int(max(0, math.floor(cols.min()))), int(min(width - 1, math.ceil(cols.max())))
            r0, r1 = int(max(0, math.floor(rows.min()))), int(min(height - 1, math.ceil(rows.max())))
            if c1 < c0 or r1 < r0:
                continue
            rr, cc = np.mgrid[r0 : r1 + 1, c0 : c1 + 1].astype(np.float64)
            # camera-frame ray with forward component 1, in world terms
            d_cam = np.stack([(cc - cx) / f, (cy - rr) / f, np.ones_like(rr)], -1)
            d_world = d_cam @ rot  # (…, 3)
            axes = np.stack([ax_u, ax_v, np.array([0.0, 0.0, 1.0])])  # (3, 3)
            o = (eye - centre) @ axes.T  # eye in box coordinates
            dl = d_world @ axes.T
            with np.errstate(divide="ignore", invalid="ignore"):
                t1 = (-half - o) / dl
                t2 = (half - o) / dl
            tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
            tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
            hit = (tmax >= tmin) & (tmin > 0)
            terr = depth[r0 : r1 + 1, c0 : c1 + 1]
            hit &= (terr <= 0) | (tmin < terr)  # t is the forward depth (d_cam has forward 1)
            if not hit.any():
                continue
            # face normal: the slab where the entry happened
            entry = np.argmax(np.minimum(t1, t2), axis=-1)
            sign = -np.sign(np.take_along_axis(dl, entry[..., None], -1)[..., 0])
            normal = axes[entry] * sign[..., None]
            shade = np.clip(normal @ sun, 0.0, None)[..., None] * np.asarray(self.look.sun_rgb) + (
                0.5 * (1 + normal[..., 2:3])
            ) * np.asarray(self.look.sky_light_rgb)
            base = np.where((entry == 2)[..., None], np.asarray(b.roof_rgb), np.asarray(b.wall_rgb))
            dist = tmin * np.linalg.norm(d_cam, axis=-1)
            trans = np.exp(-dist / self.look.fog_m)[..., None]
            colour = base * shade * trans + np.asarray(self.look.horizon_rgb) * (1 - trans)
            block = img[r0 : r1 + 1, c0 : c1 + 1]
            block[hit] = colour[hit]
            terr[hit] = tmin[hit]
            mask = np.zeros(depth.shape, bool)
            mask[r0 : r1 + 1, c0 : c1 + 1] = hit
            masks[b.name] = masks.get(b.name, np.zeros(depth.shape, bool)) | mask
            for other in masks:
                if other != b.name:
                    masks[other] &= ~mask

    # ------------------------------------------------------------------ output
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
        """One frame: (image float (height, width, 3) in [0, 1] before sensor effects,
        horizon row per column (width,) float (the first non-sky row, ``height`` where none),
        visible pixels per landmark name)."""
        if width < 8 or height < 8:
            raise ValueError(f"width and height must be >= 8, got {width}x{height}")
        ss = (2 if height < 300 else 1) if supersample is None else int(supersample)
        wo, ho = width * ss, height * ss
        f_o = (ho / 2.0) / math.tan(math.radians(fov_y_deg) / 2.0)
        margin = math.radians(6.0)
        half_y = math.atan((ho / 2.0) / f_o) + margin
        half_x = math.atan((wo / 2.0) / f_o) + margin
        hc = int(2 * math.ceil(f_o * math.tan(half_y)))
        wc = int(2 * math.ceil(f_o * math.tan(half_x)))
        canvas, depth, masks = self._canvas(x, y, z, heading_deg, f=f_o, width=wc, height=hc, far=far)
        # output rays -> canvas pixels: pitch (up) then roll about the forward axis
        p, r = math.radians(pitch_deg), math.radians(roll_deg)
        right1, up1, fwd1 = (
            np.array([1.0, 0, 0]),
            np.array([0, math.cos(p), -math.sin(p)]),
            np.array([0, math.sin(p), math.cos(p)]),
        )
        right2 = math.cos(r) * right1 + math.sin(r) * up1
        up2 = -math.sin(r) * right1 + math.cos(r) * up1
        cxo, cyo = (wo - 1) / 2.0, (ho - 1) / 2.0
        rr, cc = np.mgrid[0:ho, 0:wo].astype(np.float64)
        xo, yo = (cc - cxo) / f_o, (cyo - rr) / f_o
        v = xo[..., None] * right2 + yo[..., None] * up2 + fwd1
        cxc, cyc = (wc - 1) / 2.0, (hc - 1) / 2.0
        mx = (cxc + f_o * v[..., 0] / v[..., 2]).astype(np.float32)
        my = (cyc - f_o * v[..., 1] / v[..., 2]).astype(np.float32)
        big = cv2.remap(canvas.astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        img = cv2.resize(big, (width, height), interpolation=cv2.INTER_AREA)
        skymask = cv2.remap((depth <= 0).astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        sky_small = cv2.resize(skymask, (width, height), interpolation=cv2.INTER_AREA) > 0.5
        ground = ~sky_small
        horizon = np.where(ground.any(0), np.argmax(ground, axis=0), height).astype(np.float64)
        visible = {}
        for name, m in masks.items():
            mm = cv2.remap(m.astype(np.float32), mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
            small = cv2.resize(mm, (width, height), interpolation=cv2.INTER_AREA) > 0.5
            visible[name] = int(small.sum())
        return np.clip(img, 0.0, 1.0), horizon, visible


@dataclass(frozen=True)
class Sensor:
    """Sensor effects of one camera: gain and gamma ranges, blur sigma and noise in output pixels
    and gray levels, vignetting strength, JPEG quality (None: lossless PNG)."""

    gain: tuple[float, float] = (0.8, 1.2)
    gamma: tuple[float, float] = (0.8, 1.25)
    blur: float = 0.6
    motion_px: float = 0.0
    noise: float = 3.0
    shot: float = 0.02
    vignette: float = 0.25
    jpeg_quality: int | None = 80


def sensor_effects(image: np.ndarray, *, sensor: Sensor, rng: np.random.Generator) -> np.ndarray:
    """Apply a camera's sensor to a linear image float (H, W, 3) in [0, 1]; uint8 RGB (H, W, 3)."""
    h, w = image.shape[:2]
    img = image.astype(np.float32)
    rr, cc = np.mgrid[0:h, 0:w].astype(np.float32)
    rad2 = ((rr - (h - 1) / 2) ** 2 + (cc - (w - 1) / 2) ** 2) / ((h / 2) ** 2 + (w / 2) ** 2)
    img *= (1.0 - sensor.vignette * rad2)[..., None]
    img = np.clip(img * rng.uniform(*sensor.gain), 0.0, 1.0) ** rng.uniform(*sensor.gamma)
    if sensor.blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), sensor.blur)
    if sensor.motion_px > 0:
        n = max(1, int(round(sensor.motion_px * rng.uniform(0.5, 1.5))))
        kernel = np.zeros((1, 2 * n + 1), np.float32)
        kernel[0, n:] = 1.0 / (n + 1)
        img = cv2.filter2D(img, -1, kernel)
    out = img * 255.0
    if sensor.shot > 0:
        out = out + rng.standard_normal(out.shape).astype(np.float32) * np.sqrt(
            np.maximum(out, 0) * sensor.shot * 255.0 / 64.0
        )
    if sensor.noise > 0:
        out = out + rng.normal(0.0, sensor.noise, out.shape).astype(np.float32)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)
