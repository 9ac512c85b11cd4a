"""Sensor input: camera frames taken during the mission, from files or simulated.

A real camera's image differs from the synthetic viewframe of the nearest route point in pose
(the vehicle is between route points and off the exact heading) and in photometry (lighting,
surface texture, haze, gain, gamma, sensor noise, optical blur). :func:`simulate_frames`
produces such frames with the same camera emulator that renders the viewframes, then degrades
them; everything is drawn from one seeded generator, so a scenario always yields the same frames.
A scenario's frames (from files or simulated) are :attr:`models.world.World.sensor_frames`.

Frames on file (:func:`frames_from_files`) are decoded by :func:`read_image` (any format OpenCV
reads, 8/16-bit or float, gray to RGBA, EXIF orientation applied, truncated files refused) and
mapped onto the scenario camera's field of view by :func:`fit_to_camera` (another size or aspect
ratio is scaled by the focal lengths' ratio and cropped or padded, never squeezed; a padded
frame's :attr:`SensorFrame.columns` say which columns see the scene).

Images are ``(H, W, 3)`` uint8 RGB arrays indexed ``(row, col)``; poses are in world
``(x, y, z)`` metres with heading counterclockwise from +x.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from models.errors import InputError, ScenarioError
from models.logs import warn_once
from models.scenario import MIN_IMAGE_PX, DriveSpec, Scenario, SimulateSpec

__all__ = [
    "SensorFrame",
    "DrivePose",
    "drive_poses",
    "FrameFit",
    "MIN_COVERAGE",
    "fit_to_camera",
    "focal_px",
    "read_image",
    "load_frame",
    "load_frame_image",
    "frames_from_files",
    "degrade",
    "simulate_frames",
    "iter_simulated_frames",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SensorFrame:
    """One camera frame of the mission.

    Attributes
    ----------
    index : int
        Frame number, in mission order.
    image : ndarray of shape (H, W, 3), uint8
        RGB image at the scenario camera's size.
    truth : tuple (x, y, heading_deg) or None
        The true pose when known (world metres, degrees); never used to localize.
    source : str
        The image file, or ``"simulated"``.
    time : float or None
        Seconds (any origin) when the frame was taken, when known; increasing with ``index``.
    columns : tuple (first, last) or None
        The [first, last) columns of ``image`` that hold the scene when the file's image sees
        less than the camera's width (padded, :func:`fit_to_camera`); None: every column.
    """

    index: int
    image: np.ndarray
    truth: tuple[float, float, float] | None
    source: str
    time: float | None = None
    columns: tuple[int, int] | None = None


@dataclass(frozen=True)
class DrivePose:
    """One frame's pose on a simulated drive: ``time`` (s), ``x``, ``y`` (m), ``heading_deg``,
    ``arc_m`` (arc length of its foot point on the route), ``kidnapped`` (the frame of a jump)."""

    time: float
    x: float
    y: float
    heading_deg: float
    arc_m: float
    kidnapped: bool = False


def drive_poses(
    route: Sequence[Sequence[float]], spec: DriveSpec, *, rng: np.random.Generator | int | None = None
) -> list[DrivePose]:
    """Poses of a drive along ``route`` (N, 2), in time order (see :class:`~models.scenario.DriveSpec`).

    The vehicle starts at arc fraction ``spec.start`` and moves forward by ``speed * interval_s``
    per frame, the speed a bounded random walk in ``spec.speed_mps``, with stops; its position
    is the route polyline point at its arc length, moved perpendicular by the lateral offset,
    and its heading the route's direction plus the heading error (both AR(1) processes, so they
    vary slowly). Between route points, as a real drive is.
    """
    rng = np.random.default_rng(rng)
    pts = np.asarray(route, dtype=np.float64)
    legs = np.hypot(*np.diff(pts, axis=0).T)
    arc = np.concatenate([[0.0], np.cumsum(legs)])
    total = float(arc[-1])
    lo, hi = spec.speed_mps
    speed = rng.uniform(lo, hi)
    s = spec.start * total
    lateral = rng.normal(0.0, spec.lateral_m)
    head_err = rng.normal(0.0, spec.heading_deg)
    stop_left = 0
    out: list[DrivePose] = []
    t = 0.0
    rho = 0.8  # AR(1) persistence of the lateral and heading errors
    while True:
        kidnapped = spec.kidnap_at is not None and len(out) == spec.kidnap_at
        if kidnapped:
            if spec.kidnap_to is not None:
                s = spec.kidnap_to * total
            else:
                away = rng.uniform(0.25, 0.75) * total
                s = (s + away) % total
        seg = int(np.clip(np.searchsorted(arc, s, side="right") - 1, 0, len(pts) - 2))
        d = (pts[seg + 1] - pts[seg]) / legs[seg]
        foot = pts[seg] + (s - arc[seg]) * d
        normal = np.array([-d[1], d[0]])
        x, y = foot + lateral * normal
        heading = math.degrees(math.atan2(d[1], d[0])) + head_err
        out.append(DrivePose(t, float(x), float(y), float(heading), float(s), kidnapped))
        if spec.frames is not None and len(out) >= spec.frames:
            break
        # the next frame
        t += spec.interval_s
        if stop_left > 0:
            stop_left -= 1
        elif rng.random() < spec.p_stop:
            stop_left = int(rng.integers(1, spec.stop_frames + 1)) - 1
        else:
            speed = float(np.clip(speed + spec.speed_change * (hi - lo) * rng.normal(), lo, hi))
            s += speed * spec.interval_s
        if s > total:
            if spec.frames is None:
                break
            s = total
        lateral = rho * lateral + math.sqrt(1 - rho**2) * rng.normal(0.0, spec.lateral_m)
        head_err = rho * head_err + math.sqrt(1 - rho**2) * rng.normal(0.0, spec.heading_deg)
    return out


def focal_px(size_px: int, fov_deg: float) -> float:
    """Pinhole focal length in pixels of ``size_px`` pixels spanning a field of view of ``fov_deg``."""
    return (size_px / 2) / math.tan(math.radians(fov_deg) / 2)


@dataclass(frozen=True)
class FrameFit:
    """How a camera frame of another size or field of view was mapped onto the scenario camera.

    ``scale`` is (rows, cols): camera pixels per frame pixel (the focal lengths' ratio);
    ``coverage`` is (rows, cols): the fraction of the camera's image height and width the frame
    sees (1.0: all of it, the rest is cropped away; less: the rest was padded);
    ``valid_cols`` the [first, last) camera columns the frame sees.
    """

    scale: tuple[float, float]
    coverage: tuple[float, float]
    valid_cols: tuple[int, int]

    @property
    def padded(self) -> bool:
        """True when the frame sees less than the camera in some direction (part of it padded)."""
        return min(self.coverage) < 1.0 - 1e-6

    @property
    def columns(self) -> tuple[int, int] | None:
        """:attr:`valid_cols` when the frame sees less than the camera's width (some columns
        padded: :attr:`SensorFrame.columns`), else None (every column is the scene's)."""
        return self.valid_cols if self.coverage[1] < 1.0 - 1e-6 else None


def fit_to_camera(
    image: np.ndarray,
    *,
    width: int,
    height: int,
    fov_y_deg: float,
    frame_fov_y_deg: float | None = None,
    frame_fov_x_deg: float | None = None,
) -> tuple[np.ndarray, FrameFit]:
    """Map a camera frame ``image`` (H, W, C), indexed (row, col), onto the scenario camera's
    ``(height, width)`` pixels of vertical field ``fov_y_deg``, keeping the geometry.

    The frame is a pinhole image centred on the optical axis with vertical field
    ``frame_fov_y_deg`` (default: the camera's, the same lens) and horizontal field
    ``frame_fov_x_deg`` (default: from the vertical one with square pixels). Each axis is
    scaled by the ratio of the focal lengths (``camera f / frame f``), the frame's centre put
    on the camera's; what lies outside the camera's view is cropped away, and where the frame
    sees less than the camera the border pixels are replicated outwards (so the frame's edge
    makes no false edge for the edge-based memory; :attr:`FrameFit.valid_cols` says which
    columns are real, for the skyline). A frame of the camera's aspect ratio and field of
    view is only resized, as before.

    Returns the mapped image, shape (height, width, C), of the input's dtype, and the
    :class:`FrameFit`.
    """
    h, w = image.shape[:2]
    sy, sx = _scales(
        w, h, height=height, fov_y_deg=fov_y_deg, frame_fov_y_deg=frame_fov_y_deg, frame_fov_x_deg=frame_fov_x_deg
    )
    # resize to about the final scale first (anti-aliased when shrinking), then place it exactly
    w1, h1 = max(1, int(round(w * sx))), max(1, int(round(h * sy)))
    if (h1, w1) != (h, w):
        shrinking = w1 < w and h1 < h
        image = cv2.resize(image, (w1, h1), interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
    # pixel edges: camera x + 0.5 = width / 2 + sx * (frame x + 0.5 - w / 2), frame x + 0.5 = (x1 + 0.5) * w / w1
    ax, ay = sx * w / w1, sy * h / h1
    bx = width / 2 - 0.5 + 0.5 * ax - sx * w / 2
    by = height / 2 - 0.5 + 0.5 * ay - sy * h / 2
    if (h1, w1) == (height, width) and abs(ax - 1) < 1e-9 and abs(ay - 1) < 1e-9 and abs(bx) < 1e-6 and abs(by) < 1e-6:
        out = image
    else:
        matrix = np.array([[ax, 0.0, bx], [0.0, ay, by]])
        out = cv2.warpAffine(image, matrix, (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if out.ndim < image.ndim:  # cv2 drops a single channel
            out = out[..., None]
    half_w = sx * w / 2
    first = max(0, int(math.ceil(width / 2 - half_w - 1e-6)))
    last = min(width, int(math.floor(width / 2 + half_w + 1e-6)))
    fit = FrameFit((sy, sx), (min(1.0, sy * h / height), min(1.0, sx * w / width)), (first, last))
    return np.ascontiguousarray(out), fit


def _scales(
    w: int,
    h: int,
    *,
    height: int,
    fov_y_deg: float,
    frame_fov_y_deg: float | None,
    frame_fov_x_deg: float | None,
) -> tuple[float, float]:
    """(rows, cols) camera pixels per pixel of a (h, w) frame: the focal lengths' ratio."""
    f_cam = focal_px(height, fov_y_deg)
    if frame_fov_y_deg is None and frame_fov_x_deg is None:
        frame_fov_y_deg = fov_y_deg
    fy = focal_px(h, frame_fov_y_deg) if frame_fov_y_deg is not None else None
    fx = focal_px(w, frame_fov_x_deg) if frame_fov_x_deg is not None else None
    fy = fy if fy is not None else fx
    fx = fx if fx is not None else fy
    assert fx is not None and fy is not None
    return f_cam / fy, f_cam / fx


#: a camera frame must see at least this fraction of the camera's width and of its height
MIN_COVERAGE = 0.5


def _to_rgb8(data: np.ndarray, path: Path) -> np.ndarray:
    """A decoded image (gray, gray + alpha, BGR, BGRA; 8 or 16 bit or float) as (H, W, 3) uint8 RGB."""
    if data.ndim == 3 and data.shape[2] not in (1, 2, 3, 4):
        raise InputError(path, f"an image of {data.shape[2]} channels: gray, RGB or RGBA expected")
    if data.ndim == 3 and data.shape[2] in (2, 4):  # the alpha is dropped (before any scaling)
        data = data[..., : data.shape[2] - 1]
    if data.ndim == 3 and data.shape[2] == 1:
        data = data[..., 0]
    if data.dtype != np.uint8:
        # 16-bit (often 10 or 12 bits of data in 16) or float: scaled by the image's brightest
        # values (a gain: black stays black, colours keep their ratios; the memory's patterns and
        # the skyline's class models do not depend on a gain), the top 0.1 % clipped so that a
        # few hot pixels do not darken the rest; negative floats from their minimum
        values = data.astype(np.float64)
        finite = np.isfinite(values)
        if not finite.any():
            raise InputError(path, "the image holds no finite pixel value")
        sample = values[finite][:: max(1, int(finite.sum()) // 1_000_000)]
        lo, hi = float(sample.min()), float(np.percentile(sample, 99.9))
        if hi <= max(lo, 0.0):
            hi = float(values[finite].max())
        lo = min(float(values[finite].min()), 0.0)
        values = np.where(finite, values, lo)
        scaled = (values - lo) * (255.0 / (hi - lo)) if hi > lo else np.zeros_like(values)
        data = np.clip(scaled + 0.5, 0, 255).astype(np.uint8)
    data = np.ascontiguousarray(data)
    if data.ndim == 2:
        return cv2.cvtColor(data, cv2.COLOR_GRAY2RGB)
    return cv2.cvtColor(data, cv2.COLOR_BGR2RGB)


def read_image(path: str | Path, *, reduce: Callable[[int, int], int] | None = None) -> np.ndarray:
    """Decode an image file (PNG, JPEG, TIFF, BMP, WebP ...: what OpenCV reads) as (H, W, 3) uint8 RGB.

    Gray, gray + alpha, RGBA (the alpha is dropped) and palette images become RGB; 16-bit and
    float images are scaled so that their brightest values are 255 (a gain, which neither the
    memory nor the skyline depends on; the top 0.1 % clipped, so hot pixels do not darken the
    image; 12 bits of data in a 16-bit file keep their detail). A JPEG's EXIF
    orientation is applied (the image as a viewer shows it). Raises
    :class:`~models.errors.InputError` naming the file when it is missing, unreadable, truncated
    or smaller than :data:`~models.scenario.MIN_IMAGE_PX` on a side.

    ``reduce(width, height)`` (the image's size as shown) may return 2, 4 or 8: a JPEG is then
    decoded at that fraction of its size (libjpeg's DCT scaling, several times faster than a
    full decode of a large photo), for a caller that shrinks it much more anyway.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "camera image not found")
    try:
        raw = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise InputError(path, f"cannot read the camera image: {exc.strerror or exc}") from None
    if raw.size == 0:
        raise InputError(path, "not a readable image: the file is empty")
    _check_complete(raw, path)
    # IMREAD_UNCHANGED keeps 16 bits and alpha but ignores EXIF orientation: apply it below
    flags, size = cv2.IMREAD_UNCHANGED, None
    jpeg = raw[:2].tobytes() == b"\xff\xd8"
    orientation = _exif_orientation(raw[:65536].tobytes()) if jpeg else 1
    if reduce is not None and jpeg:
        size = _jpeg_size(raw)
        if size is not None:
            shown = size[::-1] if orientation >= 5 else size
            factor = reduce(*shown) if min(size) >= 8 * MIN_IMAGE_PX else 1
            if factor in _REDUCED:
                flags = _REDUCED[factor] | cv2.IMREAD_IGNORE_ORIENTATION
    data = cv2.imdecode(raw, flags)
    if data is None or data.size == 0:
        raise InputError(path, "not a readable image (PNG, JPEG or TIFF expected)")
    if min(data.shape[:2]) < MIN_IMAGE_PX:
        raise InputError(
            path, f"image is {data.shape[1]}x{data.shape[0]} pixels; at least {MIN_IMAGE_PX}x{MIN_IMAGE_PX} needed"
        )
    rgb = _to_rgb8(data, path)
    return np.ascontiguousarray(_oriented(rgb, orientation))


_REDUCED = {2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4, 8: cv2.IMREAD_REDUCED_COLOR_8}


def _jpeg_size(raw: np.ndarray) -> tuple[int, int] | None:
    """(width, height) of a JPEG as stored, from its start-of-frame marker; None when not found."""
    data = raw[: 1 << 20].tobytes()
    at = 2
    while at + 9 < len(data):
        if data[at] != 0xFF:
            return None
        marker = data[at + 1]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            at += 2
            continue
        length = int.from_bytes(data[at + 2 : at + 4], "big")
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            h = int.from_bytes(data[at + 5 : at + 7], "big")
            w = int.from_bytes(data[at + 7 : at + 9], "big")
            return (w, h) if w > 0 and h > 0 else None
        at += 2 + length
    return None


def _reduction(scale: float) -> int:
    """The largest JPEG decode reduction (1, 2, 4, 8) keeping at least twice the pixels a
    resize by ``scale`` (target pixels per image pixel) needs."""
    for factor in (8, 4, 2):
        if 2.0 * scale * factor <= 1.0:
            return factor
    return 1


def _check_complete(raw: np.ndarray, path: Path) -> None:
    """Refuse a PNG or JPEG cut short (OpenCV decodes a cut JPEG with grey rows and a warning only).

    A PNG must hold its IEND chunk; a JPEG its end-of-image marker after the start of its scan
    (a marker there cannot be data, which stuffs every 0xFF; the markers before the scan are
    skipped, since an EXIF thumbnail carries an end-of-image marker of its own). Data after the
    end (a phone's trailer, a motion photo's video) is allowed."""
    data = raw.tobytes()
    if data.startswith(b"\x89PNG\r\n\x1a\n") and data.rfind(b"IEND") < 0:
        raise InputError(path, "the PNG file is truncated or damaged (no IEND chunk)")
    if data.startswith(b"\xff\xd8"):
        scan = _jpeg_scan_start(data)
        if scan is None or data.find(b"\xff\xd9", scan) < 0:
            raise InputError(path, "the JPEG file is truncated or damaged (no end-of-image marker after its scan)")


def _jpeg_scan_start(data: bytes) -> int | None:
    """Offset of a JPEG's first start-of-scan segment's data, None when the markers end before it."""
    at = 2
    while at + 4 <= len(data):
        if data[at] != 0xFF:
            return None
        marker = data[at + 1]
        if marker == 0xFF:  # fill byte
            at += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            at += 2
            continue
        length = int.from_bytes(data[at + 2 : at + 4], "big")
        if marker == 0xDA:
            return at + 2 + length
        at += 2 + length
    return None


def _oriented(rgb: np.ndarray, orientation: int) -> np.ndarray:
    """Rotate/flip an image's pixels as an EXIF orientation (1..8) says (1: as stored)."""
    ops = {
        2: lambda a: a[:, ::-1],
        3: lambda a: a[::-1, ::-1],
        4: lambda a: a[::-1],
        5: lambda a: np.swapaxes(a, 0, 1),
        6: lambda a: np.swapaxes(a, 0, 1)[:, ::-1],
        7: lambda a: np.swapaxes(a, 0, 1)[::-1, ::-1],
        8: lambda a: np.swapaxes(a, 0, 1)[::-1],
    }
    op = ops.get(orientation)
    return rgb if op is None else op(rgb)


def _exif_orientation(head: bytes) -> int:
    """The EXIF orientation (1..8) of a JPEG from its first bytes, 1 when it has none."""
    import struct

    at = head.find(b"Exif\x00\x00")
    if at < 0:
        return 1
    tiff = head[at + 6 :]
    if len(tiff) < 8 or tiff[:2] not in (b"II", b"MM"):
        return 1
    order = "<" if tiff[:2] == b"II" else ">"
    try:
        ifd = struct.unpack_from(order + "I", tiff, 4)[0]
        count = struct.unpack_from(order + "H", tiff, ifd)[0]
        for k in range(count):
            tag, kind, _, value = struct.unpack_from(order + "HHI4s", tiff, ifd + 2 + 12 * k)
            if tag == 0x0112:
                v = struct.unpack_from(order + ("H" if kind == 3 else "I"), value)[0]
                return int(v) if 1 <= v <= 8 else 1
    except struct.error:
        return 1
    return 1


def load_frame_image(
    path: str | Path,
    *,
    width: int,
    height: int,
    fov_y_deg: float | None = None,
    frame_fov_y_deg: float | None = None,
    frame_fov_x_deg: float | None = None,
) -> np.ndarray:
    """Read a camera image (see :func:`read_image`), any size, as ``(height, width, 3)`` uint8 RGB.

    With ``fov_y_deg`` (the scenario camera's vertical field of view) the frame is mapped onto
    the camera's field of view by :func:`fit_to_camera` (``frame_fov_y_deg`` / ``frame_fov_x_deg``
    the frame's own, default the camera's lens), so that another aspect ratio is cropped or
    padded rather than squeezed; a frame that sees less than :data:`MIN_COVERAGE` of the
    camera's width or height is refused. Without it the image is resized to the camera size
    (its aspect ratio not kept). Raises :class:`~models.errors.InputError` naming the file.
    """
    return load_frame(
        path,
        width=width,
        height=height,
        fov_y_deg=fov_y_deg,
        frame_fov_y_deg=frame_fov_y_deg,
        frame_fov_x_deg=frame_fov_x_deg,
    )[0]


def load_frame(
    path: str | Path,
    *,
    width: int,
    height: int,
    fov_y_deg: float | None = None,
    frame_fov_y_deg: float | None = None,
    frame_fov_x_deg: float | None = None,
) -> tuple[np.ndarray, FrameFit | None]:
    """:func:`load_frame_image` and its :class:`FrameFit` (None when only resized)."""
    path = Path(path)
    fovs = {"frame_fov_y_deg": frame_fov_y_deg, "frame_fov_x_deg": frame_fov_x_deg}

    shown: list[tuple[int, int]] = []  # the file's (width, height) when decoded reduced

    def reduce(w: int, h: int) -> int:
        shown.append((w, h))
        if fov_y_deg is None:
            return _reduction(max(width / w, height / h))
        return _reduction(max(_scales(w, h, height=height, fov_y_deg=fov_y_deg, **fovs)))

    rgb = read_image(path, reduce=reduce)
    if fov_y_deg is None:
        if rgb.shape[:2] != (height, width):
            shrinking = rgb.shape[0] > height
            rgb = cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
        return np.ascontiguousarray(rgb), None
    w, h = shown[0] if shown else (rgb.shape[1], rgb.shape[0])
    try:
        out, fit = fit_to_camera(
            rgb,
            width=width,
            height=height,
            fov_y_deg=fov_y_deg,
            frame_fov_y_deg=frame_fov_y_deg,
            frame_fov_x_deg=frame_fov_x_deg,
        )
    except ValueError as exc:  # pragma: no cover - the schema bounds the fields of view
        raise InputError(path, str(exc)) from None
    rows, cols = fit.coverage
    if min(rows, cols) < MIN_COVERAGE:
        raise InputError(
            path,
            f"the image ({w}x{h} pixels) sees only {100 * cols:.0f} % of the camera's width and "
            f"{100 * rows:.0f} % of its height (at least {100 * MIN_COVERAGE:.0f} % of each needed): "
            "check sensor.fov_y_deg / sensor.fov_x_deg against camera.fov_y_deg",
        )
    if frame_fov_y_deg is None and frame_fov_x_deg is None and abs(w * height - h * width) > max(w, h, width, height):
        warn_once(
            log,
            "camera images of %dx%d pixels (aspect %.3f) against a %dx%d camera (aspect %.3f): "
            "taken with the camera's vertical field of view (%g deg) and cropped or padded; set "
            "sensor.fov_y_deg (or sensor.fov_x_deg) when the lens differs",
            w,
            h,
            w / h,
            width,
            height,
            width / height,
            fov_y_deg,
        )
    return out, fit


def frames_from_files(scenario: Scenario) -> list[SensorFrame]:
    """The scenario's ``sensor.frames``, read and mapped onto the camera (:func:`load_frame`).

    The frames' field of view is ``sensor.fov_y_deg`` / ``sensor.fov_x_deg`` (default: the
    camera's). Raises :class:`~models.errors.ScenarioError` naming the scenario, the field and
    the file."""
    cam = scenario.camera
    sensor = scenario.sensor
    frames = []
    for i, spec in enumerate((sensor.frames if sensor else None) or []):
        assert sensor is not None
        try:
            image, fit = load_frame(
                spec.image,
                width=cam.width,
                height=cam.height,
                fov_y_deg=cam.fov_y_deg,
                frame_fov_y_deg=sensor.fov_y_deg,
                frame_fov_x_deg=sensor.fov_x_deg,
            )
        except InputError as err:  # name the scenario and the field too (as the pre-run check does)
            raise ScenarioError(scenario.path, f"sensor.frames[{i}].image", str(err)) from None
        truth = None if spec.truth is None else (spec.truth.x, spec.truth.y, spec.truth.heading_deg)
        frames.append(SensorFrame(i, image, truth, str(spec.image), spec.time, None if fit is None else fit.columns))
    return frames


def degrade(
    image: np.ndarray,
    *,
    depth: np.ndarray | None = None,
    spec: SimulateSpec,
    rng: np.random.Generator | int | None = None,
) -> np.ndarray:
    """Apply a real camera's photometric differences to a rendered image.

    Parameters
    ----------
    image : ndarray of shape (H, W, 3), uint8
    depth : ndarray of shape (H, W), optional
        Metres along the view axis, 0 for sky; haze grows with it. Without it, haze is uniform.
    spec : SimulateSpec
        Strengths: ``texture`` (fine multiplicative albedo noise on surfaces, not on the sky), ``haze`` (blend to a
        bright gray with distance), ``gain`` and ``gamma`` (drawn in ``1 ± strength`` and
        ``exp(± strength)``), ``blur`` (Gaussian sigma, pixels), ``noise`` (gray levels sigma).
    rng : Generator, int or None

    Returns
    -------
    ndarray of shape (H, W, 3), uint8
    """
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must have shape (H, W, 3), not {image.shape}")
    rng = np.random.default_rng(rng)
    h, w = image.shape[:2]
    img: np.ndarray = image.astype(np.float32) / 255.0
    if spec.texture > 0:
        # surface albedo variation (grass, soil, walls): fine-grained, on surfaces only, not the sky
        field: np.ndarray = rng.standard_normal((max(2, h // 4), max(2, w // 4))).astype(np.float32)
        field = cv2.resize(field, (w, h), interpolation=cv2.INTER_CUBIC)
        field = cv2.GaussianBlur(field, (0, 0), 1.0)
        field = field / max(float(field.std()), 1e-6)
        surface = np.ones((h, w), np.float32) if depth is None else (np.asarray(depth) > 0).astype(np.float32)
        img *= np.clip(1.0 + spec.texture * 0.25 * field * surface, 0.5, 1.5)[..., None]
    if spec.haze > 0:
        amount: np.ndarray
        if depth is None:
            amount = np.full((h, w), spec.haze, np.float32)
        else:
            d = np.asarray(depth, np.float32)
            amount = spec.haze * np.where(d > 0, 1.0 - np.exp(-d / 800.0), 1.0)
        veil = np.float32(0.8 + 0.1 * rng.uniform(-1, 1))
        img = img * (1.0 - amount[..., None]) + veil * amount[..., None]
    gain = 1.0 + spec.gain * rng.uniform(-1, 1)
    gamma = math.exp(spec.gamma * rng.uniform(-1, 1))
    img = np.clip(img * gain, 0.0, 1.0) ** gamma
    if spec.blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), spec.blur)
    out = img * 255.0
    if spec.noise > 0:
        out = out + rng.normal(0.0, spec.noise, out.shape).astype(np.float32)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def simulate_frames(
    scenario: Scenario,
    emulator,
    poses: Sequence,
    *,
    spec: SimulateSpec | None = None,
    rng: np.random.Generator | int | None = None,
) -> list[SensorFrame]:
    """Simulated camera frames along the route: :func:`iter_simulated_frames`, as a list."""
    return list(iter_simulated_frames(scenario, emulator, poses, spec=spec, rng=rng))


def iter_simulated_frames(
    scenario: Scenario,
    emulator,
    poses: Sequence,
    *,
    spec: SimulateSpec | None = None,
    rng: np.random.Generator | int | None = None,
) -> Iterator[SensorFrame]:
    """Simulated camera frames along the route, each rendered as it is asked for (the same frames
    in the same order as all at once: the random draws are made in the same order).

    For every ``spec.stride``-th route point ``i`` (pose ``poses[i]``), ``spec.per_point`` frames are taken at a
    position advanced by a uniform fraction in ``[0, spec.advance)`` of the leg towards point
    ``i + 1`` (the last point advances along its heading by the previous leg's length), displaced
    by Gaussian jitter of ``spec.jitter_m`` metres per axis, with the heading off by Gaussian
    ``spec.jitter_deg`` degrees; the emulator renders it under varied lighting, then
    :func:`degrade` applies the photometric differences. ``truth`` holds the pose.

    With ``spec.drive``, the frames are a drive instead (:func:`drive_poses`), in time order
    with their ``time``.
    """
    spec = spec or (scenario.sensor.simulate if scenario.sensor else None)
    if spec is None:
        raise ValueError("spec must be given when the scenario has no sensor.simulate block")
    if rng is None:
        rng = spec.seed if spec.seed is not None else scenario.seed
    rng = np.random.default_rng(rng)
    if spec.drive is not None:
        route = [(p.x, p.y) for p in poses]
        drive = drive_poses(route, spec.drive, rng=rng)  # every pose first: its draws come first
        for k, dp in enumerate(drive):
            yield _render_frame(emulator, k, dp.x, dp.y, dp.heading_deg, spec, rng, dp.time)
        log.info("simulated a drive of %d camera frames for scenario %s", len(drive), scenario.name)
        return
    made = 0
    n = len(poses)
    for i, pose in enumerate(poses):
        if i % spec.stride:
            continue
        if i + 1 < n:
            leg = np.array([poses[i + 1].x - pose.x, poses[i + 1].y - pose.y])
        else:
            back = math.hypot(pose.x - poses[i - 1].x, pose.y - poses[i - 1].y) if n > 1 else 0.0
            th = math.radians(pose.heading_deg)
            leg = back * np.array([math.cos(th), math.sin(th)])
        for _ in range(spec.per_point):
            u = rng.uniform(0.0, spec.advance) if spec.advance > 0 else 0.0
            x, y = np.array([pose.x, pose.y]) + u * leg + rng.normal(0.0, spec.jitter_m, 2)
            heading = pose.heading_deg + rng.normal(0.0, spec.jitter_deg)
            yield _render_frame(emulator, made, float(x), float(y), float(heading), spec, rng)
            made += 1
    log.info("simulated %d camera frames for scenario %s", made, scenario.name)


def _render_frame(
    emulator,
    index: int,
    x: float,
    y: float,
    heading: float,
    spec: SimulateSpec,
    rng: np.random.Generator,
    time: float | None = None,
) -> SensorFrame:
    """Render the camera at ``(x, y, heading)`` under drawn lighting and degrade it."""
    true_pose = emulator.pose_at(x, y, heading)
    intensity = 1.0 + spec.lighting * rng.uniform(-1, 1)
    az = rng.uniform(0, 2 * math.pi)
    el = math.radians(35.0 + 20.0 * spec.lighting * rng.uniform(-1, 1))
    direction = (math.cos(az) * math.cos(el), math.sin(az) * math.cos(el), -math.sin(el))
    view = emulator.render(true_pose, light_intensity=intensity, light_direction=direction)
    image = degrade(view.image, depth=view.depth, spec=spec, rng=rng)
    return SensorFrame(index, image, (x, y, heading), "simulated", time)
