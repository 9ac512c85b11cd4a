"""Labelled detector questions for calibration (bench/tuning/calibrate_detectors.py) and for the
ROC benchmark (bench/detectors.py): camera frames with pose errors, the questions the scheduler
would ask about them, and whether the landmark is truly there.

A question is (camera frame, candidate viewframe, landmark): the candidates are the best
``candidates`` viewframes of the real associative ranking of the frame (the scheduler's own
candidate set, so the negatives are the look-alike places it must tell apart), the landmarks
those of at least ``min_pixels`` pixels in the candidate. The label comes from the sensor
simulation, never from the detector: the landmark's pixels in the mask rendered at the frame's
true pose, counted inside the candidate's silhouette box grown by the alignment search.
``label = 1`` when they are at least ``POSITIVE_FRACTION`` of the candidate's pixels, ``0``
when at most ``NEGATIVE_FRACTION``; in between (a landmark partly hidden, or half out of the
image) the question is ambiguous and left out, and counted. ``label_kind`` is the same count
over every landmark of the same kind: whether *a* landmark like L stands where the candidate
shows L (another house in the house's place is a look-alike no appearance detector can tell
apart; ``label`` counts it a negative, ``label_kind`` a positive).

Images (row, col); world (x, y, z) metres.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
# loaded by file from bench/ and bench/tuning/ scripts: the repository root must be importable
if str(Path(__file__).resolve().parents[1]) not in sys.path:
    sys.path.append(str(Path(__file__).resolve().parents[1]))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from bench.evalset import one_view_a_point  # noqa: E402
from models.camera_emulator import CameraEmulator, Pose  # noqa: E402
from models.detectors import LR_FEATURES, CandidateView, DetectorRegistry  # noqa: E402
from models.index import ViewframeIndex  # noqa: E402
from models.scenario import Scenario, SimulateSpec, load_scenario  # noqa: E402
from models.sensor import degrade  # noqa: E402
from models.world import World  # noqa: E402

POSITIVE_FRACTION = 0.3
NEGATIVE_FRACTION = 0.05


def _roll(image: np.ndarray, deg: float, *, nearest: bool) -> np.ndarray:
    """Rotate an image about its centre by ``deg`` (camera roll), edges replicated."""
    h, w = image.shape[:2]
    m = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), deg, 1.0)
    flags = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    return cv2.warpAffine(image, m, (w, h), flags=flags, borderMode=cv2.BORDER_REPLICATE)


def posed_frames(
    cam: CameraEmulator,
    poses: list[Pose],
    *,
    rng: np.random.Generator,
    spec: SimulateSpec,
    heading_deg: float = 5.0,
    pitch_deg: float = 2.0,
    roll_deg: float = 2.0,
    per_point: int = 1,
) -> list[dict]:
    """Camera frames near every route point with pose errors drawn uniformly within
    ``±heading_deg``, ``±pitch_deg`` and ``±roll_deg`` (roll applied as an image rotation), the
    position advanced along the leg and jittered as ``spec`` says, photometry degraded by
    :func:`models.sensor.degrade`. Each frame: ``image``, ``mask`` (landmark indices at the true
    pose, rolled alike), ``pose``."""
    out = []
    n = len(poses)
    for i, p in enumerate(poses):
        nxt = poses[min(i + 1, n - 1)] if i + 1 < n else None
        leg = np.array([nxt.x - p.x, nxt.y - p.y]) if nxt is not None else np.zeros(2)
        for _ in range(per_point):
            x, y = np.array([p.x, p.y]) + rng.uniform(0, spec.advance) * leg + rng.normal(0, spec.jitter_m, 2)
            heading = p.heading_deg + rng.uniform(-heading_deg, heading_deg)
            pitch = p.pitch_deg + rng.uniform(-pitch_deg, pitch_deg)
            roll = rng.uniform(-roll_deg, roll_deg)
            pose = cam.pose_at(float(x), float(y), float(heading), pitch_deg=float(pitch))
            az, el = rng.uniform(0, 2 * math.pi), math.radians(rng.uniform(25, 55))
            light = (math.cos(az) * math.cos(el), math.sin(az) * math.cos(el), -math.sin(el))
            view = cam.render(pose, light_intensity=1.0 + spec.lighting * rng.uniform(-1, 1), light_direction=light)
            image = degrade(view.image, depth=view.depth, spec=spec, rng=rng)
            out.append(
                {"image": _roll(image, roll, nearest=False), "mask": _roll(view.mask, roll, nearest=True), "pose": pose}
            )
    return out


def scenario_questions(
    scenario: Scenario,
    *,
    seed: int,
    candidates: int = 8,
    min_pixels: int = 60,
    align_px: tuple[int, int],
    **pose_errors,
) -> dict:
    """Render the viewframes and posed frames of ``scenario`` (frames drawn with ``seed``, by the
    viewframes' own renderer) and list the questions (module docstring); see :func:`questions`."""
    with World(scenario) as world:
        vfs = world.viewframes
        frames = posed_frames(
            world.emulator,
            world.poses,
            rng=np.random.default_rng(seed),
            spec=scenario.sensor.simulate or SimulateSpec(),
            **pose_errors,
        )
        env = world.environment
    return questions(scenario, env, vfs, frames, candidates=candidates, min_pixels=min_pixels, align_px=align_px)


def case_questions(case, *, candidates: int = 8, min_pixels: int = 60, align_px: tuple[int, int]) -> dict:
    """The questions of an evaluation-set case (bench/evalset): its camera frames come from another
    renderer (a ray caster) at other sizes, read and resized to the scenario camera as ``mapinterp
    run`` does; the truth mask is rendered by the camera emulator at each frame's true pose
    (position, eye height, heading, pitch; roll as an image rotation)."""
    frames = []
    with World(one_view_a_point(load_scenario(case.scenario_path))) as world:
        scenario, vfs, env = world.scenario, world.viewframes, world.environment
        for img, ef in zip(world.sensor_frames, case.frames):
            pose = Pose(ef.x, ef.y, ef.z, ef.heading_deg, ef.pitch_deg)
            mask = world.emulator.render(pose).mask
            frames.append({"image": img.image, "mask": _roll(mask, ef.roll_deg, nearest=True), "pose": pose})
    return questions(scenario, env, vfs, frames, candidates=candidates, min_pixels=min_pixels, align_px=align_px)


def questions(
    scenario: Scenario, env, vfs, frames: list[dict], *, candidates: int, min_pixels: int, align_px: tuple[int, int]
) -> dict:
    """The labelled questions about ``frames`` (``image``, ``mask`` at the true pose, ``pose``)
    against the viewframes ``vfs``. Returns ``{"viewframes", "frames", "questions", "ambiguous",
    "rankings", "truth", "landmarks"}`` (``truth``: each frame's nearest route point, the results'
    criterion of a correct frame)."""
    index = ViewframeIndex(scenario.memory)
    index.add([v.image for v in vfs], [v.index for v in vfs])
    truth = [int(np.argmin([math.hypot(v.pose.x - f["pose"].x, v.pose.y - f["pose"].y) for v in vfs])) for f in frames]
    out, ambiguous, rankings = [], 0, []
    sr, sc = align_px
    for fi, fr in enumerate(frames):
        ranking = index.rank(fr["image"])
        rankings.append(ranking)
        for k in [int(v) for v in ranking.viewframes[:candidates]]:
            vf = vfs[k]
            for li in np.unique(vf.mask[vf.mask >= 0]):
                sil = vf.mask == li
                px = int(sil.sum())
                if px < min_pixels:
                    continue
                rows, cols = np.nonzero(sil)
                r0, r1 = max(0, rows.min() - sr), rows.max() + sr + 1
                c0, c1 = max(0, cols.min() - sc), cols.max() + sc + 1
                window = fr["mask"][r0:r1, c0:c1]
                label = _label(int((window == li).sum()), px)
                lm = env.landmarks[int(li)]
                same_kind = [j for j, o in enumerate(env.landmarks) if o.kind == lm.kind]
                label_kind = _label(int(np.isin(window, same_kind).sum()), px)
                if label is None:
                    ambiguous += 1
                    continue
                out.append(
                    {
                        "frame": fi,
                        "viewframe": k,
                        "landmark": lm.id,
                        "index": int(li),
                        "kind": lm.kind,
                        "pixels": px,
                        "label": label,
                        "label_kind": label_kind,
                        "nearest": truth[fi],
                    }
                )
    return {
        "viewframes": vfs,
        "frames": frames,
        "questions": out,
        "ambiguous": ambiguous,
        "rankings": rankings,
        "truth": truth,
        "landmarks": env.landmarks,
    }


def _label(near: int, pixels: int) -> int | None:
    if near >= POSITIVE_FRACTION * pixels:
        return 1
    if near <= NEGATIVE_FRACTION * pixels:
        return 0
    return None


def evidence(data: dict, registry: DetectorRegistry) -> list[dict]:
    """Each question of :func:`questions` with the detector's evidence (the features of
    :data:`models.detectors.LR_FEATURES`, :meth:`models.detectors.EdgeTemplateDetector.evidence`)
    and the three-way ``present`` of the score thresholds."""
    out = []
    for q in data["questions"]:
        vf = data["viewframes"][q["viewframe"]]
        view = CandidateView.from_mask(vf.image, vf.mask, q["index"], background=vf.background)
        det = registry.for_kind(q["kind"])
        image = data["frames"][q["frame"]]["image"]
        ev = det.evidence(image, view=view)
        d = det.detect(image, view=view)
        if ev is None:
            continue
        out.append({**q, **dict(zip(LR_FEATURES, ev)), "present": d.present})
    return out


def roc_auc(scores, labels) -> float | None:
    """Area under the ROC curve (Mann-Whitney), ties counted half; ``None`` without both classes."""
    s = np.asarray(scores, float)
    y = np.asarray(labels, int)
    pos, neg = s[y == 1], s[y == 0]
    if len(pos) == 0 or len(neg) == 0:
        return None
    order = np.argsort(s, kind="mergesort")
    ranks = np.empty(len(s))
    sorted_s = s[order]
    i = 0
    while i < len(s):
        j = i
        while j + 1 < len(s) and sorted_s[j + 1] == sorted_s[i]:
            j += 1
        ranks[order[i : j + 1]] = (i + j) / 2 + 1
        i = j + 1
    return float((ranks[y == 1].sum() - len(pos) * (len(pos) + 1) / 2) / (len(pos) * len(neg)))
