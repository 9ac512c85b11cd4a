"""Camera emulator C((x0, y0), heading, P): renders viewframes of the environment model.

Pinhole convention (a contract): the camera stands at world (x, y, z) (metres, x east, y north,
z up), looks along ``heading_deg`` (counterclockwise from +x) tilted by ``pitch_deg`` (positive
upwards), no roll. Vertical field of view ``fov_y_deg``, square pixels, principal point at the
image centre, image row 0 at the top. Image coordinates are (row, col) with pixel centres at
integers, so ``fx = fy = (H / 2) / tan(fov_y / 2)``, ``cx = (W - 1) / 2``, ``cy = (H - 1) / 2``
and a camera-frame point (right, up, forward) = (xc, yc, zc) lands at
``col = cx + fx * xc / zc``, ``row = cy - fy * yc / zc``.

Rendering is offscreen through pyrender; ``PYOPENGL_PLATFORM`` defaults to ``egl`` (Mesa).
One renderer and one scene are reused across views; per view only the terrain tiles' levels of
detail, the landmark boxes that may be in view, the camera pose and the light change. Each
view takes two passes: a lit colour pass (the image) and a flat segmentation pass (the landmark
mask, and the depth: it rasterises without multisampling, so depth is sampled at pixel centres).
pyrender's per-draw Python work is cut without changing a pixel: each shader program looks a
uniform's location up once and skips setting a value it already holds, the renderer picks a
primitive's shader program once per flags, the scene composes a node's pose once per change
(``bench/setup.py`` measures it and checks the output bit for bit). Nodes are drawn in a fixed
order (terrain tiles by tile and level, then landmark boxes), so where two triangles meet a pixel
at the same depth every emulator, in any process, colours it the same.
Several emulators may live in one process; :meth:`CameraEmulator.close` destroys only its own
EGL context (pyrender's ``delete`` would ``eglTerminate`` the display shared with the others).

Shading is Lambertian (``albedo * (ambient + intensity * max(n . l, 0))``), done by a small
fragment shader that replaces pyrender's physically based ``mesh.frag``, which costs far more
per pixel on Mesa's software rasteriser, where the terrain fills most pixels (measured in
BENCHMARKS.md, "Rendering viewframes").
The replacement goes through pyrender's shader cache (``Renderer._program_cache``, pyrender
0.1.x); if that attribute ever disappears the emulator logs a warning and keeps PBR.
"""

from __future__ import annotations

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import atexit  # noqa: E402
import hashlib  # noqa: E402
import logging  # noqa: E402
import math  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import TYPE_CHECKING, Any  # noqa: E402

import numpy as np  # noqa: E402
import pyrender  # noqa: E402
import trimesh  # noqa: E402
from OpenGL.GL import glGetUniformLocation  # noqa: E402
from pyrender.shader_program import ShaderProgram, ShaderProgramCache  # noqa: E402

from models.environment import KIND_COLORS, EnvironmentModel, outside_frustum  # noqa: E402
from models.errors import RenderError  # noqa: E402

if TYPE_CHECKING:
    from models.scenario import CameraSpec

__all__ = ["Pose", "View", "CameraEmulator", "SKY_RGB"]

log = logging.getLogger(__name__)

#: background (sky) colour, RGB in [0, 1]
SKY_RGB = (0.70, 0.80, 0.92)
_DEFAULT_LIGHT_DIRECTION = (-0.45, 0.35, -0.82)  # light travels from the south-east, high sun
_DEFAULT_LIGHT_INTENSITY = 1.0  # a relative scale: the sun's colour carries its strength
_SUN_RGB = (0.75, 0.75, 0.73)
_AMBIENT = (0.48, 0.48, 0.52)

_LAMBERT_FRAG = """#version 330 core
struct DirectionalLight { vec3 color; float intensity; vec3 direction; };
struct Material {
    vec3 emissive_factor;
#ifdef USE_METALLIC_MATERIAL
    vec4 base_color_factor;
    float metallic_factor;
    float roughness_factor;
#endif
#ifdef USE_GLOSSY_MATERIAL
    vec4 diffuse_factor;
    vec3 specular_factor;
    float glossiness_factor;
#endif
};
uniform Material material;
uniform DirectionalLight directional_lights[MAX_DIRECTIONAL_LIGHTS];
uniform int n_directional_lights;
uniform vec3 ambient_light;
in vec3 frag_position;
#ifdef NORMAL_LOC
in vec3 frag_normal;
#endif
#ifdef COLOR_0_LOC
in vec4 color_multiplier;
#endif
out vec4 frag_color;
void main()
{
#ifdef USE_METALLIC_MATERIAL
    vec4 base = material.base_color_factor;
#else
    vec4 base = material.diffuse_factor;
#endif
#ifdef COLOR_0_LOC
    base *= color_multiplier;
#endif
    vec3 light = ambient_light;
#ifdef NORMAL_LOC
    vec3 n = normalize(frag_normal);
    for (int i = 0; i < n_directional_lights; i++) {
        vec3 l = -normalize(directional_lights[i].direction);
        light += directional_lights[i].color * directional_lights[i].intensity * max(dot(n, l), 0.0);
    }
#endif
    frag_color = clamp(vec4(base.rgb * light, base.a), 0.0, 1.0);
}
"""


def _lambert_shader_dir() -> str:
    """A shader folder: pyrender's shaders with ``mesh.frag`` replaced by the Lambert shader.

    The folder is named by a digest of its content, so every process of every run shares one
    (no folder is left behind per process, even when a process is killed); it is built in a
    private temporary folder and renamed into place, so concurrent first uses are safe.
    """
    global _SHADER_DIR
    if _SHADER_DIR is None:
        src = Path(pyrender.__file__).parent / "shaders"
        files = {f.name: f.read_bytes() for f in sorted(src.iterdir()) if f.is_file() and f.name != "mesh.frag"}
        files["mesh.frag"] = _LAMBERT_FRAG.encode()
        digest = hashlib.blake2b(digest_size=8)
        for name, data in sorted(files.items()):
            digest.update(name.encode() + b"\0" + data + b"\0")
        final = Path(tempfile.gettempdir()) / f"mapinterp-shaders-{digest.hexdigest()}"
        if not all((final / name).is_file() for name in files):
            tmp = Path(tempfile.mkdtemp(prefix="mapinterp-shaders-tmp-"))
            for name, data in files.items():
                (tmp / name).write_bytes(data)
            try:
                os.rename(tmp, final)
            except OSError:  # another process won the race, or a stale partial folder is in the way
                shutil.rmtree(tmp, ignore_errors=True)
                if not all((final / name).is_file() for name in files):
                    final = Path(tempfile.mkdtemp(prefix="mapinterp-shaders-"))
                    for name, data in files.items():
                        (final / name).write_bytes(data)
                    atexit.register(shutil.rmtree, final, True)
        _SHADER_DIR = str(final)
    return _SHADER_DIR


_SHADER_DIR: str | None = None


@dataclass(frozen=True)
class Pose:
    """Camera pose: world position (x, y, z) metres, heading ccw from +x, pitch up (degrees)."""

    x: float
    y: float
    z: float
    heading_deg: float
    pitch_deg: float = 0.0

    def rotation(self) -> np.ndarray:
        """(3, 3) matrix whose rows are the camera's right, up and forward axes in world (x, y, z)."""
        h, p = math.radians(self.heading_deg), math.radians(self.pitch_deg)
        forward = np.array([math.cos(h) * math.cos(p), math.sin(h) * math.cos(p), math.sin(p)])
        right = np.array([math.sin(h), -math.cos(h), 0.0])
        up = np.cross(right, forward)
        return np.stack([right, up, forward])

    @property
    def position(self) -> np.ndarray:
        """(3,) world (x, y, z)."""
        return np.array([self.x, self.y, self.z], dtype=np.float64)


@dataclass
class View:
    """A rendered viewframe.

    image: uint8 (H, W, 3) RGB; depth: float32 (H, W) metres along the view axis, 0 for sky;
    mask: int32 (H, W), -1 where no landmark, else the index into ``environment.landmarks``.
    """

    image: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    pose: Pose


def _box_mesh(lm, below: float = 0.0) -> trimesh.Trimesh:
    """The landmark's box, reaching ``below`` metres under its base (hidden by the ground)."""
    transform = np.eye(4)
    a = math.radians(lm.yaw_deg)
    transform[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    transform[:3, 3] = (lm.x, lm.y, lm.z0 + (lm.height - below) / 2)
    return trimesh.creation.box(extents=(lm.width, lm.depth, lm.height + below), transform=transform)


class CameraEmulator:
    """Renders :class:`View` objects of an :class:`EnvironmentModel` with one offscreen renderer.

    Use as a context manager or call :meth:`close`. Example::

        with CameraEmulator(env, scenario.camera) as cam:
            view = cam.render(cam.pose_at(100.0, 100.0, heading_deg=30.0))
    """

    def __init__(self, environment: EnvironmentModel, camera: CameraSpec) -> None:
        self.environment = environment
        self.camera = camera
        self.width, self.height = int(camera.width), int(camera.height)
        self._tan_y = math.tan(math.radians(camera.fov_y_deg) / 2)
        self._tan_x = self._tan_y * self.width / self.height
        self.scene = _ActiveScene(bg_color=(*SKY_RGB, 1.0), ambient_light=_AMBIENT)
        self._terrain_material = _StaticMaterial(
            baseColorFactor=(1.0, 1.0, 1.0, 1.0), metallicFactor=0.0, roughnessFactor=1.0, doubleSided=True
        )
        self._terrain_nodes: dict[tuple[int, int], pyrender.Node] = {}
        self._seg_map: dict[pyrender.Node, np.ndarray] = {}
        self._landmark_nodes = []
        for i, lm in enumerate(environment.landmarks):
            rgb = KIND_COLORS.get(lm.kind, KIND_COLORS["default"])
            material = pyrender.MetallicRoughnessMaterial(
                baseColorFactor=(*rgb, 1.0), metallicFactor=0.0, roughnessFactor=0.9
            )
            box = _box_mesh(lm, environment.ground_margin(lm))
            node = self.scene.add(pyrender.Mesh.from_trimesh(box, material=material, smooth=False))
            code = i + 1
            self._seg_map[node] = np.array([code & 255, (code >> 8) & 255, (code >> 16) & 255], dtype=np.float64)
            self._landmark_nodes.append(node)
        self._cam_node = self.scene.add(
            pyrender.PerspectiveCamera(
                yfov=math.radians(camera.fov_y_deg),
                znear=camera.near,
                zfar=camera.far,
                aspectRatio=self.width / self.height,
            )
        )
        self._light = pyrender.DirectionalLight(color=np.array(_SUN_RGB), intensity=_DEFAULT_LIGHT_INTENSITY)
        self._light_node = self.scene.add(self._light, pose=_light_pose(_DEFAULT_LIGHT_DIRECTION))
        self._current_levels = np.full(len(environment.tiles), -1)
        # drawn boxes reach ground_margin below z0: cull with the corners of what is drawn
        self._box_corners = np.array([lm.box_vertices() for lm in environment.landmarks]).reshape(-1, 8, 3)
        margins = np.array([environment.ground_margin(lm) for lm in environment.landmarks])
        self._box_corners[:, :4, 2] -= margins.reshape(-1, 1)
        try:
            self._renderer = pyrender.OffscreenRenderer(self.width, self.height)
        except Exception as exc:  # pyrender/PyOpenGL raise many kinds
            platform = os.environ.get("PYOPENGL_PLATFORM")
            raise RenderError(f"cannot create an offscreen renderer (PYOPENGL_PLATFORM={platform}): {exc}") from exc
        inner = getattr(self._renderer, "_renderer", None)
        if inner is not None and hasattr(inner, "_program_cache"):
            inner._program_cache = _UniformCachingProgramCache(shader_dir=_lambert_shader_dir())
            if type(inner) is pyrender.renderer.Renderer:
                inner.__class__ = _ProgramCachingRenderer
                inner._programs = {}
                inner._max_lights = {}
        else:  # pragma: no cover - other pyrender versions
            log.warning("pyrender has no shader cache to replace: keeping its PBR shader (slower)")
        self.triangles_last = 0

    # -- geometry -------------------------------------------------------------------------
    @property
    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in pixels, (row, col) pixel centres at integers (module docstring)."""
        f = (self.height / 2) / self._tan_y
        return f, f, (self.width - 1) / 2, (self.height - 1) / 2

    def pose_at(self, x: float, y: float, heading_deg: float, *, pitch_deg: float | None = None) -> Pose:
        """The pose at ground point (x, y): z = F(x, y) + eye_height; pitch defaults to the camera's."""
        z = float(self.environment.terrain.height_at(x, y)) + self.camera.eye_height
        pitch = self.camera.pitch_deg if pitch_deg is None else pitch_deg
        return Pose(float(x), float(y), z, float(heading_deg), float(pitch))

    def project(self, points_xyz: np.ndarray, pose: Pose) -> np.ndarray:
        """Project world points, ndarray (n, 3) (x, y, z), to image (row, col), ndarray (n, 2).

        Points at or behind the camera plane (forward distance <= 0) give NaN.
        """
        pts = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
        cam = (pts - pose.position) @ pose.rotation().T
        fx, fy, cx, cy = self.intrinsics
        with np.errstate(divide="ignore", invalid="ignore"):
            col = cx + fx * cam[:, 0] / cam[:, 2]
            row = cy - fy * cam[:, 1] / cam[:, 2]
        out = np.stack([row, col], 1)
        out[cam[:, 2] <= 0] = np.nan
        return out

    def camera_frame(self, points_xyz: np.ndarray, pose: Pose) -> np.ndarray:
        """World points (n, 3) in camera coordinates (n, 3): (right, up, forward) metres."""
        return (np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3) - pose.position) @ pose.rotation().T

    # -- rendering ------------------------------------------------------------------------
    def _terrain_node(self, tile: int, level: int) -> pyrender.Node:
        """The scene node of a tile at a level, created (and uploaded) on first use."""
        key = (tile, level)
        node = self._terrain_nodes.get(key)
        if node is None:
            lod = self.environment.tile_mesh(tile, level)
            prim = pyrender.Primitive(
                positions=lod.positions,
                normals=lod.normals,
                color_0=lod.colors,
                indices=lod.indices,
                material=self._terrain_material,
            )
            node = self.scene.add(pyrender.Mesh([prim]))
            self._seg_map[node] = np.zeros(3)
            self._terrain_nodes[key] = node
        return node

    def _set_levels(self, pose: Pose) -> None:
        levels = self.environment.tile_levels(
            pose.position, pose.rotation(), tan_half_fov=(self._tan_x, self._tan_y), far=self.camera.far
        )
        for t in np.nonzero(levels != self._current_levels)[0].tolist():
            old, new = int(self._current_levels[t]), int(levels[t])
            if old >= 0:
                self.scene.deactivate(self._terrain_nodes[(t, old)])
            if new >= 0:
                self.scene.activate(self._terrain_node(t, new), (0, t, new))
        self._current_levels = levels
        # landmark boxes: draw only those that may be in view (every draw call costs Python time)
        hidden = outside_frustum(
            self._box_corners, pose.position, pose.rotation(), tan_half_fov=(self._tan_x, self._tan_y)
        )
        far = np.linalg.norm(self._box_corners.mean(1) - pose.position, axis=1) > self.camera.far + 100
        for i, (node, off) in enumerate(zip(self._landmark_nodes, hidden | far)):
            if off:
                self.scene.deactivate(node)
            else:
                self.scene.activate(node, (1, i))
        self.triangles_last = sum(
            len(self.environment.tile_mesh(t, lv).indices) for t, lv in enumerate(levels) if lv >= 0
        )

    def _prepare(
        self,
        pose: Pose,
        light_intensity: float | None,
        light_direction: tuple[float, float, float] | None,
    ) -> None:
        if self._renderer is None:
            raise RenderError("the camera emulator is closed")
        self._set_levels(pose)
        m = np.eye(4)
        rot = pose.rotation()
        m[:3, 0], m[:3, 1], m[:3, 2] = rot[0], rot[1], -rot[2]
        m[:3, 3] = pose.position
        self.scene.set_pose(self._cam_node, m)
        self._light.intensity = _DEFAULT_LIGHT_INTENSITY if light_intensity is None else float(light_intensity)
        self.scene.set_pose(self._light_node, _light_pose(light_direction or _DEFAULT_LIGHT_DIRECTION))

    def render_background(
        self,
        pose: Pose,
        *,
        light_intensity: float | None = None,
        light_direction: tuple[float, float, float] | None = None,
    ) -> np.ndarray:
        """The colour image from ``pose`` with every landmark box left out: the bare terrain and
        sky, uint8 (H, W, 3) RGB. Where a landmark covers pixels of :meth:`render`'s image, these
        are the pixels behind it (what the camera sees when the landmark is not there). One
        colour pass, no segmentation pass; lighting options as in :meth:`render`.
        """
        self._prepare(pose, light_intensity, light_direction)
        for node in self._landmark_nodes:
            self.scene.deactivate(node)
        try:
            color, _ = self._renderer.render(self.scene)
        except Exception as exc:
            raise RenderError(f"rendering failed: {exc}") from exc
        return np.ascontiguousarray(color[..., :3], dtype=np.uint8)

    def render_image(
        self,
        pose: Pose,
        *,
        light_intensity: float | None = None,
        light_direction: tuple[float, float, float] | None = None,
    ) -> np.ndarray:
        """The colour image of :meth:`render` alone, uint8 (H, W, 3) RGB, landmarks included: one
        colour pass, no segmentation pass (about half a :meth:`render`'s cost), for callers that
        need neither depth nor mask (render-and-compare, :mod:`models.verify`)."""
        self._prepare(pose, light_intensity, light_direction)
        try:
            color, _ = self._renderer.render(self.scene)
        except Exception as exc:
            raise RenderError(f"rendering failed: {exc}") from exc
        return np.ascontiguousarray(color[..., :3], dtype=np.uint8)

    def render(
        self,
        pose: Pose,
        *,
        light_intensity: float | None = None,
        light_direction: tuple[float, float, float] | None = None,
    ) -> View:
        """Render the view from ``pose``: image, depth and landmark mask (see :class:`View`).

        ``light_intensity`` (relative sun strength, default 1.0; the ambient light stays) and
        ``light_direction`` (world (x, y, z) direction the sunlight travels, default from the
        south-east and high) change the lighting of this view only.
        """
        self._prepare(pose, light_intensity, light_direction)
        try:
            color, _ = self._renderer.render(self.scene)
            # depth from the segmentation pass: it rasterises without multisampling, so depth is
            # sampled at pixel centres (the colour pass' depth comes from MSAA sample 0, which
            # sits 3/8 pixel off the centre)
            seg, depth = self._renderer.render(self.scene, flags=pyrender.RenderFlags.SEG, seg_node_map=self._seg_map)
        except Exception as exc:
            raise RenderError(f"rendering failed: {exc}") from exc
        seg = seg.astype(np.int32)
        mask = (seg[..., 0] | (seg[..., 1] << 8) | (seg[..., 2] << 16)) - 1
        mask[mask >= len(self.environment.landmarks)] = -1
        return View(
            image=np.ascontiguousarray(color[..., :3], dtype=np.uint8),
            depth=np.asarray(depth, dtype=np.float32),
            mask=mask.astype(np.int32),
            pose=pose,
        )

    def release(self) -> None:
        """Make the GL context no longer current on the calling thread, so that a later
        :meth:`render` or :meth:`close` may run on another thread (EGL binds a context to one
        thread at a time; each render makes it current again)."""
        r = self._renderer
        platform = None if r is None else getattr(r, "_platform", None)
        if platform is not None and getattr(platform, "_egl_context", None) is not None:
            try:  # pyrender's EGL make_uncurrent does nothing
                from OpenGL.EGL import EGL_NO_CONTEXT, EGL_NO_SURFACE, eglMakeCurrent

                eglMakeCurrent(platform._egl_display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT)
            except Exception as exc:  # noqa: BLE001 - nothing to release
                log.debug("releasing the GL context: %s", exc)

    def close(self) -> None:
        """Release the GL context (idempotent).

        pyrender's own ``OffscreenRenderer.delete`` calls ``eglTerminate`` on the process-wide
        EGL display, which kills every other renderer still open in the process; on EGL only
        this renderer's context is destroyed here.
        """
        r, self._renderer = self._renderer, None
        if r is None:
            return
        platform = r._platform
        context = getattr(platform, "_egl_context", None)
        if context is None:
            r.delete()
            return
        from OpenGL.EGL import eglDestroyContext

        try:
            platform.make_current()
            r._renderer.delete()
            platform.make_uncurrent()
            eglDestroyContext(platform._egl_display, context)
            platform._egl_context = None
        except Exception as exc:  # noqa: BLE001 - best effort at teardown
            log.warning("closing the offscreen renderer: %s", exc)
        finally:
            _disarm(r)

    def __del__(self) -> None:
        """Collected without :meth:`close`: destroy this context only, without making it current.

        Garbage collection runs at any allocation, in any thread, possibly in the middle of
        another emulator's render there: it must not switch the thread's current context (as
        :meth:`close` does to delete the GL objects; destroying the context frees them too), nor
        let pyrender's renderer delete its objects by id in the context that happens to be
        current (another renderer's objects of the same ids), nor let pyrender's own ``__del__``
        call ``eglTerminate`` on the shared display, which ended every other renderer of the
        process."""
        r = getattr(self, "_renderer", None)
        if r is None:
            return
        self._renderer = None
        platform = getattr(r, "_platform", None)
        context = getattr(platform, "_egl_context", None)
        if platform is None or context is None:
            return
        try:
            from OpenGL.EGL import eglDestroyContext

            eglDestroyContext(platform._egl_display, context)  # deferred by EGL while current somewhere
        except Exception:  # noqa: BLE001, S110 - nothing else to do at collection
            pass
        finally:
            _disarm(r)

    def __enter__(self) -> CameraEmulator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _disarm(renderer: Any) -> None:
    """Leave the ``__del__`` methods of pyrender's ``OffscreenRenderer`` ``renderer`` nothing to do,
    its EGL context destroyed (or being destroyed) by the caller: its ``Renderer`` would delete
    its buffers, arrays and programs by id in whatever context is current when it is collected
    (another renderer's objects of the same ids), its platform would call ``eglTerminate`` on the
    process-wide display (ending every other renderer)."""
    inner = getattr(renderer, "_renderer", None)
    if inner is not None:
        inner.delete = lambda: None
    platform = getattr(renderer, "_platform", None)
    if platform is not None:
        platform._egl_context = None
        platform._egl_display = None
    renderer._platform = None
    renderer._renderer = None


class _UniformCachingProgram(ShaderProgram):
    """A pyrender shader program that looks each uniform's location up once and skips a
    ``glUniform*`` call when the uniform already holds the value.

    pyrender sets every uniform of every primitive in every pass (camera, lights, material,
    model pose), each time asking GL for the location first; through PyOpenGL each call costs
    tens of microseconds, which is most of a pass at our image sizes. A uniform's value is state
    of the GL program object and persists across ``glUseProgram`` switches, so a call with the
    value the uniform already holds changes nothing: skipping it leaves the rendered images
    bit-identical. Programs are made by pyrender; :class:`_UniformCachingProgramCache` turns each
    into this class as it is created.
    """

    _locations: dict[str, int]
    _values: dict[int, object]

    def set_uniform(self, name: str, value: object, unsigned: bool = False) -> None:
        loc = self._locations.get(name)
        if loc is None:
            loc = self._locations[name] = int(glGetUniformLocation(self._program_id, name))
        if loc == -1:
            return  # pyrender ignores uniforms the program does not have
        if isinstance(value, np.ndarray):
            key: object = (value.dtype.str, value.shape, value.tobytes(), unsigned)
        else:
            key = (type(value), value, unsigned)
        if self._values.get(loc) == key:
            return
        self._values[loc] = key
        super().set_uniform(name, value, unsigned)


class _UniformCachingProgramCache(ShaderProgramCache):
    """pyrender's shader cache handing out :class:`_UniformCachingProgram` programs."""

    def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
        program = super().get_program(vertex_shader, fragment_shader, geometry_shader, defines)
        if not isinstance(program, _UniformCachingProgram):
            program.__class__ = _UniformCachingProgram
            program._locations = {}
            program._values = {}
        return program


class _ProgramCachingRenderer(pyrender.renderer.Renderer):
    """pyrender's renderer remembering, per primitive and flags, the shader program it chose.

    pyrender rebuilds a primitive's shader defines (and queries GL for the texture units) at
    every draw; they depend only on the primitive's buffers and material and on the flags, which
    do not change for our meshes once made, so the choice is made once per (primitive, flags).
    """

    _programs: dict[tuple[object, int, int], ShaderProgram]
    _max_lights: dict[int, list[int]]

    def _compute_max_n_lights(self, flags):
        out = self._max_lights.get(int(flags))
        if out is None:
            out = self._max_lights[int(flags)] = super()._compute_max_n_lights(flags)
        return list(out)

    def _get_primitive_program(self, primitive, flags, program_flags):
        key = (primitive, int(flags), int(program_flags))  # the primitive itself: kept alive, never reused
        program = self._programs.get(key)
        if program is None or not program._in_context():
            program = self._programs[key] = super()._get_primitive_program(primitive, flags, program_flags)
        return program


class _ActiveScene(pyrender.Scene):
    """A scene that shows pyrender's renderer only its *active* mesh nodes, in a fixed order.

    pyrender sorts and visits every mesh node in each pass, including hidden ones; with a mesh
    per terrain tile and level that costs more than the drawing. ``mesh_nodes`` here returns
    the active nodes only, while ``meshes`` still returns all of them, so inactive meshes keep
    their GL buffers instead of being deleted and uploaded again.

    The active nodes come sorted by the key they were activated with (terrain tiles by tile and
    level, then landmarks by index), whatever the history of views. pyrender draws solid nodes
    sorted by the distance of their node origin only, and every terrain tile has its origin at
    the world origin: with a set, the order of equally distant tiles followed the objects'
    addresses, so a pixel where two tiles meet could differ by a grey level between processes.
    """

    def __init__(self, **kwargs) -> None:
        self._active: set[pyrender.Node] = set()
        self._order: dict[pyrender.Node, tuple[int, ...]] = {}
        self._drawn: list[pyrender.Node] | None = None  # the active nodes sorted, until one changes
        self._poses: dict[pyrender.Node, np.ndarray] = {}
        super().__init__(**kwargs)

    # pyrender asks for the camera's and each mesh node's world pose at every draw, composing it
    # along the node's path each time; poses change only through set_pose, add and remove here
    def get_pose(self, node: pyrender.Node) -> np.ndarray:
        pose = self._poses.get(node)
        if pose is None:
            pose = super().get_pose(node)
            pose.setflags(write=False)  # shared between callers: a caller writing to it fails loudly
            self._poses[node] = pose
        return pose

    def set_pose(self, node: pyrender.Node, pose: np.ndarray) -> None:
        super().set_pose(node, pose)
        self._poses.clear()

    def add_node(self, node: pyrender.Node, parent_node: pyrender.Node | None = None) -> None:
        super().add_node(node, parent_node)
        self._poses.clear()

    def remove_node(self, node: pyrender.Node) -> None:
        super().remove_node(node)
        self._poses.clear()

    @property
    def mesh_nodes(self) -> list[pyrender.Node]:
        if self._drawn is None:
            self._drawn = sorted(self._active, key=self._order.__getitem__)
        return self._drawn

    @property
    def meshes(self) -> set[pyrender.Mesh]:
        return {n.mesh for n in self._mesh_nodes}

    def activate(self, node: pyrender.Node, key: tuple[int, ...]) -> None:
        """Show ``node``; ``key`` fixes its place in the drawing order."""
        if self._order.get(node) != key or node not in self._active:
            self._order[node] = key
            self._active.add(node)
            self._drawn = None

    def deactivate(self, node: pyrender.Node) -> None:
        if node in self._active:
            self._active.discard(node)
            self._drawn = None


class _StaticMaterial(pyrender.MetallicRoughnessMaterial):
    """An untextured material whose (empty) texture set pyrender need not recompute per mesh."""

    @property
    def textures(self) -> set:
        return set()


def _light_pose(direction) -> np.ndarray:
    """Node pose of a directional light shining along ``direction`` (world (x, y, z))."""
    d = np.asarray(direction, dtype=np.float64)
    n = np.linalg.norm(d)
    if not n > 0:
        raise ValueError("light_direction must be a non-zero 3-vector")
    z = -d / n  # pyrender lights shine along the node's -z
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = x, y, z
    return m
