"""Every mapinterp error, for catching them all in one ``except``.

Each layer has its own exception root: the domain models :class:`models.errors.ModelError`, the
blackboard :class:`blackboard.errors.BlackboardError` (neither layer imports the other). This
module, in the layer that sees both, puts them together::

    from knowledge_sources.errors import MAPINTERP_ERRORS

    try:
        results = run_mission("scenarios/hills.yaml")
    except MAPINTERP_ERRORS as err:   # a malformed scenario, a missing image, a dead agent, ...
        print(f"error: {err}")

A tuple rather than a common base class: a base class shared by both layers would have to live
in a module both import, i.e. in one of them or in a fourth package. The commands' own errors
have a third root here::

    CommandError             root of the commands' errors
    ├── UsageError           a command-line option is out of range   (.option, .message)
    └── RunFailed            a run ended without localizing any frame
"""

from __future__ import annotations

from blackboard.errors import BlackboardError
from models.errors import InputError, ModelError, ScenarioError

__all__ = ["MAPINTERP_ERRORS", "CommandError", "UsageError", "RunFailed", "input_error_message"]


class CommandError(Exception):
    """Root of the errors of the commands (``knowledge_sources``)."""


class UsageError(CommandError):
    """A command-line option is out of range (``--rate: 8 frames at 1e-300 Hz take ...``)."""

    def __init__(self, option: str, message: str) -> None:
        self.option = option
        self.message = message
        super().__init__(f"{option}: {message}")


class RunFailed(CommandError):
    """A run ended without localizing any frame: never a success (its results are still written)."""


def input_error_message(err: BaseException) -> str | None:
    """The one-line message of a user's input error (a malformed scenario, a bad data or image
    file: retrying cannot help, the message names the file and the field), else None."""
    return str(err) if isinstance(err, (ScenarioError, InputError)) else None


#: the root of every layer's errors: ``except MAPINTERP_ERRORS`` catches each mapinterp error
MAPINTERP_ERRORS: tuple[type[Exception], ...] = (ModelError, BlackboardError, CommandError)
