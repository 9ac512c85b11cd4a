"""The exception hierarchy of the domain models (``models/``).

Every error the models raise for a user's mistake or a failed resource derives from
:class:`ModelError` and carries the context that names the culprit as attributes, so the command
line can print one clear sentence instead of a traceback::

    ModelError                  root of the models' errors
    ├── ScenarioError           a scenario file is malformed          (.path, .field, .message)
    ├── InputError              a data or image file is missing/bad   (.path, .message)
    │   └── CacheEntryError     a viewframe cache entry named by a message is missing or stale
    ├── RenderError             the offscreen renderer failed         (.message)
    └── AssociativeMemoryError  bad memory configuration or input     (.message)

``models`` imports nothing from ``blackboard`` or ``knowledge_sources``; the blackboard has its
own root (:class:`blackboard.errors.BlackboardError`). To catch every mapinterp error in one
``except``, use the tuple :data:`knowledge_sources.errors.MAPINTERP_ERRORS`
(``except MAPINTERP_ERRORS as err:``), defined in the layer that sees both.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["ModelError", "ScenarioError", "InputError", "CacheEntryError", "RenderError", "AssociativeMemoryError"]


class ModelError(Exception):
    """Root of the models' errors; ``message`` is the sentence without its context."""

    def __init__(self, message: str, *, where: str | None = None) -> None:
        self.message = message
        super().__init__(f"{where}: {message}" if where else message)


class ScenarioError(ModelError):
    """A scenario file is malformed.

    ``str(err)`` reads ``scenarios/x.yaml: landmarks[3].height: must be > 0``; ``path`` is the
    file (None for a scenario built from a dict), ``field`` the field path (None for the file as a
    whole).
    """

    def __init__(self, path: str | Path | None, field: str | None, message: str) -> None:
        self.path = None if path is None else Path(path)
        self.field = field
        super().__init__(message, where=": ".join(str(p) for p in (self.path, field) if p))


class InputError(ModelError):
    """A data file (DEM, contours, camera image, results, output folder) is missing or unreadable."""

    def __init__(self, path: str | Path | None, message: str) -> None:
        self.path = None if path is None else Path(path)
        super().__init__(message, where=None if self.path is None else str(self.path))


class CacheEntryError(InputError):
    """A viewframe cache entry (:mod:`models.viewframe_cache`) that a viewframe message names for its
    pixels cannot be read here: missing (another host, a deleted cache), not committed, of another
    count than the reference says (stale), or the row out of range. ``path`` is the entry's folder."""


class RenderError(ModelError):
    """The offscreen renderer could not be created or failed to render."""


class AssociativeMemoryError(ModelError):
    """Bad configuration of, or input to, the associative memory."""
