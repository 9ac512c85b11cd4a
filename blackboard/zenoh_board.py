"""The distributed :class:`~blackboard.knowledge_source.Board`: an agent's view of the blackboard over its zenoh session."""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING, TypeVar

import zenoh

from blackboard.codec import DEFAULT_MAX_BYTES, decode, encode
from blackboard.errors import BlackboardError, CodecError, DeclarationError, TransportError
from blackboard.hypothesis import Hypothesis, validate_name
from blackboard.trust import PRIVATE_LEVELS, SEALED, read_message, seal, sign

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

    from blackboard.keys import RunKeys

__all__ = ["REQUEST_TIMEOUT_S", "ZenohBoard"]

logger = logging.getLogger(__name__)
T = TypeVar("T")

#: how long a request to the blackboard node may take before TransportError
REQUEST_TIMEOUT_S = 10.0


class ZenohBoard:
    """What an agent sees of the blackboard, bound to its zenoh session (no global state);
    implements :class:`~blackboard.knowledge_source.Board`.

    A new post travels one hop: it is published on ``mapinterp/<run>/<level>/<id>``, which the
    node (store, trace) and the consumers receive at once. Updates and retractions go to the
    node, which assigns versions serially, so concurrent updates never lose a write.
    Reads come from the node's store and see this agent's own earlier posts.
    """

    def __init__(
        self,
        session: zenoh.Session,
        keys: RunKeys,
        agent: str,
        *,
        produces: Iterable[str] | None,
        max_message_bytes: int = DEFAULT_MAX_BYTES,
    ) -> None:
        self._session = session
        self._keys = keys
        self.agent = agent
        self._produces = None if produces is None else frozenset(produces)
        self._levels_ok: set[str] = set()  # levels that passed _check_level (checked once)
        self._max = max_message_bytes
        self._lock = threading.Lock()
        #: this agent's own key and the run's shared key, handed out by the node at join
        #: (:mod:`blackboard.trust`); None before joining
        self.agent_key: bytes | None = None
        self.run_key: bytes | None = None
        self.sent = 0  # one-hop posts published so far (quiescence accounting)
        #: sender -> highest post number seen from it; the node answers this agent's requests only
        #: after it has received those posts too (so an update of a post just seen never misses it)
        self.seen_from: dict[str, int] = {}

    def _check_level(self, level: str) -> None:
        if type(level) is str and level in self._levels_ok:
            return
        validate_name(level, "level")
        if self._produces is not None and level not in self._produces:
            raise DeclarationError(self.agent, level, f"not declared in produces {sorted(self._produces)}")
        if len(self._levels_ok) < 1024:
            self._levels_ok.add(level)

    def post(
        self,
        level: str,
        body: dict,
        *,
        links: Iterable[str] = (),
        credibility: float = 1.0,
        id: str | None = None,
        addressed_to: str | None = None,
        deadline_s: float | None = None,
    ) -> Hypothesis:
        """Post a new hypothesis (version 1) on ``level``; returns it.

        With ``addressed_to``, the addressee is expected to post a hypothesis linking to this one
        (within ``deadline_s`` if given); otherwise this agent's ``on_timeout`` is called.

        Raises:
            DeclarationError: ``level`` is not in this agent's ``produces``.
            CodecError: ``body`` cannot be encoded or is larger than the message limit.
            ValueError: a bad id, link, credibility or deadline.
        """
        self._check_level(level)
        hyp = Hypothesis.new(
            level,
            body,
            source=self.agent,
            links=tuple(links),
            credibility=credibility,
            id=id,
            addressed_to=addressed_to,
            deadline_s=deadline_s,
        )
        key = self._keys.hypothesis(level, hyp.id)
        with self._lock:  # the envelope is ours (str keys, validated names): only the body needs the walk
            record = hyp.to_record()
            if level in PRIVATE_LEVELS and self.agent_key is not None:  # only the node may read it
                record["body"] = {SEALED: seal(self.agent_key, encode(hyp.body, max_bytes=self._max))}
            data = encode(
                {"op": "post", "hyp": record, "sender": self.agent, "n": self.sent + 1},
                max_bytes=self._max,
                check=((hyp.body, 2),),
            )
            try:
                self._session.put(
                    key, data, congestion_control=zenoh.CongestionControl.BLOCK, attachment=self._tags(data, both=True)
                )
            except zenoh.ZError as err:
                raise TransportError(f"agent {self.agent!r}: cannot publish on {key}: {err}") from None
            self.sent += 1
        return hyp

    def update(self, hypothesis_id: str, *, body: dict | None = None, credibility: float | None = None) -> Hypothesis:
        """Merge ``body`` into the hypothesis' body (top-level keys) and/or set its credibility;
        the node assigns the next version. Returns the new version.

        Raises:
            DeclarationError: its level is not in this agent's ``produces``.
            BlackboardError: no such hypothesis (never posted, or retracted).
        """
        reply = self._request({"op": "update", "id": hypothesis_id, "body": body, "credibility": credibility})
        return Hypothesis.from_record(reply["hyp"])

    def retract(self, hypothesis_id: str) -> None:
        """Remove a hypothesis from the board (consumers get a RETRACTED event).

        Raises:
            DeclarationError: its level is not in this agent's ``produces``.
            BlackboardError: no such hypothesis.
        """
        self._request({"op": "retract", "id": hypothesis_id})

    def get(self, hypothesis_id: str) -> Hypothesis | None:
        """The current version of a hypothesis from the node's store, or None."""
        validate_name(hypothesis_id, "hypothesis id")
        found = self._read(self._keys.any_level(hypothesis_id))
        return found[0] if found else None

    def query(self, level: str) -> list[Hypothesis]:
        """All hypotheses on ``level`` in the node's store, oldest first."""
        validate_name(level, "level")
        return self._read(self._keys.level(level))

    # -- transport ---------------------------------------------------------------------------------

    def _read(self, key: str) -> list[Hypothesis]:
        selector = self._keys.read_selector(key, agent=self.agent, sent=self.sent, seen=self.seen_from)
        if self.agent_key is not None:  # only an authenticated read makes the node wait for those posts
            after = ",".join(f"{name}:{n}" for name, n in self.seen_from.items())
            selector += f";tag={sign(self.agent_key, read_message(key, self.agent, str(self.sent), after)).hex()}"
        out = []
        for reply in self._get(selector, None):
            record = decode(reply, max_bytes=self._max, key=key)
            out.append(Hypothesis.from_record(record.get("hyp") if isinstance(record, dict) else None, key=key))
        out.sort(key=lambda h: (h.timestamp, h.id))
        return out

    def _request(self, request: dict) -> dict:
        """Send ``request`` to the node and return its reply; a refusal raises.

        Raises:
            TransportError: no reply.
            DeclarationError, BlackboardError: the node refused the request.
        """
        replies = self._send(request, consolidation=None)
        reply = decode(replies[0], key=self._keys.request)
        if not isinstance(reply, dict):
            raise CodecError("malformed reply from the blackboard node", key=self._keys.request)
        return self._outcome(reply)

    def _request_authentic(self, request: dict, accept: Callable[[dict], T | None]) -> T:
        """Send ``request`` (a challenge, a join) and return ``accept(reply)`` of the first reply
        it accepts (not None): every reply is looked at (no consolidation, so another session
        answering on the node's key cannot hide the node's reply); the others are ignored.

        Raises:
            TransportError: no reply accepted, nor a refusal.
            DeclarationError, BlackboardError: the node refused the request.
        """
        refusal: dict | None = None
        for data in self._send(request, consolidation=zenoh.ConsolidationMode.NONE):
            try:
                reply = decode(data, max_bytes=self._max, key=self._keys.request)
            except CodecError:
                continue
            if not isinstance(reply, dict):
                continue
            if reply.get("ok"):
                value = accept(reply)
                if value is not None:
                    return value
                logger.warning("agent %s: ignored a %s reply not from this run's node", self.agent, request["op"])
            elif refusal is None:
                refusal = reply
        if refusal is not None:
            self._outcome(refusal)
        raise TransportError(
            f"agent {self.agent!r}: no reply to its {request['op']} came from this run's node "
            "(only replies that prove nothing: not a mapinterp node of this version, or forged)"
        )

    def _send(self, request: dict, *, consolidation: zenoh.ConsolidationMode | None) -> list[bytes]:
        request = {**request, "agent": self.agent, "sent": self.sent, "after": dict(self.seen_from)}
        payload = encode(request, max_bytes=self._max)
        replies = self._get(self._keys.request, payload, attachment=self._tags(payload), consolidation=consolidation)
        if not replies:
            raise TransportError(f"agent {self.agent!r}: the blackboard node did not answer a {request['op']} request")
        return replies

    def _outcome(self, reply: dict) -> dict:
        if reply.get("ok"):
            return reply
        if reply.get("error") == "declaration":
            raise DeclarationError(self.agent, str(reply.get("level")), str(reply.get("message")))
        raise BlackboardError(f"agent {self.agent!r}: {reply.get('message')}")

    def _tags(self, data: bytes, *, both: bool = False) -> bytes | None:
        """The attachment of a message of this agent: its own tag (and the run's, for posts)."""
        if self.agent_key is None:
            return None
        tag = sign(self.agent_key, data)
        return tag + sign(self.run_key, data) if both and self.run_key is not None else tag

    def _get(
        self,
        selector: str,
        payload: bytes | None,
        *,
        attachment: bytes | None = None,
        consolidation: zenoh.ConsolidationMode | None = None,
    ) -> list[bytes]:
        try:
            replies = self._session.get(
                selector,
                payload=payload,
                timeout=REQUEST_TIMEOUT_S,
                attachment=attachment,
                congestion_control=zenoh.CongestionControl.BLOCK,
                consolidation=consolidation,
            )
            out = []
            for reply in replies:
                if reply.ok is not None:
                    out.append(reply.ok.payload.to_bytes())
                elif reply.err is not None:
                    logger.warning(
                        "agent %s: error reply to %s: %s", self.agent, selector, reply.err.payload.to_string()
                    )
            return out
        except zenoh.ZError as err:
            raise TransportError(f"agent {self.agent!r}: query {selector} failed: {err}") from None
