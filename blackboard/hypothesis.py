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
import math
import os
import re
import time
from dataclasses import dataclass, field, replace
from typing import Any

from blackboard.errors import CodecError

__all__ = ["Hypothesis", "validate_name", "new_id", "NAME_PATTERN"]

#: levels, hypothesis ids, agent names and run ids are key-expression chunks
NAME_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,128}")


#: names already validated (levels, agents: a handful per run; ids are not remembered)
_KNOWN_NAMES: set[str] = set()
_MAX_KNOWN_NAMES = 4096


def validate_name(value: object, what: str) -> str:
    """Return ``value`` if it is a valid chunk name, else raise ``ValueError`` naming ``what``."""
    if not isinstance(value, str) or NAME_PATTERN.fullmatch(value) is None:
        raise ValueError(f"{what} must be 1-128 characters of [A-Za-z0-9_-], got {value!r}")
    return value


def _check_known_name(value: object, what: str) -> None:
    """:func:`validate_name` for names that recur (levels, agents), remembered once valid."""
    if type(value) is str and value in _KNOWN_NAMES:
        return
    validate_name(value, what)
    if len(_KNOWN_NAMES) >= _MAX_KNOWN_NAMES:
        _KNOWN_NAMES.clear()
    _KNOWN_NAMES.add(value)  # type: ignore[arg-type]


#: bounds on a hypothesis' numbers (a record from the network may hold anything: 1e300, 2**70)
MAX_DEADLINE_S = 86_400.0
MAX_VERSION = 2**62
MAX_LINKS = 1024

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
        _check_fields(self.__dict__)

    @classmethod
    def _make(cls, fields: dict[str, Any]) -> Hypothesis:
        """A validated instance from all its fields (the fast path of :meth:`new` and
        :meth:`from_record`: no per-field frozen ``__setattr__``); same checks as ``__init__``."""
        _check_fields(fields)
        self = object.__new__(cls)
        self.__dict__.update(fields)
        return self

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
        return cls._make(
            {
                "id": new_id(source) if id is None else id,
                "level": level,
                "source": source,
                "credibility": credibility,
                "links": links,
                "version": 1,
                "timestamp": time.time(),
                "body": body,
                "addressed_to": addressed_to,
                "deadline_s": None if deadline_s is None else float(deadline_s),
            }
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
            get = record.get
            return cls._make(
                {
                    "id": record["id"],
                    "level": record["level"],
                    "source": record["source"],
                    "credibility": record["credibility"],
                    "links": get("links", ()),
                    "version": record["version"],
                    "timestamp": float(record["timestamp"]),
                    "body": record["body"],
                    "addressed_to": get("addressed_to"),
                    "deadline_s": get("deadline_s"),
                }
            )
        except KeyError as err:
            raise CodecError(f"hypothesis record lacks field {err.args[0]!r}", key=key) from None
        except (TypeError, ValueError) as err:
            raise CodecError(f"bad hypothesis record: {err}", key=key) from None


def _check_fields(fields: dict[str, Any]) -> None:
    """Validate the fields of a :class:`Hypothesis` in place (``links`` becomes a tuple,
    ``credibility`` a float); raise ``ValueError`` naming the first bad one."""
    validate_name(fields["id"], "hypothesis id")
    _check_known_name(fields["level"], "level")
    _check_known_name(fields["source"], "source")
    addressed_to = fields["addressed_to"]
    if addressed_to is not None:
        _check_known_name(addressed_to, "addressed_to")
    credibility = fields["credibility"]
    if not isinstance(credibility, (int, float)) or not 0.0 <= float(credibility) <= 1.0:
        raise ValueError(f"credibility must be a number in [0, 1], got {credibility!r}")
    version = fields["version"]
    if not isinstance(version, int) or version < 1:
        raise ValueError(f"version must be an integer >= 1, got {version!r}")
    body = fields["body"]
    if not isinstance(body, dict):
        raise ValueError(f"body must be a dict, got {type(body).__name__}")
    if version > MAX_VERSION:
        raise ValueError(f"version must be <= {MAX_VERSION}, got {version!r}")
    deadline_s = fields["deadline_s"]
    if deadline_s is not None and (
        isinstance(deadline_s, bool) or not isinstance(deadline_s, (int, float)) or not 0 < deadline_s <= MAX_DEADLINE_S
    ):
        raise ValueError(f"deadline_s must be a number of seconds in (0, {MAX_DEADLINE_S:g}], got {deadline_s!r}")
    if not math.isfinite(fields["timestamp"]):
        raise ValueError(f"timestamp must be finite, got {fields['timestamp']!r}")
    links = fields["links"]
    if isinstance(links, (str, bytes, dict)) or len(links) > MAX_LINKS:
        raise ValueError(f"links must be a list of at most {MAX_LINKS} ids")
    links = links if type(links) is tuple else tuple(links)
    for link in links:
        validate_name(link, "link")
    fields["links"] = links
    fields["credibility"] = float(credibility)
