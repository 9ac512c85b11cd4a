"""The exception hierarchy of the blackboard (``blackboard/``).

Every error of the distributed blackboard derives from :class:`BlackboardError` and carries the
context that names the culprit (agent, level, key, file) as attributes, so the command line can
print one clear sentence instead of a traceback::

    BlackboardError          root of the blackboard's errors
    ├── CodecError           a message could not be encoded/decoded   (.key, .message)
    ├── DeclarationError     an agent posted outside its declared levels (.agent, .level, .message)
    ├── AgentError           an agent died, failed or timed out       (.agent, .message)
    │   └── AgentInputError  an agent met a user's input error        (.agent; str: that error's line)
    ├── TransportError       a zenoh session could not be opened or used
    └── TraceError           a trace file cannot be read              (.path, .message)

The blackboard imports nothing of ``models`` or ``knowledge_sources``, and the domain models have
their own root (:class:`models.errors.ModelError`). To catch every mapinterp error in one
``except``, use the tuple :data:`knowledge_sources.errors.MAPINTERP_ERRORS`.
"""

from __future__ import annotations

from pathlib import Path

__all__ = [
    "BlackboardError",
    "CodecError",
    "DeclarationError",
    "AgentError",
    "TransportError",
    "AgentInputError",
    "TraceError",
]


class BlackboardError(Exception):
    """Root of the blackboard's errors."""


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


class AgentInputError(AgentError):
    """An agent met a user's input error during the run (a file changed under it); ``str(err)``
    is that error's own one-line message (file and field), so the run fails as the pre-run check
    would have."""

    def __init__(self, agent: str, message: str) -> None:
        self.agent = agent
        self.message = message
        Exception.__init__(self, message)


class TransportError(BlackboardError):
    """A zenoh session could not be opened, configured or used."""


class TraceError(BlackboardError):
    """A trace file cannot be opened or read."""

    def __init__(self, path: str | Path | None, message: str) -> None:
        self.path = None if path is None else Path(path)
        self.message = message
        super().__init__(f"{self.path}: {message}" if self.path else message)
