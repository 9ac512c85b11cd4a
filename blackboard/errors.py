"""The one exception hierarchy of mapinterp.

Every error a user can cause or meet derives from :class:`MapinterpError` and carries the
context that names the culprit (file, field, agent, key) as attributes, so the command line
can print one clear sentence instead of a traceback::

    MapinterpError
    ├── ScenarioError        a scenario file is malformed        (.path, .field)
    ├── InputError           a data or image file is missing/bad (.path)
    ├── RenderError          the offscreen renderer failed
    ├── AssociativeMemoryError  bad memory configuration or input
    ├── TraceError           a trace file cannot be read         (.path)
    └── BlackboardError      the distributed blackboard
        ├── CodecError       a message could not be encoded/decoded (.key)
        ├── DeclarationError an agent posted outside its declared levels (.agent, .level)
        ├── AgentError       an agent died, failed or timed out  (.agent)
        └── TransportError   a zenoh session could not be opened or used

The hierarchy lives in ``blackboard`` because it is the lowest layer: ``models`` and
``knowledge_sources`` import it from here, ``blackboard`` imports nothing of theirs.
"""

from __future__ import annotations

from pathlib import Path

__all__ = [
    "MapinterpError",
    "ScenarioError",
    "InputError",
    "RenderError",
    "AssociativeMemoryError",
    "TraceError",
    "BlackboardError",
    "CodecError",
    "DeclarationError",
    "AgentError",
    "TransportError",
]


class MapinterpError(Exception):
    """Root of every mapinterp error."""


class ScenarioError(MapinterpError):
    """A scenario file is malformed.

    ``str(err)`` reads ``scenarios/x.yaml: landmarks[3].height: must be > 0``.
    """

    def __init__(self, path: str | Path | None, field: str | None, message: str) -> None:
        self.path = None if path is None else Path(path)
        self.field = field
        self.message = message
        where = [str(p) for p in (self.path, field) if p]
        super().__init__(": ".join([*where, message]))


class InputError(MapinterpError):
    """A data file (DEM, contours, camera image) is missing or unreadable."""

    def __init__(self, path: str | Path | None, message: str) -> None:
        self.path = None if path is None else Path(path)
        self.message = message
        super().__init__(f"{self.path}: {message}" if self.path else message)


class RenderError(MapinterpError):
    """The offscreen renderer could not be created or failed to render."""


class AssociativeMemoryError(MapinterpError):
    """Bad configuration of, or input to, the associative memory."""


class TraceError(MapinterpError):
    """A trace file cannot be opened or read."""

    def __init__(self, path: str | Path | None, message: str) -> None:
        self.path = None if path is None else Path(path)
        self.message = message
        super().__init__(f"{self.path}: {message}" if self.path else message)


class BlackboardError(MapinterpError):
    """Errors of the distributed blackboard."""


class CodecError(BlackboardError):
    """A payload could not be encoded or decoded (malformed, oversized, wrong schema)."""

    def __init__(self, message: str, *, key: str | None = None) -> None:
        self.key = key
        self.message = message
        super().__init__(f"{key}: {message}" if key else message)


class DeclarationError(BlackboardError):
    """An agent touched a level it did not declare, or a second exclusive writer appeared."""

    def __init__(self, agent: str, level: str, message: str) -> None:
        self.agent = agent
        self.level = level
        self.message = message
        super().__init__(f"agent {agent!r}, level {level!r}: {message}")


class AgentError(BlackboardError):
    """A knowledge source died, raised, or did not answer in time."""

    def __init__(self, agent: str, message: str) -> None:
        self.agent = agent
        self.message = message
        super().__init__(f"agent {agent!r}: {message}")


class TransportError(BlackboardError):
    """A zenoh session could not be opened, configured or used."""
