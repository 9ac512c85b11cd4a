"""``mapinterp report RESULTS [RESULTS ...] --out DIR``: one HTML page and plots of results files.

Writes ``index.html`` (:mod:`knowledge_sources.html_report`: opens from disk; the results side by
side, the map, the frames wrong-first, each frame's images with the landmark answers drawn),
``positions.png`` (map, true and estimated positions), ``track.png`` (the track over
the map) and ``belief.png`` (the tracker's belief over the route against time), ``rankings.png``,
``queries.png`` (one series per results file, e.g. associative and prior on the same frames),
``frames/frame_NNN.png`` (camera frame beside the chosen viewframe and their edge images) for the
first results file, and ``report.md`` linking them with the summary. On a georeferenced map it
also writes ``positions.geojson`` (route, landmarks, true and estimated positions in lon/lat,
:mod:`knowledge_sources.geojson`), which QGIS opens. The scenario is read from
the results' ``scenario_path`` (or ``--scenario``) to redraw the map and the images.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from knowledge_sources.commands import bounded_number

HELP = "plot a results file: map, frames beside their viewframes, rankings, queries"

__all__ = ["HELP", "add_arguments", "main"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("results", type=Path, nargs="+", help="results JSON from 'mapinterp run' (several: compared)")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--scenario", type=Path, default=None, help="scenario file (default: from the results)")
    parser.add_argument(
        "--max-frames",
        type=bounded_number(0, 10_000, "", integer=True, low_inclusive=True),
        default=40,
        help="frame panels to draw at most (default 40)",
    )


def main(args: argparse.Namespace) -> int:
    import sys

    import matplotlib.pyplot as plt
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from knowledge_sources.html_report import frame_order, write_html_report
    from knowledge_sources.replay import replay
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
    from models.route_views import shown_view
    from models.scenario import load_scenario

    runs = [load_results(p) for p in args.results]
    names = [p.name if [q.name for q in args.results].count(p.name) == 1 else str(p) for p in args.results]
    main_run = runs[0]
    scenario_path = args.scenario or main_run.get("scenario_path")
    if scenario_path is None:
        raise InputError(args.results[0], "has no scenario_path: give --scenario")
    scenario = load_scenario(scenario_path)
    out: Path = args.out
    try:
        (out / "frames").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(out, f"cannot create the report folder: {exc}") from None

    console = Console(stderr=True)
    detailed = frame_order(main_run["frames"])[: args.max_frames]
    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        disable=not sys.stderr.isatty(),
        transient=True,
    ) as bar:
        task = bar.add_task("rendering viewframes and camera frames", total=None)
        scene = replay(scenario)
        env, viewframes, frames = scene.environment, scene.viewframes, scene.frames

        def save(fig, name: str) -> str:
            fig.savefig(out / name, dpi=100)
            plt.close(fig)
            return name

        bar.update(task, description="plotting", total=5 + len(detailed), completed=0)
        on_map = {
            "terrain": env.terrain,
            "landmarks": env.landmarks,
            "route": scenario.route,
            "poses": [v.pose for v in viewframes],
        }
        written = [
            save(plot_positions(main_run, **on_map), "positions.png"),
            save(plot_track(main_run, **on_map), "track.png"),
            save(plot_belief(main_run), "belief.png"),
            save(plot_rankings(main_run), "rankings.png"),
            save(plot_queries(runs), "queries.png"),
        ]
        n_figures = len(written)
        bar.update(task, completed=n_figures)
        written_geojson: list[str] = []
        if scenario.map_frame is not None:
            import json

            from knowledge_sources.geojson import results_geojson

            doc = results_geojson(
                main_run, frame=scenario.map_frame, route=scenario.route, landmarks=scenario.landmarks
            )
            (out / "positions.geojson").write_text(json.dumps(doc) + "\n")
            written_geojson = ["positions.geojson"]
        for rec in detailed:
            if rec["frame"] in frames:
                k = shown_view(rec, scenario.views_per_leg)
                vf = viewframes[k].image if k is not None else None
                written.append(
                    save(
                        plot_frame(rec, frames[rec["frame"]].image, vf, pattern=scene.pattern),
                        f"frames/frame_{rec['frame']:03d}.png",
                    )
                )
            bar.advance(task)
        bar.update(task, description="writing index.html", total=len(detailed), completed=0)
        page = write_html_report(
            out,
            runs,
            names,
            scene,
            figures=written[:n_figures],
            extra_links=[
                (n, f"{n}: route, landmarks, true and estimated positions (lon/lat, opens in QGIS)")
                for n in written_geojson
            ],
            max_frames=args.max_frames,
            progress=lambda done, total: bar.update(task, completed=done),
        )

    lines = [f"# mapinterp report: {main_run['scenario']}", "", "The full report is [index.html](index.html).", ""]
    lines.append("| results | strategy | frames | top-1 | mean queries | mean error (m) | latency p50 (ms) |")
    lines.append("|---|---|---|---|---|---|---|")
    for name, run in zip(names, runs):
        s = run["summary"]
        top1 = "n/a" if s["top1"] is None else f"{s['top1']:.1%}"
        err = "n/a" if s["mean_error_m"] is None else f"{s['mean_error_m']:.1f}"
        lines.append(
            f"| {name} | {run['strategy']} | {s['frames']} | {top1} | {s['mean_queries']:.2f} | "
            f"{err} | {s['latency_ms_p50']:.0f} |"
        )
    lines.append("")
    lines += [f"![{name}]({name})" for name in written]
    lines += [f"[{name}]({name}) (route, landmarks, true and estimated positions, lon/lat)" for name in written_geojson]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    print(f"report written to {page} ({len(written)} figures; also {out}/report.md)")
    return 0
