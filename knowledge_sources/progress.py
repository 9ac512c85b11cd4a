"""The progress bar of the commands: rich, on stderr, shown only on a terminal, gone when done.

``with progress_bar() as bar: task = bar.add_task("rendering viewframes", total=n)``; pass
:func:`callback` ``(bar, task)`` where a model function takes ``progress(done, total)``.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn, TimeElapsedColumn

__all__ = ["progress_bar", "callback"]


def progress_bar(*, disable: bool = False) -> Progress:
    """A transient bar on stderr with the phase as its label; disabled off a terminal."""
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=Console(stderr=True),
        disable=disable or not sys.stderr.isatty(),
        transient=True,
    )


def callback(bar: Progress, task: TaskID, description: str | None = None) -> Callable[[int, int], None]:
    """A ``progress(done, total)`` function updating ``task`` (and relabelling it, when given)."""

    def update(done: int, total: int) -> None:
        if description is None:
            bar.update(task, completed=done, total=total)
        else:
            bar.update(task, completed=done, total=total, description=description)

    return update
