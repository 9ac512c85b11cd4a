"""``mapinterp report RESULTS [RESULTS ...] --out DIR``: plots of one or more results files.

Writes ``positions.png`` (map, true and estimated positions), ``track.png`` (the track over
the map) and ``belief.png`` (the tracker's belief over the route against time), ``rankings.png``,
``queries.png`` (one series per results file, e.g. associative and prior on the same frames),
``frames/frame_NNN.png`` (camera frame beside the chosen viewframe and their edge images) for the
first results file, and ``report.md`` linking them with the summary. The scenario is read from
the results' ``scenario_path`` (or ``--scenario``) to redraw the map and the images.
"""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "plot a results file: map, frames beside their viewframes, rankings, queries"

__all__ = ["HELP", "add_arguments", "main"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("results", type=Path, nargs="+", help="results JSON from 'mapinterp run' (several: compared)")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--scenario", type=Path, default=None, help="scenario file (default: from the results)")
    parser.add_argument("--max-frames", type=int, default=40, help="frame panels to draw at most (default 40)")


def main(args: argparse.Namespace) -> int:
    import matplotlib.pyplot as plt

    from knowledge_sources.report import (
        plot_belief,
        plot_frame,
        plot_positions,
        plot_queries,
        plot_rankings,
        plot_track,
    )
    from knowledge_sources.results import load_results
    from models.errors import InputError
    from models.index import ViewframeIndex
    from models.scenario import load_scenario
    from models.world import World

    runs = [load_results(p) for p in args.results]
    main_run = runs[0]
    scenario_path = args.scenario or main_run.get("scenario_path")
    if scenario_path is None:
        raise InputError(args.results[0], "has no scenario_path: give --scenario")
    scenario = load_scenario(scenario_path)
    out: Path = args.out
    (out / "frames").mkdir(parents=True, exist_ok=True)

    with World(scenario) as world:
        env = world.environment
        viewframes = world.viewframes
        frames = {f.index: f for f in world.sensor_frames}

    def save(fig, name: str) -> str:
        fig.savefig(out / name, dpi=100)
        plt.close(fig)
        return name

    written = [
        save(plot_positions(main_run, terrain=env.terrain, landmarks=env.landmarks, route=scenario.route,
                            poses=[v.pose for v in viewframes]), "positions.png"),
        save(plot_track(main_run, terrain=env.terrain, landmarks=env.landmarks, route=scenario.route,
                        poses=[v.pose for v in viewframes]), "track.png"),
        save(plot_belief(main_run), "belief.png"),
        save(plot_rankings(main_run), "rankings.png"),
        save(plot_queries(runs), "queries.png"),
    ]
    index = ViewframeIndex(scenario.memory)  # its preprocessing, for the edge images
    for rec in main_run["frames"][: args.max_frames]:
        cam_img = frames[rec["frame"]].image if rec["frame"] in frames else None
        if cam_img is None:
            continue
        vf = viewframes[rec["viewframe"]].image if rec["viewframe"] is not None else None
        written.append(save(plot_frame(rec, cam_img, vf, pattern=index.pattern), f"frames/frame_{rec['frame']:03d}.png"))

    lines = [f"# mapinterp report: {main_run['scenario']}", ""]
    lines.append("| results | strategy | frames | top-1 | mean queries | mean error (m) | latency p50 (ms) |")
    lines.append("|---|---|---|---|---|---|---|")
    for path, run in zip(args.results, runs):
        s = run["summary"]
        top1 = "n/a" if s["top1"] is None else f"{s['top1']:.1%}"
        err = "n/a" if s["mean_error_m"] is None else f"{s['mean_error_m']:.1f}"
        lines.append(f"| {path.name} | {run['strategy']} | {s['frames']} | {top1} | {s['mean_queries']:.2f} | "
                     f"{err} | {s['latency_ms_p50']:.0f} |")
    lines.append("")
    lines += [f"![{name}]({name})" for name in written]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    print(f"report written to {out}/report.md ({len(written)} figures)")
    return 0
