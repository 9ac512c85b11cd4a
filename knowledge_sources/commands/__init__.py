"""One module per ``mapinterp`` sub-command.

Each module defines ``HELP: str``, ``add_arguments(parser) -> None`` and
``main(args: argparse.Namespace) -> int``; :mod:`knowledge_sources.cli` imports it lazily,
so a command's heavy dependencies (pyrender, zenoh) load only when it runs.
"""
