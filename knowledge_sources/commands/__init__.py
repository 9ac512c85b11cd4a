"""One module per ``mapinterp`` sub-command.

Each module defines ``HELP: str``, ``add_arguments(parser) -> None`` and
``main(args: argparse.Namespace) -> int``; :mod:`knowledge_sources.cli` imports it lazily,
so a command's heavy dependencies (pyrender, zenoh) load only when it runs.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

__all__ = ["bounded_number"]


def bounded_number(
    low: float, high: float, unit: str, *, integer: bool = False, low_inclusive: bool = False
) -> Callable[[str], float]:
    """An argparse ``type``: a finite number in ``(low, high]`` (``[low, high]`` with
    ``low_inclusive``), else one clear sentence (no inf, no NaN, no 1e-300 Hz)."""
    bracket = "[" if low_inclusive else "("
    span = f"{bracket}{low:g}, {high:g}] {unit}".rstrip()

    def parse(text: str) -> float:
        try:
            value = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"must be {'an integer' if integer else 'a number'} in {span}, got {text!r}"
            ) from None
        if not math.isfinite(value) or not (low <= value if low_inclusive else low < value) or value > high:
            raise argparse.ArgumentTypeError(f"must be in {span}, got {text}")
        return value

    return parse
