"""The trust model of a run: who may say what on the blackboard, and how the node knows.

Anyone who reaches a run's zenoh router can publish on its keys, so nothing on the wire is
believed for what it claims to be. The rules (enforced by the node; the agents enforce the
half that concerns them):

* **Joining.** A run expects a fixed set of agent names (those the runtime starts, and the
  ``--remote`` ones). Each gets a *join secret* that never travels: an in-process agent gets it
  in memory, an agent process on its standard input, a remote agent from the run secret the
  user hands over (``mapinterp agent --secret``). The join request carries
  ``proof = HMAC(secret, "join/<run>/<name>")``; the node refuses a join without a good proof,
  of an unexpected name, or of a name already live.
* **Binding a name to a session.** The join reply, a query reply (routed to the querying
  session only), hands the agent two fresh keys: its own *agent key* and the *run key* shared
  by the joined agents, sealed (:func:`seal`) with :func:`join_key`, which only the holder of
  the secret can derive: a session that sent a copied join learns nothing, and the agent takes
  only a reply it can unseal (a forged "welcome" from another session is ignored). Every message of the agent (posts, status, requests) carries
  ``HMAC(agent key, payload)`` in its zenoh attachment: the node accepts it only if the tag
  matches the name it claims, so a post, a status, a leave or activity records under a real
  agent's name from any other session are refused and traced (``rejected``). Posts also carry
  ``HMAC(run key, payload)``, which the consumers check before decoding: a post from outside
  the run never reaches a knowledge source.
* **Levels.** A hypothesis is accepted only on a level its agent declared in ``produces``; an
  exclusive level has one writer (a second declaration is refused at join).
* **Node messages** (updates, retractions, timeouts, quiescence probes, the run end) carry
  ``HMAC(run key, payload)``: agents ignore forged ones.
* **Every field checked.** Control messages are validated field by field
  (:func:`check_status`, :func:`check_request`) and hypotheses by
  :class:`~blackboard.hypothesis.Hypothesis` (finite, bounded numbers: ``deadline_s: 1e300``
  is refused), so no single message can crash or stall the node.
* **The truth level** (true poses, for evaluation only) is never served to ``get`` queries,
  and its bodies travel sealed (:func:`seal`) with the posting agent's own key (the node's
  own posts with a key of the node alone), not with the run key every joined agent holds: only
  the node, which writes the results and the trace for the run's own user, reads them.
* **Memory budgets.** A message larger than ``max_message_bytes`` is dropped by everyone
  before decoding; the node also keeps a per-run budget of the bytes its store keeps (compressed, for large
  messages; :data:`RUN_BUDGET_BYTES`),
  beyond which posts are refused and traced.

Across machines the router itself also asks for a user name and password (zenoh ``usrpwd``):
see :mod:`blackboard.config`; TLS and access control come from a zenoh config file
(``scenarios/zenoh/``). Known limits (README.md, "Trust model"): a joined agent holds the run
key, so it could forge posts that other *consumers* believe (the node, and so the results,
still refuse them); an outside session can declare a liveliness token under an agent's name,
which hides that agent's death from the node until its questions time out; a session that
receives a join request before the node does (by declaring the node's queryable) and sends it
on first makes the real agent's join fail (visible, never silent; it gains no key); anyone who
reaches the port can flood it; zenoh itself authenticates sessions only with ``usrpwd`` or
TLS, which are off on loopback by default.
"""

from __future__ import annotations

import hashlib
import hmac
import math
import os
import secrets
from typing import Any

__all__ = [
    "new_secret",
    "proof",
    "join_key",
    "sign",
    "verify",
    "seal",
    "unseal",
    "check_status",
    "check_request",
    "TAG_BYTES",
    "RUN_BUDGET_BYTES",
    "PRIVATE_LEVELS",
    "SEALED",
    "attachment_bytes",
    "read_message",
]

#: length of an HMAC-SHA256 tag
TAG_BYTES = 32
#: stored bytes the node accepts over a whole run
RUN_BUDGET_BYTES = 2 * 1024**3
#: levels whose bodies travel sealed and are never served to ``get`` queries
PRIVATE_LEVELS: frozenset[str] = frozenset({"truth"})
#: the one key of a sealed body on the wire: ``{SEALED: seal(agent key, encode(body))}``
SEALED = "__sealed__"

_MAX_INT = 2**62
_MAX_ENTRIES = 4096
_MAX_ACTIVITY = 100_000
_MAX_TEXT = 4000
_STATES = frozenset({"idle", "busy", "dead", "stopped"})
_OPS = frozenset({"challenge", "join", "leave", "update", "retract"})
_ACTIVITY_KINDS = frozenset({"activation_start", "activation_finish", "activation_error", "activation_obviated"})


def new_secret() -> str:
    """A fresh random secret: 32 hex digits (128 bits)."""
    return secrets.token_hex(16)


def proof(secret: str, *parts: str) -> str:
    """``HMAC-SHA256(secret, "/".join(parts))`` in hex: proves knowledge of ``secret``."""
    return hmac.new(secret.encode(), "/".join(parts).encode(), hashlib.sha256).hexdigest()


def join_key(secret: str, run_id: str, name: str, nonce: str) -> bytes:
    """The key that seals the join reply to agent ``name`` for challenge ``nonce``: derived from
    the agent's join secret, so only the node and that agent know it."""
    return hmac.new(secret.encode(), f"keys/{run_id}/{name}/{nonce}".encode(), hashlib.sha256).digest()


def sign(key: bytes, payload: bytes) -> bytes:
    """The :data:`TAG_BYTES`-byte HMAC-SHA256 tag of ``payload``."""
    return hmac.new(key, payload, hashlib.sha256).digest()


def verify(key: bytes | None, payload: bytes, tag: bytes | None) -> bool:
    """True when ``tag`` is ``sign(key, payload)`` (constant time); False without a key or tag."""
    if key is None or tag is None or len(tag) != TAG_BYTES:
        return False
    return hmac.compare_digest(sign(key, payload), tag)


def _keystream(key: bytes, nonce: bytes, n: int) -> bytes:
    blocks = (n + 31) // 32
    return b"".join(hmac.new(key, nonce + i.to_bytes(8, "big"), hashlib.sha256).digest() for i in range(blocks))[:n]


def seal(key: bytes, plaintext: bytes) -> bytes:
    """Encrypt then authenticate ``plaintext`` with ``key``: ``nonce (16) | ciphertext | tag (32)``.

    The cipher is HMAC-SHA256 in counter mode (a PRF keystream); the tag covers nonce and
    ciphertext. Meant for the small bodies of :data:`PRIVATE_LEVELS`."""
    nonce = os.urandom(16)
    stream = _keystream(key, nonce, len(plaintext))
    body = nonce + bytes(a ^ b for a, b in zip(plaintext, stream))
    return body + sign(key, body)


def unseal(key: bytes | None, sealed: Any) -> bytes | None:
    """Inverse of :func:`seal`; None when ``sealed`` is not a valid sealing under ``key``."""
    if key is None or not isinstance(sealed, (bytes, bytearray)) or len(sealed) < 16 + TAG_BYTES:
        return None
    sealed = bytes(sealed)
    body, tag = sealed[:-TAG_BYTES], sealed[-TAG_BYTES:]
    if not verify(key, body, tag):
        return None
    nonce, data = body[:16], body[16:]
    return bytes(a ^ b for a, b in zip(data, _keystream(key, nonce, len(data))))


def read_message(key: str, agent: str, sent: str, after: str) -> bytes:
    """What a read's ``tag`` parameter signs: its key expression and its other parameters."""
    return f"read\n{key}\n{agent}\n{sent}\n{after}".encode()


def attachment_bytes(carrier: Any) -> bytes | None:
    """The attachment of a zenoh sample or query as bytes (None when there is none)."""
    attachment = getattr(carrier, "attachment", None)
    return None if attachment is None else attachment.to_bytes()


# -- field-by-field validation of control messages -------------------------------------------------


def _name(value: Any) -> bool:
    from blackboard.hypothesis import NAME_PATTERN

    return type(value) is str and NAME_PATTERN.fullmatch(value) is not None


def _count(value: Any) -> bool:
    return type(value) is int and 0 <= value <= _MAX_INT


def _counts(value: Any) -> bool:
    return type(value) is dict and len(value) <= _MAX_ENTRIES and all(_name(k) and _count(v) for k, v in value.items())


def _text(value: Any, *, optional: bool = True) -> bool:
    return (value is None and optional) or (type(value) is str and len(value) <= _MAX_TEXT)


def _finite(value: Any) -> bool:
    return type(value) in (int, float) and math.isfinite(value)


def _activity_problem(records: Any) -> str | None:
    from blackboard.agent import ACTIVITY_CODES

    if type(records) is not list or len(records) > _MAX_ACTIVITY:
        return f"activity must be a list of at most {_MAX_ACTIVITY} records"
    for i, record in enumerate(records):
        if type(record) is list:
            if len(record) != 8 or type(record[0]) is not str or len(record[0]) > 8:
                return f"activity[{i}]: a row needs 8 fields and a code"
            if record[0] not in ACTIVITY_CODES:
                continue  # a kind of a newer agent: ignored, as the node ignores it
            code, level, hyp_id, version, event, rating, t, extra = record
            if not (
                _name(level)
                and _name(hyp_id)
                and _count(version)
                and _text(event, optional=False)
                and (rating is None or _finite(rating))
                and _finite(t)
            ):
                return f"activity[{i}]: malformed row"
            if not (extra is None or _finite(extra) or _text(extra, optional=False)):
                return f"activity[{i}]: malformed extra field"
        elif type(record) is dict:
            if type(record.get("kind")) is not str or record["kind"] not in _ACTIVITY_KINDS or len(record) > 16:
                return f"activity[{i}]: a map record needs a kind of {sorted(_ACTIVITY_KINDS)}"
            for k, v in record.items():
                if type(k) is not str or not (v is None or _finite(v) or type(v) is str and len(v) <= 20_000):
                    return f"activity[{i}].{k}: must be a number or a short text"
        else:
            return f"activity[{i}]: must be a row or a map"
    return None


def check_status(message: Any) -> str | None:
    """The problem of an agent's status message, field by field, or None when it is well formed:
    ``{"agent", "state", "recv", "sent", "timeouts", "probe", "activity", "reason"[, "input_error"]}``."""
    if type(message) is not dict:
        return "a status must be a map"
    allowed = {"agent", "state", "recv", "sent", "timeouts", "probe", "activity", "reason", "input_error", "seq"}
    extra = set(message) - allowed
    if extra:
        return f"unknown field {sorted(map(str, extra))[0]!r}"
    if not _name(message.get("agent")):
        return "agent: must be an agent name"
    if type(message.get("state")) is not str or message["state"] not in _STATES:
        return f"state: must be one of {sorted(_STATES)}"
    if not _counts(message.get("recv", {})):
        return "recv: must map level names to counts"
    for k in ("sent", "timeouts"):
        if not _count(message.get(k, 0)):
            return f"{k}: must be a count"
    probe = message.get("probe")
    if probe is not None and not _count(probe):
        return "probe: must be a count or null"
    if not _count(message.get("seq", 0)):
        return "seq: must be a count"
    for k in ("reason", "input_error"):
        if not _text(message.get(k)):
            return f"{k}: must be a text of at most {_MAX_TEXT} characters"
    return _activity_problem(message.get("activity", []))


def check_request(request: Any) -> str | None:
    """The problem of a request to the node (challenge, join, leave, update, retract), or None."""
    if type(request) is not dict:
        return "a request must be a map"
    op = request.get("op")
    if type(op) is not str or op not in _OPS:
        return f"op: must be one of {sorted(_OPS)}"
    if not _name(request.get("agent")):
        return "agent: must be an agent name"
    if not _count(request.get("sent", 0)):
        return "sent: must be a count"
    if not _counts(request.get("after", {})):
        return "after: must map agent names to counts"
    if op == "challenge" and not _text(request.get("nonce")):
        return "nonce: must be a short text"
    if op == "join":
        for k in ("consumes", "produces", "exclusive"):
            levels = request.get(k, [])
            if type(levels) is not list or len(levels) > _MAX_ENTRIES or not all(_name(x) for x in levels):
                return f"{k}: must be a list of level names"
        pid = request.get("pid")
        if pid is not None and not _count(pid):
            return "pid: must be a process id"
        if not _text(request.get("host")) or not _text(request.get("proof")) or not _text(request.get("nonce")):
            return "host, proof, nonce: must be short texts"
    elif op in ("update", "retract"):
        if not _name(request.get("id")):
            return "id: must be a hypothesis id"
        if op == "update":
            body = request.get("body")
            if body is not None and type(body) is not dict:
                return "body: must be a map"
            cred = request.get("credibility")
            if cred is not None and not (_finite(cred) and 0 <= cred <= 1):
                return "credibility: must be a number in [0, 1]"
    return None
