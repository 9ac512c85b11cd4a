"""``mapinterp schema``: the scenario file's JSON Schema, for editors' YAML completion.

Generated from the scenario specs (:mod:`models.scenario`), so it cannot drift from what
``mapinterp run`` accepts. With the YAML language server (VS Code, vim, emacs), first line of a
scenario::

    # yaml-language-server: $schema=scenario.schema.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

__all__ = ["HELP", "add_arguments", "main", "scenario_schema"]

HELP = "print the scenario file's JSON Schema (for editors' YAML completion)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=None, help="write the schema to this file instead")


def scenario_schema() -> dict:
    """The JSON Schema (draft 2020-12) of a scenario file."""
    from models.scenario import Scenario

    schema = Scenario.model_json_schema()
    return {**schema, "$schema": "https://json-schema.org/draft/2020-12/schema", "title": "mapinterp scenario"}


def main(args: argparse.Namespace) -> int:
    text = json.dumps(scenario_schema(), indent=2) + "\n"
    if args.out is None:
        print(text, end="")
    else:
        from models.errors import InputError

        try:
            args.out.write_text(text)
        except OSError as exc:
            raise InputError(args.out, f"cannot write the schema: {exc}") from None
        print(f"scenario JSON Schema written to {args.out}")
    return 0
