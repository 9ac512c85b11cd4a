"""``mapinterp render SCENARIO --out DIR``: viewframes, symbolic descriptions and an overview.

Writes ``vf_000.png`` (the rendered viewframe), ``vf_000.json`` (its pose and symbolic
description), ``priors.json`` (the a-priori landmark probabilities P(L)) and ``overview.png``.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import cv2

from models.errors import InputError

__all__ = ["HELP", "add_arguments", "main"]

HELP = "render a scenario's viewframes, their symbolic descriptions and an overview map"

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``mapinterp render``."""
    parser.add_argument("scenario", type=Path, help="scenario YAML file")
    parser.add_argument("--out", type=Path, required=True, help="output folder (created)")
    parser.add_argument("--no-overview", action="store_true", help="skip overview.png")


def main(args: argparse.Namespace) -> int:
    """Render every viewframe of the scenario into ``args.out``; returns 0."""
    from dataclasses import asdict

    from knowledge_sources.progress import callback, progress_bar
    from models.overview import draw_overview
    from models.scenario import load_scenario
    from models.world import World

    scenario = load_scenario(args.scenario)
    out: Path = args.out
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(out, f"cannot create the output folder: {exc}") from None
    with progress_bar() as bar:
        task = bar.add_task(f"{scenario.name}: building the environment model", total=None)
        world = World(scenario, progress=callback(bar, task, f"{scenario.name}: rendering viewframes"))
        env = world.environment
        t0 = time.perf_counter()
        with world:
            frames = world.viewframes
        dt = time.perf_counter() - t0
        bar.update(task, description=f"{scenario.name}: writing", completed=0, total=len(frames))
        for vf in frames:
            stem = out / f"vf_{vf.index:03d}"
            if not cv2.imwrite(str(stem.with_suffix(".png")), cv2.cvtColor(vf.image, cv2.COLOR_RGB2BGR)):
                raise InputError(stem.with_suffix(".png"), "cannot write image")
            doc = {"index": vf.index, "pose": asdict(vf.pose), "description": vf.description.to_dict()}
            stem.with_suffix(".json").write_text(json.dumps(doc, indent=1), encoding="utf-8")
            bar.advance(task)
        priors = world.priors
        (out / "priors.json").write_text(json.dumps(priors, indent=1), encoding="utf-8")
        if not args.no_overview:
            bar.update(task, description=f"{scenario.name}: drawing overview.png", total=None)
            draw_overview(
                env.terrain,
                env.landmarks,
                scenario.route,
                [vf.pose for vf in frames],
                out / "overview.png",
                title=scenario.name,
            )
    seen = sum(1 for vf in frames if vf.description.visible)
    print(
        f"{scenario.name}: {len(frames)} viewframes in {dt:.2f} s ({len(frames) / dt:.1f}/s), "
        f"{seen} with landmarks in view -> {out}"
    )
    return 0
