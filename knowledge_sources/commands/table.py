"""``mapinterp table SCENARIO``: the error-variance table of camera images against viewframes.

Renders the scenario's viewframes (:class:`models.world.World`), stores them in a
:class:`models.index.ViewframeIndex` (preprocessing and memory from the scenario's ``memory``
block, as the indexer agent does), and for every camera frame (the files of
``sensor.frames``, resized to the camera size, or the simulated frames of ``sensor.simulate``)
prints one row: the error variance of the recall against every stored viewframe (see
:mod:`models.associative`), the row's minimum marked ``*``. When a frame has a true pose, its
*truth viewframe* is the viewframe nearest to it (the route point itself with one viewframe a
point), and the row says whether the minimum falls
on it. ``--json`` prints the same as one JSON document.
"""

from __future__ import annotations

import argparse
import json
import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from models.errors import ScenarioError

__all__ = ["HELP", "TableRow", "add_arguments", "error_variance_table", "format_table", "rich_table", "main"]

log = logging.getLogger(__name__)

HELP = "print the error-variance table of camera images against stored viewframes"


@dataclass(frozen=True)
class TableRow:
    """One camera frame: ``variances`` (V,) in viewframe order, ``best`` the index of the
    minimum, ``truth`` the viewframe nearest to the true pose (None if unknown)."""

    frame: int
    source: str
    variances: list[float]
    best: int
    reliability: float
    truth: int | None

    @property
    def correct(self) -> bool | None:
        """Whether the minimum falls on the truth viewframe (None without a true pose)."""
        return None if self.truth is None else self.best == self.truth

    def to_dict(self) -> dict[str, Any]:
        return {
            "frame": self.frame,
            "source": self.source,
            "variances": self.variances,
            "best": self.best,
            "reliability": self.reliability,
            "truth_viewframe": self.truth,
            "correct": self.correct,
        }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", type=Path, help="scenario YAML file with a sensor block")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def error_variance_table(
    scenario, *, progress: Callable[[str, int, int], None] | None = None
) -> tuple[list, list[TableRow]]:
    """Render, store and rank: ``(viewframes, rows)`` for a loaded scenario with sensor frames.

    ``progress(phase, done, total)`` follows the rendering and the ranking.

    Raises :class:`~models.errors.ScenarioError` when the scenario has no ``sensor`` block.
    """
    from knowledge_sources.results import nearest_viewframe
    from models.index import ViewframeIndex
    from models.world import World

    if scenario.sensor is None:
        raise ScenarioError(
            scenario.path, "sensor", "the table needs camera frames: add sensor.frames or sensor.simulate"
        )
    viewframes_progress = None if progress is None else (lambda d, t: progress("rendering viewframes", d, t))
    with World(scenario, progress=viewframes_progress) as world:
        viewframes = world.viewframes
        if progress is not None:
            progress("rendering camera frames", 0, 0)
        frames = world.sensor_frames
    index = ViewframeIndex(scenario.memory, seed=scenario.seed)
    index.add([vf.image for vf in viewframes], [vf.index for vf in viewframes])
    rows = []
    places = [(vf.pose.x, vf.pose.y) for vf in viewframes]  # the viewframes' (x, y), between the route points too
    for frame in frames:
        ranking = index.rank(frame.image)
        by_viewframe = dict(zip(ranking.viewframes.tolist(), ranking.variances.tolist()))
        variances = [by_viewframe[vf.index] for vf in viewframes]
        truth = None
        if frame.truth is not None:
            truth = nearest_viewframe(frame.truth[0], frame.truth[1], places)
        rows.append(
            TableRow(frame.index, frame.source, variances, int(ranking.viewframes[0]), ranking.reliability, truth)
        )
        if progress is not None:
            progress("ranking camera frames", len(rows), len(frames))
    return viewframes, rows


def format_table(scenario_name: str, viewframe_indices: list[int], rows: list[TableRow], *, size: int) -> str:
    """Plain-text table; cells are error variances x N^2 (so 0 = perfect, 2 = unrelated)."""
    scale = float(size * size)
    head = f"{'frame':<22}" + "".join(f"{'V' + str(v):>10}" for v in viewframe_indices) + f"{'rel':>7}  truth"
    lines = [
        f"error variance x {size}^2 of the recall against each stored viewframe ({scenario_name}); * row minimum",
        head,
        "-" * len(head),
    ]
    for r in rows:
        name = Path(r.source).name if r.source != "simulated" else f"simulated {r.frame}"
        cells = "".join(
            f"{v * scale:>9.4f}{'*' if j == r.best else ' '}" for j, v in zip(viewframe_indices, r.variances)
        )
        verdict = "-" if r.truth is None else f"V{r.truth} {'ok' if r.correct else 'WRONG'}"
        lines.append(f"{name[:21]:<22}{cells}{r.reliability:>7.2f}  {verdict}")
    judged = [r for r in rows if r.truth is not None]
    if judged:
        ok = sum(bool(r.correct) for r in judged)
        lines.append(f"{ok}/{len(judged)} rows have their minimum on the truth viewframe")
    return "\n".join(lines)


def rich_table(scenario_name: str, viewframe_indices: list[int], rows: list[TableRow], *, size: int) -> Any:
    """:func:`format_table` as a rich Table: row minimum marked ``*`` (bold), wrong verdicts red."""
    from rich.table import Table

    scale = float(size * size)
    judged = [r for r in rows if r.truth is not None]
    caption = None
    if judged:
        caption = f"{sum(bool(r.correct) for r in judged)}/{len(judged)} rows have their minimum on the truth viewframe"
    table = Table(
        title=f"error variance x {size}^2 of the recall against each stored viewframe ({scenario_name}); * row minimum",
        caption=caption,
    )
    table.add_column("frame", justify="left")
    for v in viewframe_indices:
        table.add_column(f"V{v}", justify="right")
    table.add_column("rel", justify="right")
    table.add_column("truth", justify="left")
    for r in rows:
        name = Path(r.source).name if r.source != "simulated" else f"simulated {r.frame}"
        cells = [
            f"[bold]{v * scale:.4f}*[/bold]" if j == r.best else f"{v * scale:.4f} "
            for j, v in zip(viewframe_indices, r.variances)
        ]
        verdict = "-" if r.truth is None else (f"V{r.truth} ok" if r.correct else f"[red]V{r.truth} WRONG[/red]")
        table.add_row(name, *cells, f"{r.reliability:.2f}", verdict)
    return table


def main(args: argparse.Namespace) -> int:
    from knowledge_sources.progress import progress_bar
    from models.scenario import load_scenario

    scenario = load_scenario(args.scenario)
    with progress_bar() as bar:
        task = bar.add_task(f"{scenario.name}: rendering viewframes", total=None)
        viewframes, rows = error_variance_table(
            scenario,
            progress=lambda phase, done, total: bar.update(
                task, description=f"{scenario.name}: {phase}", completed=done, total=total or None
            ),
        )
    indices = [vf.index for vf in viewframes]
    if args.json:
        doc = {
            "scenario": scenario.name,
            "memory": scenario.memory.model_dump(),
            "viewframes": [
                {"index": vf.index, "pose": [vf.pose.x, vf.pose.y, vf.pose.z, vf.pose.heading_deg]} for vf in viewframes
            ],
            "rows": [r.to_dict() for r in rows],
        }
        print(json.dumps(doc, indent=1))
    else:
        import shutil
        import sys

        from rich.console import Console

        width = None if sys.stdout.isatty() else shutil.get_terminal_size((160, 24)).columns
        Console(width=width, highlight=False).print(rich_table(scenario.name, indices, rows, size=scenario.memory.size))
    return 0
