"""Hypotheses: the entries of the blackboard, and the names that become key-expression chunks.

A :class:`Hypothesis` is immutable; a new version is a new object. On the wire it is a plain
dict (:meth:`Hypothesis.to_record` / :meth:`Hypothesis.from_record`) encoded by
:mod:`blackboard.codec`.

Example::

    >>> h = Hypothesis.new("answer", {"x": 1.0}, source="doubler", links=("in-1",))
    >>> h.version, h.level
    (1, 'answer')
"""

from __future__ import annotations

import itertools
import os
import re
import time
from dataclasses import dataclass, field, replace
from typing import Any

from blackboard.errors import CodecError

__all__ = ["Hypothesis", "validate_name", "new_id", "NAME_PATTERN"]

#: levels, hypothesis ids, agent names and run ids are key-expression chunks
NAME_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,128}")


def validate_name(value: object, what: str) -> str:
    """Return ``value`` if it is a valid chunk name, else raise ``ValueError`` naming ``what``."""
    if not isinstance(value, str) or NAME_PATTERN.fullmatch(value) is None:
        raise ValueError(f"{what} must be 1-128 characters of [A-Za-z0-9_-], got {value!r}")
    return value


_PROCESS_TOKEN = os.urandom(6).hex()
_counter = itertools.count(1)


def new_id(prefix: str = "h") -> str:
    """A fresh, globally unique hypothesis id such as ``doubler-3f2a9c0d41b7-1a``: the prefix,
    48 random bits drawn once per process, and a per-process counter (no syscall per id)."""
    return f"{prefix}-{_PROCESS_TOKEN}-{next(_counter):x}"


@dataclass(frozen=True)
class Hypothesis:
    """One entry on the blackboard.

    Attributes:
        id: unique id, a key chunk ``[A-Za-z0-9_-]+``.
        level: the level it lives on, a key chunk.
        source: name of the knowledge source that posted it (``"user"`` for inputs).
        credibility: belief in [0, 1].
        links: ids of the hypotheses it was derived from.
        version: 1 when posted; the blackboard node assigns each update the next version.
        timestamp: wall-clock time (``time.time()``) of this version.
        body: msgpack-able dict (numpy arrays allowed).
        addressed_to: agent expected to answer (post linking to this one), or None.
        deadline_s: seconds the addressee has to answer, or None.
    """

    id: str
    level: str
    source: str
    credibility: float
    links: tuple[str, ...]
    version: int
    timestamp: float
    body: dict = field(compare=False)
    addressed_to: str | None = None
    deadline_s: float | None = None

    def __post_init__(self) -> None:
        validate_name(self.id, "hypothesis id")
        validate_name(self.level, "level")
        validate_name(self.source, "source")
        if self.addressed_to is not None:
            validate_name(self.addressed_to, "addressed_to")
        if not isinstance(self.credibility, (int, float)) or not 0.0 <= float(self.credibility) <= 1.0:
            raise ValueError(f"credibility must be a number in [0, 1], got {self.credibility!r}")
        if not isinstance(self.version, int) or self.version < 1:
            raise ValueError(f"version must be an integer >= 1, got {self.version!r}")
        if not isinstance(self.body, dict):
            raise ValueError(f"body must be a dict, got {type(self.body).__name__}")
        if self.deadline_s is not None and not float(self.deadline_s) > 0:
            raise ValueError(f"deadline_s must be > 0, got {self.deadline_s!r}")
        links = tuple(self.links)
        for link in links:
            validate_name(link, "link")
        object.__setattr__(self, "links", links)
        object.__setattr__(self, "credibility", float(self.credibility))

    @classmethod
    def new(
        cls,
        level: str,
        body: dict,
        *,
        source: str,
        links: tuple[str, ...] | list[str] = (),
        credibility: float = 1.0,
        id: str | None = None,
        addressed_to: str | None = None,
        deadline_s: float | None = None,
    ) -> Hypothesis:
        """A version-1 hypothesis with a fresh id (``<source>-<hex>``) unless ``id`` is given."""
        return cls(
            id=new_id(source) if id is None else id,
            level=level,
            source=source,
            credibility=credibility,
            links=tuple(links),
            version=1,
            timestamp=time.time(),
            body=body,
            addressed_to=addressed_to,
            deadline_s=None if deadline_s is None else float(deadline_s),
        )

    def evolve(self, *, body: dict | None = None, credibility: float | None = None) -> Hypothesis:
        """The next version: ``body`` is merged into the current body (top-level keys)."""
        return replace(
            self,
            body=self.body if body is None else {**self.body, **body},
            credibility=self.credibility if credibility is None else credibility,
            version=self.version + 1,
            timestamp=time.time(),
        )

    def to_record(self) -> dict[str, Any]:
        """A plain dict for :func:`blackboard.codec.encode`."""
        return {
            "id": self.id,
            "level": self.level,
            "source": self.source,
            "credibility": self.credibility,
            "links": list(self.links),
            "version": self.version,
            "timestamp": self.timestamp,
            "body": self.body,
            "addressed_to": self.addressed_to,
            "deadline_s": self.deadline_s,
        }

    @classmethod
    def from_record(cls, record: Any, *, key: str | None = None) -> Hypothesis:
        """Inverse of :meth:`to_record`; raise :class:`CodecError` (naming ``key``) if malformed."""
        if not isinstance(record, dict):
            raise CodecError(f"hypothesis record must be a map, got {type(record).__name__}", key=key)
        try:
            return cls(
                id=record["id"],
                level=record["level"],
                source=record["source"],
                credibility=record["credibility"],
                links=tuple(record.get("links", ())),
                version=record["version"],
                timestamp=float(record["timestamp"]),
                body=record["body"],
                addressed_to=record.get("addressed_to"),
                deadline_s=record.get("deadline_s"),
            )
        except KeyError as err:
            raise CodecError(f"hypothesis record lacks field {err.args[0]!r}", key=key) from None
        except (TypeError, ValueError) as err:
            raise CodecError(f"bad hypothesis record: {err}", key=key) from None
