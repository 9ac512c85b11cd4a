"""Camera images as users hand them over: other formats, sizes, aspect ratios, broken files.

Every case is a real file written into ``tmp_path`` and read as a scenario's frames are read.
Images are (H, W, 3) uint8 RGB indexed (row, col).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from models.errors import InputError, ScenarioError
from models.scenario import scenario_from_dict
from models.sensor import MIN_COVERAGE, fit_to_camera, frames_from_files, load_frame, load_frame_image, read_image

W, H = 160, 120
SKY, GROUND, RED = (120, 170, 230), (60, 120, 40), (200, 30, 30)


def _scene(h: int = H, w: int = W) -> np.ndarray:
    """Sky over ground, a red block below-left of the centre: orientation and colours show."""
    img = np.zeros((h, w, 3), np.uint8)
    img[: h // 2] = SKY
    img[h // 2 :] = GROUND
    img[int(h * 0.6) : int(h * 0.75), int(w * 0.12) : int(w * 0.25)] = RED
    return img


def _write_bgr(path: Path, rgb: np.ndarray) -> Path:
    assert cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]))
    return path


def _close(a, b, tol: float = 3.0) -> bool:
    return bool(np.all(np.abs(np.asarray(a, int) - np.asarray(b, int)) <= tol))


# -- formats -------------------------------------------------------------------------------------


@pytest.mark.parametrize("ext", [".png", ".tif"])
def test_16_bit_colour_keeps_its_colours(tmp_path, ext):
    path = _write_bgr(tmp_path / f"f16{ext}", _scene().astype(np.uint16) * 257)
    img = load_frame_image(path, width=W, height=H)
    assert img.dtype == np.uint8 and img.shape == (H, W, 3)
    # scaled by the brightest value (230 * 257): a gain, colour ratios kept
    gain = 255 / 230
    assert _close(img[5, 5], np.array(SKY) * gain) and _close(img[80, 30], np.array(RED) * gain)


def test_12_bits_in_a_16_bit_file_keep_their_detail(tmp_path):
    ramp = np.linspace(0, 4095, W)[None].repeat(H, 0).astype(np.uint16)  # 12-bit data
    cv2.imwrite(str(tmp_path / "g12.png"), ramp)
    img = load_frame_image(tmp_path / "g12.png", width=W, height=H)
    assert len(np.unique(img[0, :, 0])) > 100  # not the 16 levels its upper 8 bits hold
    assert img[0, 0, 0] == 0 and img[0, -1, 0] == 255


def test_float_tiff(tmp_path):
    gray = cv2.cvtColor(_scene(), cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    cv2.imwrite(str(tmp_path / "f.tif"), gray)
    img = load_frame_image(tmp_path / "f.tif", width=W, height=H)
    assert img[5, 5, 0] > img[100, 100, 0]  # sky brighter than ground
    assert np.all(img[..., 0] == img[..., 1])


@pytest.mark.parametrize("mode", ["L", "LA", "RGBA", "P"])
def test_gray_alpha_and_palette_images(tmp_path, mode):
    scene = _scene()
    if mode == "L":
        pil = Image.fromarray(cv2.cvtColor(scene, cv2.COLOR_RGB2GRAY), "L")
    elif mode == "LA":
        pil = Image.fromarray(np.dstack([cv2.cvtColor(scene, cv2.COLOR_RGB2GRAY), np.full((H, W), 128, np.uint8)]))
    elif mode == "RGBA":
        pil = Image.fromarray(np.dstack([scene, np.full((H, W), 255, np.uint8)]), "RGBA")
    else:
        pil = Image.fromarray(scene).convert("P", palette=Image.Palette.ADAPTIVE, colors=8)
    assert pil.mode == mode
    pil.save(tmp_path / "f.png")
    img = load_frame_image(tmp_path / "f.png", width=W, height=H)
    assert img.shape == (H, W, 3)
    if mode in ("RGBA", "P"):
        assert _close(img[5, 5], SKY) and _close(img[80, 30], RED)
    else:
        gray = cv2.cvtColor(scene, cv2.COLOR_RGB2GRAY)
        assert _close(img[..., 0], gray, 1) and np.all(img[..., 0] == img[..., 2])


@pytest.mark.parametrize(
    "orientation, stored",
    [(1, lambda a: a), (3, lambda a: a[::-1, ::-1]), (6, lambda a: np.rot90(a, 1)), (8, lambda a: np.rot90(a, -1))],
)
def test_jpeg_exif_orientation_is_applied(tmp_path, orientation, stored):
    """A phone's JPEG stores the sensor's pixels and says in EXIF how to turn them: the image
    is read as a viewer shows it (sky up), not as stored."""
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(np.ascontiguousarray(stored(_scene()))).save(tmp_path / "f.jpg", exif=exif.tobytes(), quality=95)
    img = load_frame_image(tmp_path / "f.jpg", width=W, height=H)
    assert _close(img[5, 80], SKY, 8) and _close(img[110, 80], GROUND, 8)
    assert _close(img[80, 30], RED, 12)


@pytest.mark.slow
@pytest.mark.parametrize("orientation", [1, 6])
def test_a_huge_jpeg_is_decoded_reduced_to_what_the_camera_needs(tmp_path, orientation, monkeypatch):
    """A 6000 x 4000 photo (72 MB of pixels) for a 160 x 120 camera: decoded at 1/8 (libjpeg's
    DCT scaling), as fast as a small image, and the same camera image as a full decode gives."""
    import time

    import models.sensor as sensor

    decoded: list[tuple[int, tuple[int, ...]]] = []  # (flags, decoded shape) of every decode
    real = cv2.imdecode

    def spy(buf, flags):
        out = real(buf, flags)
        decoded.append((flags, out.shape))
        return out

    monkeypatch.setattr(sensor.cv2, "imdecode", spy)

    rng = np.random.default_rng(4)
    scene = cv2.resize(_scene(400, 600), (6000, 4000), interpolation=cv2.INTER_LINEAR)
    scene = cv2.GaussianBlur(scene, (0, 0), 3.0) + rng.integers(0, 6, scene.shape, dtype=np.uint8)
    stored = scene if orientation == 1 else np.ascontiguousarray(np.rot90(scene, 1))
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(stored).save(tmp_path / "big.jpg", exif=exif.tobytes(), quality=90)
    t0 = time.perf_counter()
    img, fit = load_frame(tmp_path / "big.jpg", width=W, height=H, fov_y_deg=45.0)
    elapsed = time.perf_counter() - t0
    (flags, shape), *_ = decoded
    assert flags & ~cv2.IMREAD_IGNORE_ORIENTATION == cv2.IMREAD_REDUCED_COLOR_8 and max(shape) == 750
    full = read_image(tmp_path / "big.jpg")  # no reduction
    assert full.shape == (4000, 6000, 3)
    want, _ = fit_to_camera(full, width=W, height=H, fov_y_deg=45.0)
    assert img.shape == (H, W, 3) and fit is not None
    assert np.abs(img.astype(int) - want).mean() < 1.0
    assert _close(img[5, 80], SKY, 10) and _close(img[110, 80], GROUND, 10)
    assert elapsed < 1.0  # about 0.05 s on the 2-core test machine; a full decode about 0.3 s
    # (the peak memory of a decode at 1/8 is the reduced image's: the flags above say so; this
    # process's own peak, ru_maxrss, is its whole life's and says nothing in a test suite)


def test_a_huge_png_is_read(tmp_path):
    big = cv2.resize(_scene(), (6000, 4000), interpolation=cv2.INTER_NEAREST)
    img = load_frame_image(_write_bgr(tmp_path / "big.png", big), width=W, height=H, fov_y_deg=45.0)
    assert _close(img[80, 30], RED, 3)


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda d: d[: len(d) // 2], "truncated or damaged"),
        (lambda d: d[:40], "truncated or damaged"),
        (lambda d: b"", "not a readable image: the file is empty"),
        (lambda d: b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 2, "truncated or damaged"),
        (lambda d: b"GIF89a not really", "not a readable image"),
    ],
)
@pytest.mark.parametrize("ext", [".png", ".jpg"])
def test_broken_files_are_refused_naming_the_file(tmp_path, make, message, ext):
    good = _write_bgr(tmp_path / f"good{ext}", _scene())
    bad = tmp_path / f"bad{ext}"
    bad.write_bytes(make(good.read_bytes()))
    with pytest.raises(InputError, match=message) as err:
        read_image(bad)
    assert err.value.path == bad and f"bad{ext}" in str(err.value)


def test_a_folder_or_missing_file_is_refused(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_image(tmp_path)
    with pytest.raises(InputError, match="not found"):
        read_image(tmp_path / "nope.png")


# -- other sizes and aspect ratios ---------------------------------------------------------------

CAMERA = {"width": W, "height": H, "fov_y_deg": 45.0, "eye_height": 2.0, "near": 1.0, "far": 5000.0}


def _scenario(tmp_path: Path, frames: list[dict] | None = None, **sensor):
    data = {
        "name": "aspect",
        "seed": 5,
        "terrain": {"cell_size": 10.0, "procedural": {"size": 64, "relief": 60.0, "seed": 2}},
        "landmarks": [{"id": "T1", "kind": "tower", "x": 330, "y": 310, "width": 4, "depth": 4, "height": 30}],
        "route": [[200, 300], [250, 300], [300, 320]],
        "camera": CAMERA,
        "sensor": {"frames": frames, **sensor} if frames else {"simulate": {}, **sensor},
    }
    return scenario_from_dict(data, path=tmp_path / "s.yaml")


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    """Views of the route points rendered at the camera's 4:3 size and at other sizes with the
    same vertical field of view (the same lens on another sensor): {(w, h): [image, ...]}."""
    from models.camera_emulator import CameraEmulator
    from models.environment import build_environment
    from models.viewframes import route_poses

    scenario = _scenario(tmp_path_factory.mktemp("aspect"))
    env = build_environment(scenario)
    out: dict[tuple[int, int], list[np.ndarray]] = {}
    poses = route_poses(scenario, env.terrain)
    for size in [(W, H), (1280, 720), (1920, 1080), (641, 479), (96, 72), (720, 960), (320, 240)]:
        spec = scenario.camera.model_copy(update={"width": size[0], "height": size[1]})
        with CameraEmulator(env, spec) as cam:
            out[size] = [cam.render(p).image for p in poses]
    return out


@pytest.mark.slow
@pytest.mark.parametrize("size", [(1280, 720), (1920, 1080), (641, 479), (96, 72), (320, 240)])
def test_a_frame_of_another_size_maps_onto_the_camera_view(renders, size):
    """The same lens on a 16:9 (or odd-sized) sensor: mapped onto the 4:3 camera it is the
    camera's own view, within resampling; squeezed to 4:3 (as before) it is not."""
    for image, want in zip(renders[size], renders[(W, H)]):
        got, fit = fit_to_camera(image, width=W, height=H, fov_y_deg=45.0)
        assert got.shape == (H, W, 3) and not fit.padded
        err = np.abs(got.astype(int) - want).mean()
        tol = 1.5 if min(size) < H else 0.6  # a smaller frame is upsampled: blurrier
        assert err < tol, err
        if abs(size[0] * H / (size[1] * W) - 1) > 0.05:  # another aspect ratio: the old squeeze distorts it
            squeezed = cv2.resize(image, (W, H), interpolation=cv2.INTER_AREA)
            assert np.abs(squeezed.astype(int) - want).mean() > 2 * err + 1.0


@pytest.mark.slow
def test_a_narrower_frame_is_padded_without_false_edges(renders):
    """A portrait 3:4 frame with the camera's vertical field sees 56 % of the camera's width:
    the middle columns are the camera's view, the sides replicate the frame's border columns
    (no step at the frame's edge) and FrameFit says which columns are real."""
    for image, want in zip(renders[(720, 960)], renders[(W, H)]):
        got, fit = fit_to_camera(image, width=W, height=H, fov_y_deg=45.0)
        assert fit.padded and math.isclose(fit.coverage[1], (720 / 960) / (W / H))
        a, b = fit.valid_cols
        assert b - a == pytest.approx(0.5625 * W, abs=1.5)
        assert abs((a + b) / 2 - W / 2) <= 1
        assert np.abs(got[:, a + 1 : b - 1].astype(int) - want[:, a + 1 : b - 1]).mean() < 0.6
        # replicated: each padded row is constant, so the edge image has no vertical step there
        assert np.all(got[:, : a - 1] == got[:, a - 1 : a]) and np.all(got[:, b + 1 :] == got[:, b : b + 1])


@pytest.mark.slow
def test_mapped_16_by_9_frames_rank_their_own_route_point_first(renders, tmp_path):
    from models.index import ViewframeIndex
    from models.scenario import MemorySpec

    index = ViewframeIndex(MemorySpec())
    index.add(renders[(W, H)], [0, 1, 2])
    for k, image in enumerate(renders[(1280, 720)]):
        path = _write_bgr(tmp_path / f"f{k}.png", image)
        mapped = load_frame_image(path, width=W, height=H, fov_y_deg=45.0)
        assert index.rank(mapped).top(1)[0][0] == k


def test_frames_on_file_warn_once_about_another_aspect_ratio(tmp_path, caplog, monkeypatch):
    import models.logs

    monkeypatch.setattr(models.logs, "_said", set())
    for k in range(3):
        _write_bgr(tmp_path / f"f{k}.png", _scene(720, 1280))
    frames = [{"image": f"f{k}.png"} for k in range(3)]
    with caplog.at_level(logging.WARNING, logger="models.sensor"):
        got = frames_from_files(_scenario(tmp_path, frames))
    assert [f.image.shape for f in got] == [(H, W, 3)] * 3
    assert caplog.text.count("camera images of 1280x720") == 1 and "sensor.fov_y_deg" in caplog.text
    caplog.clear()
    monkeypatch.setattr(models.logs, "_said", set())
    with caplog.at_level(logging.WARNING, logger="models.sensor"):
        frames_from_files(_scenario(tmp_path, frames, fov_y_deg=45.0))  # the lens named: no warning
    assert "camera images of" not in caplog.text


def test_the_frames_field_of_view_scales_them(tmp_path):
    """A frame of the camera's size but twice its focal length (a narrower lens) fills only the
    middle half of the camera's view: refused below MIN_COVERAGE, else padded."""
    half = math.degrees(2 * math.atan(math.tan(math.radians(45.0) / 2) / 2))  # f doubled
    img = _scene()
    got, fit = fit_to_camera(img, width=W, height=H, fov_y_deg=45.0, frame_fov_y_deg=half)
    assert fit.coverage == pytest.approx((0.5, 0.5)) and fit.scale == pytest.approx((0.5, 0.5))
    path = _write_bgr(tmp_path / "tele.png", img)
    out, fit = load_frame(path, width=W, height=H, fov_y_deg=45.0, frame_fov_y_deg=half)  # exactly 50 %: taken
    assert fit is not None and fit.valid_cols == (40, 120)
    narrower = math.degrees(2 * math.atan(math.tan(math.radians(45.0) / 2) / 2.5))
    with pytest.raises(InputError, match=r"tele.png.*sees only 40 % of the camera's width") as err:
        load_frame(path, width=W, height=H, fov_y_deg=45.0, frame_fov_y_deg=narrower)
    assert "sensor.fov_y_deg" in str(err.value)
    # a wider lens (fov_x given): its middle is the camera's view, enlarged; the rest cropped
    wide, fit = fit_to_camera(img, width=W, height=H, fov_y_deg=45.0, frame_fov_x_deg=90.0)
    assert not fit.padded and fit.scale == pytest.approx((1.8107, 1.8107), abs=1e-4)


def test_a_very_narrow_frame_is_refused_in_the_scenario(tmp_path):
    _write_bgr(tmp_path / "slit.png", _scene(960, 240))  # 1:4 portrait: a quarter of the camera's width
    with pytest.raises(ScenarioError, match=r"s.yaml: sensor.frames\[0\].image: .*slit.png: .*sees only 19 %"):
        frames_from_files(_scenario(tmp_path, [{"image": "slit.png"}]))


def test_fov_fields_need_frames_on_file(tmp_path):
    with pytest.raises(ScenarioError, match="sensor: .*fov_y_deg and fov_x_deg describe the images of sensor.frames"):
        _scenario(tmp_path, None, fov_y_deg=50.0)
    with pytest.raises(ScenarioError, match=r"s.yaml: sensor.fov_x_deg: must be < 180"):
        _write_bgr(tmp_path / "a.png", _scene())
        _scenario(tmp_path, [{"image": "a.png"}], fov_x_deg=180)


def test_min_coverage_is_half():
    assert MIN_COVERAGE == 0.5


@pytest.mark.slow
def test_a_padded_frame_has_no_horizon_where_it_sees_nothing(renders, tmp_path):
    """The portrait frame's columns reach the skyline: its bins outside them are NaN (the
    replicated border would otherwise draw a flat false horizon there), the ones inside
    agree with the 4:3 view's where that view has a horizon with sky above it (a degree below
    the frame's top edge or more: where the inner columns see terrain up to the top there is no
    horizon to agree on, and the extraction, which has no "no sky" answer, draws one anywhere)."""
    from models.skyline import profile_azimuths, skyline_from_image

    frames = []
    for k, image in enumerate(renders[(720, 960)]):
        _write_bgr(tmp_path / f"p{k}.png", image)
        frames.append({"image": f"p{k}.png"})
    got = frames_from_files(_scenario(tmp_path, frames, fov_y_deg=45.0))
    compared = 0
    for frame, want in zip(got, renders[(W, H)]):
        assert frame.columns is not None
        q = skyline_from_image(frame.image, fov_y_deg=45.0, columns=frame.columns)
        full = skyline_from_image(frame.image, fov_y_deg=45.0)
        ref = skyline_from_image(want, fov_y_deg=45.0)
        az = profile_azimuths(q.size)
        half = math.degrees(math.atan(math.tan(math.radians(22.5)) * 720 / 960))
        outside, inside = np.abs(az) > half + 0.5, np.abs(az) < half - 1.0
        assert np.all(np.isnan(q[outside])) and np.isfinite(full[outside]).mean() > 0.5
        # the top edge's elevation at each bin's azimuth, minus a degree
        top = np.degrees(np.arctan(np.tan(np.radians(22.5)) * np.cos(np.radians(az)))) - 1.0
        sky = inside & np.isfinite(ref) & (np.nan_to_num(ref, nan=90.0) < top)
        if sky.sum() < 0.5 * inside.sum():
            continue  # the inner columns see (almost) no sky in the 4:3 view
        ok = sky & np.isfinite(q)
        assert ok.mean() > 0.5 * sky.mean()
        assert np.median(np.abs(q[ok] - ref[ok])) < 0.5  # degrees
        compared += 1
    assert compared >= 2
    # a frame of the camera's aspect ratio is not padded: every column counts
    _write_bgr(tmp_path / "full.png", renders[(1280, 720)][0])
    assert frames_from_files(_scenario(tmp_path, [{"image": "full.png"}]))[0].columns is None


def test_16_bit_rgba_with_12_bits_of_colour(tmp_path):
    """A 16-bit RGBA PNG whose colours use 12 bits and whose alpha is opaque (65535): the gain
    comes from the colours, not from the alpha (which would leave the image nearly black)."""
    bgr = (_scene()[..., ::-1].astype(np.uint16) * 16).astype(np.uint16)  # up to 230 * 16 = 3680
    bgra = np.dstack([bgr, np.full((H, W), 65535, np.uint16)])
    assert cv2.imwrite(str(tmp_path / "f.png"), bgra)
    img = load_frame_image(tmp_path / "f.png", width=W, height=H)
    assert _close(img[5, 5], np.array(SKY) * 255 / 230) and img.max() == 255


def test_jpeg_endings_phones_write_are_accepted_and_cut_scans_refused(tmp_path):
    """Data after a JPEG's end (a phone's trailer, a motion photo's video) is no damage; a JPEG
    cut inside its scan is, even when an EXIF thumbnail before the scan ends with its own
    end-of-image marker."""
    ok, enc = cv2.imencode(".jpg", np.ascontiguousarray(_scene()[..., ::-1]))
    assert ok
    jpeg = enc.tobytes()
    (tmp_path / "trailer.jpg").write_bytes(jpeg + b"\x00" * 100 + b"SEFT" + bytes(range(256)) * 40)
    assert _close(read_image(tmp_path / "trailer.jpg")[80, 30], RED, 12)
    thumb = b"\xff\xd8" + b"thumbnail" * 10 + b"\xff\xd9"
    app1 = b"Exif\x00\x00" + thumb
    with_thumb = jpeg[:2] + b"\xff\xe1" + (len(app1) + 2).to_bytes(2, "big") + app1 + jpeg[2:]
    (tmp_path / "thumb.jpg").write_bytes(with_thumb)
    assert _close(read_image(tmp_path / "thumb.jpg")[80, 30], RED, 12)
    (tmp_path / "cut.jpg").write_bytes(with_thumb[: len(with_thumb) - 200])
    with pytest.raises(InputError, match="cut.jpg: the JPEG file is truncated or damaged"):
        read_image(tmp_path / "cut.jpg")


def test_hot_pixels_do_not_darken_a_16_bit_frame(tmp_path):
    ramp = np.linspace(0, 4095, W)[None].repeat(H, 0).astype(np.uint16)
    ramp[3, 7] = ramp[50, 90] = 65535  # two hot pixels
    cv2.imwrite(str(tmp_path / "hot.png"), ramp)
    img = load_frame_image(tmp_path / "hot.png", width=W, height=H)
    assert img[0, -1, 0] >= 250 and img[0, W // 2, 0] > 100  # not 4095 / 65535 of the range
