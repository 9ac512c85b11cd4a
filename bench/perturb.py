"""How the ranking sources hold up when the camera images look otherwise: photometric perturbations.

The judged camera images come from a renderer (or a camera) nobody here has seen: another sky,
other colours, other compression. Each perturbation below changes every camera frame of an
evaluation-set split (bench/evalset; ``tuning`` by default, so that what this finds may be acted
on) the same way, seeded per frame, and the frames are ranked as the agents rank them
(bench/tracking_data.ranked_drive: the associative memory, the skyline, their fusion by the
scheduler's rule). Sky perturbations use the frame's true horizon (the evaluation set's
``labels.npz``), so that only the sky changes.

Perturbations (:data:`PERTURBATIONS`): ``none``; ``gray`` (luminance only); ``overcast`` (a flat
light-gray sky); ``clouds`` (fractal cumulus over half the sky); ``dusk`` (a warm cast, darker);
``haze`` (35 % of a light gray over everything); ``jpeg20`` (JPEG quality 20); ``lowres`` (half
the resolution, then back); ``noise`` (Gaussian, 15 gray levels); ``sharpen`` (unsharp mask).

Reported per perturbation over all frames: ranking top-1 of the memory, of the skyline and of
the fusion, and the fusion's top-5 (the truth: the route point nearest the true position).

    python bench/perturb.py [--split tuning|heldout] [--only none clouds ...] [--json-only]

Prints JSON, then a table.
"""

from __future__ import annotations

import sys
from pathlib import Path

_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from bench.evalset import cases  # noqa: E402

sys.path.insert(0, str(_HERE))  # bench/tracking_data.py, then off the path again (bench/blackboard.py)
from tracking_data import observed, per_point, ranked_drive  # noqa: E402

sys.path.pop(0)

#: a perturbation: (image (H, W, 3) uint8, sky mask (H, W) bool, rng) -> image
Perturbation = Callable[[np.ndarray, np.ndarray, np.random.Generator], np.ndarray]


def _u8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def _fbm(shape: tuple[int, int], rng: np.random.Generator, *, octaves: int = 5) -> np.ndarray:
    """Fractal noise in [0, 1], (H, W)."""
    h, w = shape
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for o in range(octaves):
        n = max(2, 2 ** (o + 2))
        layer = rng.standard_normal((n, max(2, n * w // max(h, 1)))).astype(np.float32)
        out += amp * cv2.resize(layer, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= 0.55
    out /= total
    return (out - out.min()) / max(float(np.ptp(out)), 1e-6)


def _gray(img, sky, rng):
    g = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return np.repeat(g[:, :, None], 3, axis=2)


def _overcast(img, sky, rng):
    h, w = sky.shape
    rows = np.linspace(0.0, 1.0, h, dtype=np.float32)[:, None, None]
    flat = np.array([200.0, 202.0, 206.0], np.float32)[None, None, :] + 12.0 * rows  # lighter towards the horizon
    out = img.astype(np.float32)
    out[sky] = np.broadcast_to(flat, (h, w, 3))[sky]
    return _u8(out)


def _clouds(img, sky, rng):
    h, w = sky.shape
    cover = np.clip((_fbm((h, w), rng) - 0.45) * 4.0, 0.0, 1.0)[:, :, None]  # about half the sky
    shade = 0.75 + 0.25 * _fbm((h, w), rng)[:, :, None]
    cloud = np.array([238.0, 238.0, 242.0], np.float32) * shade
    out = img.astype(np.float32)
    mixed = (1.0 - cover) * out + cover * cloud
    out[sky] = mixed[sky]
    return _u8(out)


def _dusk(img, sky, rng):
    return _u8(img.astype(np.float32) * np.array([1.15, 0.85, 0.6], np.float32) * 0.7)


def _haze(img, sky, rng):
    return _u8(0.65 * img.astype(np.float32) + 0.35 * 210.0)


def _jpeg20(img, sky, rng):
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 20])
    assert ok
    return cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def _lowres(img, sky, rng):
    h, w = img.shape[:2]
    small = cv2.resize(img, (max(8, w // 2), max(8, h // 2)), interpolation=cv2.INTER_AREA)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def _noise(img, sky, rng):
    return _u8(img.astype(np.float32) + rng.normal(0.0, 15.0, img.shape))


def _sharpen(img, sky, rng):
    blur = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 1.5)
    return _u8(img.astype(np.float32) + 1.5 * (img.astype(np.float32) - blur))


PERTURBATIONS: dict[str, Perturbation | None] = {
    "none": None,
    "gray": _gray,
    "overcast": _overcast,
    "clouds": _clouds,
    "dusk": _dusk,
    "haze": _haze,
    "jpeg20": _jpeg20,
    "lowres": _lowres,
    "noise": _noise,
    "sharpen": _sharpen,
}


def sky_masks(case_dir: Path, shape: tuple[int, int]) -> np.ndarray:
    """The true sky of each frame at ``shape`` (H, W): rows above the labelled horizon, (T, H, W) bool."""
    horizons = np.load(case_dir / "labels.npz")["horizons"].astype(np.float64)  # (T, W0) rows of the native frame
    h, w = shape
    native_w = horizons.shape[1]
    out = np.zeros((len(horizons), h, w), bool)
    cols = (np.arange(w) + 0.5) * native_w / w - 0.5
    for t, row in enumerate(horizons):
        ok = np.isfinite(row)
        if not ok.any():
            continue
        at = np.interp(cols, np.flatnonzero(ok), row[ok])
        native_h = native_w * h / w  # the native frame has the camera's aspect
        out[t] = np.arange(h)[:, None] < (at * h / native_h)[None, :]
    return out


def _transform(name: str, masks: np.ndarray, seed: int) -> Callable[[np.ndarray, int], np.ndarray] | None:
    fn = PERTURBATIONS[name]
    if fn is None:
        return None

    def apply(image: np.ndarray, i: int) -> np.ndarray:
        return fn(image, masks[i], np.random.default_rng([seed, i]))

    return apply


def _rank_of_truth(scores: np.ndarray, truth: int) -> int:
    order = np.argsort(np.nan_to_num(scores, nan=np.inf), kind="stable")
    return int(np.flatnonzero(order == truth)[0])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", choices=["tuning", "heldout"], default="tuning")
    ap.add_argument("--only", nargs="+", choices=list(PERTURBATIONS), help="these perturbations only")
    ap.add_argument("--json-only", action="store_true")
    args = ap.parse_args(argv)
    names = args.only or list(PERTURBATIONS)
    t0 = time.time()
    ranks: dict[str, dict[str, list[int]]] = {n: {"memory": [], "skyline": [], "fused": []} for n in names}
    for ci, case in enumerate(cases(args.split)):
        masks = None
        for name in names:
            if masks is None:
                first = ranked_drive(case.scenario_path)  # also the image size
                shape = (int(first["camera_hw"][0]), int(first["camera_hw"][1]))
                masks = sky_masks(case.scenario_path.parent, shape)
            d = (
                first
                if name == "none"
                else ranked_drive(case.scenario_path, transform=_transform(name, masks, 7000 + ci))
            )
            fused = observed(d, "fused", point="best")  # the scene analysis's ranking of route points
            memory = per_point(d, d["variances"], nats=False)
            skyline = None if d["skyline"] is None else per_point(d, d["skyline"], nats=False)
            for t, truth in enumerate(d["true_point"]):
                ranks[name]["memory"].append(_rank_of_truth(memory[t], truth))
                ranks[name]["skyline"].append(_rank_of_truth(skyline[t], truth) if skyline is not None else -1)
                ranks[name]["fused"].append(_rank_of_truth(fused[t], truth))
        print(f"{case.name}: done", file=sys.stderr)
    out: dict = {
        "split": args.split,
        "machine": platform.platform(),
        "utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime(t0)),
        "wall_s": round(time.time() - t0, 1),
        "perturbations": {},
    }
    for name in names:
        r = {k: np.array(v) for k, v in ranks[name].items()}
        out["perturbations"][name] = {
            "frames": int(r["fused"].size),
            "memory_top1": float(np.mean(r["memory"] == 0)),
            "skyline_top1": float(np.mean(r["skyline"] == 0)),
            "fused_top1": float(np.mean(r["fused"] == 0)),
            "fused_top5": float(np.mean(r["fused"] < 5)),
        }
    print(json.dumps(out, indent=1))
    if not args.json_only:
        print(f"\nsplit {args.split}: ranking top-1 per source under each perturbation (all frames)")
        print(f"{'perturbation':12s} {'frames':>6s} {'memory':>7s} {'skyline':>7s} {'fused':>7s} {'fused top-5':>11s}")
        for name, m in out["perturbations"].items():
            print(
                f"{name:12s} {m['frames']:6d} {m['memory_top1']:7.3f} {m['skyline_top1']:7.3f}"
                f" {m['fused_top1']:7.3f} {m['fused_top5']:11.3f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
