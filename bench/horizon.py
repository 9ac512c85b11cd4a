"""The horizon extraction against the true horizons of the evaluation set's camera frames.

Every camera frame of the selected cases of :mod:`bench.evalset` (each case keeps the true
horizon of its frames, ``labels.npz``: the first non-sky row of each column, from the frame's own
renderer) is given to :func:`models.skyline.skyline_from_image` as the skyline ranker gives it (the
scenario camera's vertical field of view); the extracted profile is compared bin by bin with the
true horizon's (:func:`models.skyline.boundary_to_profile`). Per case and over all frames:

The frames are read as taken (their own size; the profile's bins are those of the frame's
field of view), not fitted to the scenario camera.

* ``median_deg``: the median over frames of each frame's median absolute error (degrees),
* ``frames_off``: share of frames whose median error exceeds ``--off`` degrees (1 by default: the
  skyline's trust ends there, :data:`models.skyline.TRUST_DEG`),
* ``bins_off``: share of all valid bins more than ``--off`` degrees off,
* ``rounds``: the extraction's EM rounds per frame (mean),
* ``ms``: CPU milliseconds of an extraction (mean).

``--extraction-rounds N`` fixes the EM at N rounds (3: the rule before session 14), for a before and
after in one tree; ``--both`` runs each frame both ways (the default rule, then N = 3) in one run.
``--seed-trim-rounds 0``: the first round's sky model untrimmed (the rule before session 15);
``--sky-field quadratic``: the sky model's field quadratic in the row (the rule before session 15's
spline).

    python bench/horizon.py --split tuning-sky [--errors large] [--kinds sweep] [--both]

Prints JSON, then a table.
"""

from __future__ import annotations

import sys
from pathlib import Path

# bench/blackboard.py would shadow the blackboard package: drop this folder, add the repository root
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from collections.abc import Iterator, Sequence  # noqa: E402
from contextlib import AbstractContextManager, contextmanager  # noqa: E402
from typing import Any  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from bench.evalset import ERROR_PROFILES, SPLITS, cases  # noqa: E402
from models import skyline  # noqa: E402

#: the rule before session 14: three EM rounds, whatever the boundary does
BEFORE_ROUNDS = 3


@contextmanager
def _skyline_set(**values: Any) -> Iterator[None]:
    """Within the block the named constants of :mod:`models.skyline` have these values."""
    saved = {name: getattr(skyline, name) for name in values}
    for name, value in values.items():
        setattr(skyline, name, value)
    try:
        yield
    finally:
        for name, value in saved.items():
            setattr(skyline, name, value)


def fixed_rounds(rounds: int | None) -> AbstractContextManager[None]:
    """Within the block the extraction's EM runs exactly ``rounds`` rounds (None: the default rule)."""
    return _skyline_set() if rounds is None else _skyline_set(_ROUNDS=max(1, int(rounds)), _SETTLED=-1.0)


def seed_trim(rounds: int | None) -> AbstractContextManager[None]:
    """Within the block the first EM round's sky model is trimmed ``rounds`` times (0: untrimmed,
    the rule before session 15; None: the default, :data:`models.skyline._SEED_TRIM_ROUNDS`)."""
    return _skyline_set() if rounds is None else _skyline_set(_SEED_TRIM_ROUNDS=max(0, int(rounds)))


def sky_field(kind: str | None) -> AbstractContextManager[None]:
    """Within the block the sky model's field along the rows is ``kind`` ("quadratic": the rule
    before session 15; "spline"; None: the default, :data:`models.skyline._SKY_FIELD`)."""
    if kind is None:
        return _skyline_set()
    if kind not in skyline._SKY_FIELDS:
        raise ValueError(f"sky field must be one of {', '.join(skyline._SKY_FIELDS)}, not {kind!r}")
    return _skyline_set(_SKY_FIELD=kind)


def add_sky_model_options(parser: argparse.ArgumentParser) -> None:
    """``--seed-trim-rounds`` and ``--sky-field``: the horizon extraction's sky model as before
    session 15, for a before and after in one tree (read back by :func:`sky_model`)."""
    parser.add_argument(
        "--seed-trim-rounds",
        type=int,
        default=None,
        help="trimmed refits of the horizon extraction's seed sky model (0: untrimmed, the rule before session 15)",
    )
    parser.add_argument(
        "--sky-field",
        choices=skyline._SKY_FIELDS,
        default=None,
        help="the horizon extraction's sky field along the rows (quadratic: the rule before session 15)",
    )


@contextmanager
def sky_model(args: argparse.Namespace, result: dict[str, Any]) -> Iterator[None]:
    """Within the block the sky model of :func:`add_sky_model_options`'s ``args``; ``result``
    records them."""
    with seed_trim(args.seed_trim_rounds), sky_field(args.sky_field):
        yield
    result["seed_trim_rounds"] = args.seed_trim_rounds
    result["sky_field"] = args.sky_field


def frame_errors(image: np.ndarray, horizon: np.ndarray, *, fov_y_deg: float) -> tuple[np.ndarray, int, float]:
    """(absolute errors of the valid bins in degrees, EM rounds, CPU seconds) of one frame (H, W, 3)
    against its true horizon (W,) rows."""
    calls = 0
    viterbi = skyline._viterbi

    def counted(*args: Any, **kwargs: Any) -> Any:
        nonlocal calls
        calls += 1
        return viterbi(*args, **kwargs)

    skyline._viterbi = counted  # type: ignore[assignment]
    try:
        t0 = time.process_time()
        got = skyline.skyline_from_image(image, fov_y_deg=fov_y_deg)
        cpu = time.process_time() - t0
    finally:
        skyline._viterbi = viterbi  # type: ignore[assignment]
    want = skyline.boundary_to_profile(horizon, image.shape[0], fov_y_deg=fov_y_deg)
    err = np.abs(got.astype(np.float64) - want)
    return err[np.isfinite(err)], calls, cpu


def measure(rows: Sequence[dict[str, Any]], *, off: float) -> dict[str, Any]:
    """The columns of the module docstring over frame records ``{"err", "rounds", "cpu"}``."""
    meds = [float(np.median(r["err"])) for r in rows if r["err"].size]
    bins = np.concatenate([r["err"] for r in rows]) if rows else np.zeros(0)
    return {
        "frames": len(rows),
        "median_deg": float(np.median(meds)) if meds else None,
        "frames_off": float(np.mean(np.array(meds) > off)) if meds else None,
        "bins_off": float(np.mean(bins > off)) if bins.size else None,
        "rounds": float(np.mean([r["rounds"] for r in rows])) if rows else None,
        "ms": float(1e3 * np.mean([r["cpu"] for r in rows])) if rows else None,
    }


def run(
    split: str,
    *,
    errors: str = "standard",
    kinds: Sequence[str] | None = None,
    names: Sequence[str] | None = None,
    rules: Sequence[int | None] = (None,),
    off: float = 1.0,
    max_frames: int | None = None,
    out_dir: Path | None = None,
) -> dict[str, Any]:
    """Every frame of the selected cases under each rule (None: the default; N: N fixed rounds);
    ``out_dir``: the evaluation set's folder (default :func:`bench.evalset.default_out_dir`)."""
    label = {r: "default" if r is None else f"{r} rounds" for r in rules}
    per_case: dict[str, dict[str, Any]] = {}
    everything: dict[str, list[dict[str, Any]]] = {label[r]: [] for r in rules}
    for case in cases(split, errors=errors, kinds=kinds, names=names, max_frames=max_frames, out_dir=out_dir):
        horizons = np.load(case.folder / "labels.npz")["horizons"]
        fov = float(case.scenario_dict()["camera"]["fov_y_deg"])
        rows: dict[str, list[dict[str, Any]]] = {label[r]: [] for r in rules}
        for j, frame in enumerate(case.frames):
            bgr = cv2.imread(str(frame.image), cv2.IMREAD_COLOR)  # as taken, at its own size
            if bgr is None:
                raise OSError(f"cannot read camera frame {frame.image}")
            image = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            for r in rules:
                with fixed_rounds(r):
                    err, rounds, cpu = frame_errors(image, horizons[j], fov_y_deg=fov)
                rows[label[r]].append({"err": err, "rounds": rounds, "cpu": cpu})
        per_case[case.name] = {name: measure(rr, off=off) for name, rr in rows.items()}
        for name, rr in rows.items():
            everything[name].extend(rr)
    return {
        "split": split,
        "errors": errors,
        "off_deg": off,
        "cases": per_case,
        "all": {name: measure(rr, off=off) for name, rr in everything.items()},
    }


COLUMNS = ("frames", "median_deg", "frames_off", "bins_off", "rounds", "ms")


def table(result: dict[str, Any]) -> str:
    """Per case and rule, then over all frames, as text."""
    lines = ["case                              rule        " + "  ".join(f"{c:>10}" for c in COLUMNS)]
    groups = [*result["cases"].items(), ("all", result["all"])]
    for case, by_rule in groups:
        for rule, m in by_rule.items():
            cells = [
                "-" if m[c] is None else (f"{m[c]:d}" if isinstance(m[c], int) else f"{m[c]:.3f}") for c in COLUMNS
            ]
            lines.append(f"{case:33s} {rule:10s}  " + "  ".join(f"{v:>10}" for v in cells))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=SPLITS, default="tuning-sky")
    parser.add_argument("--errors", choices=sorted(ERROR_PROFILES), default="standard")
    parser.add_argument("--kinds", nargs="*", default=None, help="sweep, drive, kidnap (default all)")
    parser.add_argument("--names", nargs="*", default=None, help="cases or terrains (default all)")
    parser.add_argument("--off", type=float, default=1.0, help="degrees off the truth that count as wrong")
    parser.add_argument("--max-frames", type=int, default=None, help="the first frames of each case only")
    parser.add_argument(
        "--extraction-rounds", type=int, default=None, help="fixed EM rounds instead of the default rule"
    )
    add_sky_model_options(parser)
    parser.add_argument(
        "--both", action="store_true", help=f"the default rule and {BEFORE_ROUNDS} fixed rounds, frame by frame"
    )
    parser.add_argument("--json-only", action="store_true")
    args = parser.parse_args(argv)
    rules: tuple[int | None, ...] = (None, BEFORE_ROUNDS) if args.both else (args.extraction_rounds,)
    t0 = time.time()
    result: dict[str, Any] = {}
    with sky_model(args, result):
        result.update(
            run(
                args.split,
                errors=args.errors,
                kinds=args.kinds,
                names=args.names,
                rules=rules,
                off=args.off,
                max_frames=args.max_frames,
            )
        )
    result["machine"] = {
        "python": platform.python_version(),
        "load_at_end": Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else None,
        "wall_s": time.time() - t0,
    }
    print(json.dumps(result, indent=1))
    if not args.json_only:
        print(f"\nsplit {args.split} ({args.errors} pose errors): horizon extraction against the true horizons")
        print(table(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
