"""Running one knowledge source: its zenoh session, its agenda and its worker thread.

Zenoh callbacks only enqueue what arrives (they never call zenoh or block); the worker
thread turns hypothesis samples into :class:`Event` objects, rates them with the
knowledge source's precondition, keeps them on the agenda (a heap: highest rating first,
FIFO among equals), drops obviated activations (the triggering hypothesis was retracted or
superseded before the activation ran) and runs ``act``. Whenever the inbox and the agenda
are empty it reports ``idle`` to the node with its counters (samples received per level,
posts sent, timeouts received), which is what global quiescence is decided from.

The runner also follows the run itself: the node holds a liveliness token on
:attr:`~blackboard.keys.RunKeys.node_token` and announces the end of the run on
:attr:`~blackboard.keys.RunKeys.run_end`; :attr:`AgentRunner.ended` is set on either the
announcement or the loss of the node (:attr:`AgentRunner.node_lost`), which is how an agent
started on another machine (``mapinterp agent``) knows when to stop.
"""

from __future__ import annotations

import heapq
import hmac
import itertools
import logging
import os
import queue
import secrets
import socket
import threading
import time
import traceback
from typing import Any

import zenoh

from blackboard.codec import DEFAULT_MAX_BYTES, decode, encode
from blackboard.config import ZenohOptions, zenoh_config
from blackboard.errors import AgentError, BlackboardError, CodecError, TransportError
from blackboard.hypothesis import Hypothesis
from blackboard.keys import RunKeys
from blackboard.knowledge_source import Event, EventKind, KnowledgeSource
from blackboard.sessions import SESSIONS, SharedSession
from blackboard.trust import TAG_BYTES, attachment_bytes, join_key, proof, unseal, verify
from blackboard.zenoh_board import ZenohBoard

__all__ = ["ACTIVITY_CODES", "ACTIVITY_ROW", "AgentRunner"]

logger = logging.getLogger(__name__)

#: the sender of messages the node publishes itself (see blackboard.node)
NODE_SENDER = "@node"
_OPS = {"post": EventKind.POSTED, "update": EventKind.UPDATED, "retract": EventKind.RETRACTED}
#: activity records are sent to the node in batches of at most this many (and when idle)
_ACTIVITY_BATCH = 64
#: an agent reports idle after its inbox stayed empty this long (fewer status messages; the
#: correctness of quiescence does not depend on it, only its latency)
_IDLE_GRACE_S = 0.002
#: between two attempts to reach the node while :meth:`AgentRunner.start` waits for it
_RETRY_S = 0.2
#: how long :meth:`AgentRunner.stop` waits for the node to acknowledge the agent's leaving
_LEAVE_TIMEOUT_S = 2.0


#: an activity row, as an agent sends it in its status: ``(code, level, id, version, event, rating, t, extra)``
#: with code ``"s"`` (activation_start, extra None), ``"f"`` (activation_finish, extra duration_s) or
#: ``"o"`` (activation_obviated, extra reason); errors travel as full dict records
ACTIVITY_ROW = ("code", "level", "id", "version", "event", "rating", "t", "extra")
ACTIVITY_CODES = {
    "s": ("activation_start", None),
    "f": ("activation_finish", "duration_s"),
    "o": ("activation_obviated", "reason"),
}


class AgentRunner:
    """One knowledge source connected to the blackboard of run ``run_id``.

    ``connect`` are the endpoints of the blackboard node (a zenoh router); the session is a
    zenoh client of it, shared with the other agents of this process that have the same zenoh
    configuration (:mod:`blackboard.sessions`; the subscribers and the liveliness token are the
    agent's own). :meth:`start` joins (raises :class:`DeclarationError` if refused) and
    runs ``setup``; :meth:`stop` shuts down cleanly; :meth:`kill` drops the agent abruptly.
    :attr:`ended` is set when the node announces the end of the run, or is lost
    (:attr:`node_lost`).
    """

    def __init__(
        self,
        source: KnowledgeSource,
        *,
        run_id: str,
        connect: list[str],
        zenoh_options: ZenohOptions | None = None,
        max_message_bytes: int = DEFAULT_MAX_BYTES,
        secret: str | None = None,
    ) -> None:
        self.source = source
        self._secret = secret  # proves at join that this agent is the one the run expects
        self.name = source.name
        self.keys = RunKeys(run_id)
        self._config = zenoh_config(zenoh_options, mode="client", connect=connect)
        self.connect = list(connect)
        self._max = max_message_bytes
        self._inbox: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()
        self._agenda: list[tuple[float, int, Event]] = []
        self._order = itertools.count()
        self._latest: dict[str, int] = {}  # id -> newest version seen
        self._retracted: set[str] = set()
        self._recv: dict[str, int] = {}
        self._timeouts = 0
        self._failures = 0
        self._activity: list[tuple | dict] = []
        self._probe: int | None = None
        self._status_seq = 0
        self._dead: str | None = None
        self._session: zenoh.Session | None = None
        self._hold: SharedSession | None = None  # this agent's hold on the shared session
        self._thread: threading.Thread | None = None
        self._entities: list[Any] = []
        self.board: ZenohBoard | None = None
        self.done = threading.Event()
        #: set when the node announces the end of the run, or its liveliness token disappears
        self.ended = threading.Event()
        self.node_lost = False
        self._node_seen = threading.Event()
        self._end_announced = False

    # -- lifecycle ---------------------------------------------------------------------------------

    def start(self, *, wait_s: float = 0.0) -> None:
        """Open the session, subscribe, join the node, declare liveliness, run ``setup``, start working.

        ``wait_s`` > 0: keep trying to reach the endpoints, and wait for the node of this run,
        for up to that long (an agent started before the run, or on another machine).

        Raises:
            TransportError: the node cannot be reached (within ``wait_s``), or no node of this
                run is there.
            DeclarationError: the node refused the declaration (e.g. a second exclusive writer).
            AgentError: ``setup`` raised (the agent is reported dead).
        """
        deadline = time.monotonic() + wait_s
        self._session = session = self._open(wait_s, deadline)
        put = self._inbox.put
        self._entities.append(session.declare_subscriber(self.keys.run_end, self._on_run_end))
        self._entities.append(
            session.liveliness().declare_subscriber(self.keys.node_token, self._on_node_token, history=True)
        )
        if wait_s > 0 and not self._node_seen.wait(max(0.0, deadline - time.monotonic())):
            self._close_session()
            raise TransportError(
                f"no blackboard node of run {self.keys.run_id!r} at {', '.join(self.connect)} "
                f"within {wait_s:g} s (is the run started, with this --run-id?)"
            )
        for level in self.source.consumes:
            self._entities.append(session.declare_subscriber(self.keys.level(level), lambda s: put(("hyp", s))))
        self._entities.append(session.declare_subscriber(self.keys.inbox(self.name), lambda s: put(("ctl", s))))
        self._entities.append(session.declare_subscriber(self.keys.probe, lambda s: put(("probe", s))))
        self.board = ZenohBoard(
            session, self.keys, self.name, produces=self.source.produces, max_message_bytes=self._max
        )
        try:
            self._join()
        except BlackboardError:
            self._close_session()
            raise
        self._entities.append(session.liveliness().declare_token(self.keys.liveliness(self.name)))
        try:
            self.source.setup(self.board)
        except Exception as err:  # an agent's own code: report, do not crash the runtime
            reason = f"setup failed: {type(err).__name__}: {err}"
            self._report_dead(reason, input_error=self._input_error(err))
            self._close_session()
            raise AgentError(self.name, reason) from err
        self._thread = threading.Thread(target=self._work, name=f"agent-{self.name}", daemon=True)
        self._thread.start()

    def _join(self) -> None:
        """Join the run (see :mod:`blackboard.trust`): ask the node for a challenge, prove the
        join secret against it, take the agent and run keys from the reply sealed for us. Replies
        of other sessions on the node's key (a forged challenge, a forged welcome) are ignored:
        only the node knows the secret that the challenge's proof and the keys' seal need."""
        board, secret, run_id, name = self.board, self._secret or "", self.keys.run_id, self.name
        assert board is not None
        mine, offered = secrets.token_hex(16), []

        def challenge(reply: dict) -> str | None:
            nonce, shown = reply.get("nonce"), reply.get("proof")
            if not isinstance(nonce, str) or not isinstance(shown, str):
                return None
            offered.append(nonce)
            return nonce if hmac.compare_digest(shown, proof(secret, "challenge", run_id, name, mine, nonce)) else None

        try:
            nonce = board._request_authentic({"op": "challenge", "nonce": mine}, challenge)
        except TransportError:
            if not offered:
                raise
            # none proves itself: a wrong (or no) secret, most likely; join anyway, so that the
            # node's refusal says why
            nonce = offered[0]
        keys = board._request_authentic(
            {
                "op": "join",
                "consumes": list(self.source.consumes),
                "produces": list(self.source.produces),
                "exclusive": list(self.source.exclusive),
                "pid": os.getpid(),
                "host": socket.gethostname()[:200],
                "nonce": nonce,
                "proof": proof(secret, "join", run_id, name, nonce) if self._secret is not None else None,
            },
            lambda reply: unseal(join_key(secret, run_id, name, nonce), reply.get("keys")),
        )
        if len(keys) != 64:
            raise TransportError(f"agent {name!r}: the node's join reply holds no keys (not a mapinterp node)")
        board.agent_key, board.run_key = keys[:32], keys[32:]

    def _open(self, wait_s: float, deadline: float) -> zenoh.Session:
        """The client session (shared, :mod:`blackboard.sessions`); retried until ``deadline``
        when ``wait_s`` > 0."""
        while True:
            try:
                self._hold = SESSIONS.acquire(self._config, scope=self.keys.run_id)
                return self._hold.session
            except TransportError:
                if time.monotonic() + _RETRY_S > deadline:
                    if wait_s <= 0:
                        raise
                    raise TransportError(
                        f"cannot reach the blackboard at {', '.join(self.connect)} within "
                        f"{wait_s:g} s (nothing listens there, or not reachable from here)"
                    ) from None
            time.sleep(_RETRY_S)

    def _from_node(self, sample: zenoh.Sample) -> bool:
        """True when ``sample`` carries the run key's tag (the node sent it, or a joined agent)."""
        run_key = self.board.run_key if self.board is not None else None
        tag = attachment_bytes(sample)
        return verify(run_key, sample.payload.to_bytes(), None if tag is None else tag[-TAG_BYTES:])

    def _on_run_end(self, sample: zenoh.Sample) -> None:
        """Zenoh callback: only sets an event (once the announcement proved to come from the node)."""
        if not self._from_node(sample):
            logger.warning("agent %s: ignored a run end not signed by the node", self.name)
            return
        self._end_announced = True
        self.ended.set()

    def _on_node_token(self, sample: zenoh.Sample) -> None:
        """Zenoh callback: only sets events."""
        if sample.kind == zenoh.SampleKind.PUT:
            self._node_seen.set()
        elif self._node_seen.is_set() and not self._end_announced:
            self.node_lost = True
            self.ended.set()

    def stop(self, timeout_s: float = 10.0, *, leave: bool = True) -> None:
        """Finish the current activation (waiting up to ``timeout_s``), run ``shutdown``, leave
        (unless not ``leave``: an interrupted run does not wait for the node's answer), close the
        session."""
        if self._thread is not None:
            self._inbox.put(("stop", None))
            self._thread.join(timeout_s)
            self._thread = None
        if self._session_open():
            try:
                self.source.shutdown()
            except Exception:  # the agent's own code
                logger.exception("agent %s: shutdown raised", self.name)
            self._flush(state="stopped")
            if leave:
                self._leave()
        self._close_session()
        self.done.set()

    def _leave(self) -> None:
        """Tell the node this agent stops, and wait for its answer: the liveliness token dropped
        next is then never taken for a death (a token's undeclaration may overtake a status put)."""
        if self._session is None or self.node_lost:
            return
        try:
            payload = encode({"op": "leave", "agent": self.name})
            attachment = self.board._tags(payload) if self.board is not None else None
            for _ in self._session.get(
                self.keys.request,
                payload=payload,
                attachment=attachment,
                timeout=_LEAVE_TIMEOUT_S,
                congestion_control=zenoh.CongestionControl.BLOCK,
            ):
                pass
        except (zenoh.ZError, CodecError) as err:
            logger.warning("agent %s: could not say goodbye to the node: %s", self.name, err)

    def kill(self) -> None:
        """Drop the agent abruptly (tests: an agent that dies): its subscribers and liveliness
        token go, as with a session of its own closed; no shutdown, no goodbye."""
        self._inbox.put(("kill", None))
        if self._thread is not None:
            self._thread.join(10.0)
            self._thread = None
        self._close_session()
        self.done.set()

    def _session_open(self) -> bool:
        return self._hold is not None and self._hold.open

    def _close_session(self) -> None:
        """Undeclare this agent's subscribers and token (newest first) and give the shared session back."""
        if self._hold is not None:
            self._hold.release(reversed(self._entities))
        self._entities.clear()

    # -- worker ------------------------------------------------------------------------------------

    def _work(self) -> None:
        while True:
            if self._dead is not None:
                item = self._inbox.get()
                if item[0] in ("stop", "kill"):
                    return
                continue
            try:
                item = self._inbox.get_nowait()
            except queue.Empty:
                if self._agenda:
                    self._run_one()
                    if len(self._activity) >= _ACTIVITY_BATCH:
                        self._flush(state="busy")
                    continue
                try:  # under a stream of posts, do not report idle between every two of them
                    item = self._inbox.get(timeout=_IDLE_GRACE_S)
                except queue.Empty:
                    self._flush(state="idle")
                    item = self._inbox.get()
            kind, payload = item
            if kind in ("stop", "kill"):
                return
            if kind == "hyp":
                self._on_sample(payload)
            elif kind == "ctl":
                self._on_control(payload)
            elif kind == "probe":
                self._on_probe(payload)
            if len(self._activity) >= _ACTIVITY_BATCH:
                self._flush(state="busy")

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        split = self.keys.split(key)
        level = split[0] if split else "?"
        self._recv[level] = self._recv.get(level, 0) + 1  # counted as the node counts it: every sample
        if not self._from_node(sample):  # checked before decoding: a forged or outsized post costs no memory
            logger.warning("agent %s: ignored a message without the run's tag on %s", self.name, key)
            return
        if split is not None:
            try:
                wanted = self.source.wants(*split)
            except Exception as err:  # the agent's own code: decode it, as without the filter
                logger.warning("agent %s: wants() raised %s: %s", self.name, type(err).__name__, err)
                wanted = True
            if not wanted:
                return
        try:
            message = decode(sample.payload.to_bytes(), max_bytes=self._max, key=key)
            if not isinstance(message, dict) or message.get("op") not in _OPS:
                raise CodecError("not a blackboard message (no op)", key=key)
            hyp = Hypothesis.from_record(message.get("hyp"), key=key)
            if split != (hyp.level, hyp.id):
                raise CodecError(f"key does not match hypothesis {hyp.level}/{hyp.id}", key=key)
            if message.get("sender") not in (hyp.source, NODE_SENDER):
                raise CodecError(f"sender {message.get('sender')!r} posted as {hyp.source!r}", key=key)
        except CodecError as err:  # the node rejects (and traces) the same message
            logger.warning("agent %s: ignored a malformed message: %s", self.name, err)
            return
        sender, n = message.get("sender"), message.get("n")
        if isinstance(n, int) and isinstance(sender, str) and self.board is not None:
            if n > self.board.seen_from.get(sender, 0):
                self.board.seen_from[sender] = n
        kind = _OPS[message["op"]]
        if kind is EventKind.RETRACTED:
            self._retracted.add(hyp.id)
        elif hyp.version > self._latest.get(hyp.id, 0):
            self._latest[hyp.id] = hyp.version
        self._enqueue(Event(kind, hyp))

    def _on_control(self, sample: zenoh.Sample) -> None:
        if not self._from_node(sample):
            logger.warning("agent %s: ignored a control message not signed by the node", self.name)
            return
        try:
            message = decode(sample.payload.to_bytes(), max_bytes=self._max)
            if message.get("op") != "timeout":
                return
            hyp = Hypothesis.from_record(message.get("hyp"))
        except (CodecError, AttributeError) as err:
            logger.warning("agent %s: ignored a malformed control message: %s", self.name, err)
            return
        self._timeouts += 1
        heapq.heappush(
            self._agenda,
            (-float("inf"), next(self._order), Event(EventKind.TIMEOUT, hyp, str(message.get("reason", "")))),
        )

    def _on_probe(self, sample: zenoh.Sample) -> None:
        if not self._from_node(sample):
            logger.warning("agent %s: ignored a probe not signed by the node", self.name)
            return
        try:
            self._probe = int(decode(sample.payload.to_bytes())["probe"])
        except (CodecError, KeyError, TypeError, ValueError):
            logger.warning("agent %s: ignored a malformed probe", self.name)

    def _enqueue(self, event: Event) -> None:
        try:
            rating = self.source.precondition(event)
        except Exception as err:  # the agent's own code
            self._failed(event, "precondition", err)
            return
        if rating is None:
            return
        heapq.heappush(self._agenda, (-float(rating), next(self._order), event))

    def _obviated(self, event: Event) -> str | None:
        hyp = event.hypothesis
        if event.kind in (EventKind.RETRACTED, EventKind.TIMEOUT):
            return None
        if hyp.id in self._retracted:
            return "retracted before the activation ran"
        if self._latest.get(hyp.id, 0) > hyp.version:
            return f"superseded by version {self._latest[hyp.id]}"
        return None

    def _run_one(self) -> None:
        neg_rating, _, event = heapq.heappop(self._agenda)
        hyp = event.hypothesis
        # activity rows (see ACTIVITY_ROW): compact on the wire, made into trace records by the node
        head = (
            hyp.level,
            hyp.id,
            hyp.version,
            event.kind.value,
            -neg_rating if neg_rating != -float("inf") else None,
            time.time(),
        )
        why = self._obviated(event)
        if why is not None:
            self._activity.append(("o", *head, why))
            return
        self._activity.append(("s", *head, None))
        started = time.perf_counter()
        assert self.board is not None  # work is queued only after start() made the board
        try:
            if event.kind is EventKind.TIMEOUT:
                self.source.on_timeout(hyp, event.reason, self.board)
            else:
                self.source.act(event, self.board)
        except Exception as err:  # the agent's own code: trace it, keep going
            self._failed(event, "act", err, started=started)
            return
        self._activity.append(("f", *head[:5], time.time(), time.perf_counter() - started))

    def _failed(self, event: Event, where: str, err: Exception, *, started: float | None = None) -> None:
        self._failures += 1
        hyp = event.hypothesis
        message = f"{where} raised {type(err).__name__}: {err}"
        logger.warning("agent %s: %s on %s %s", self.name, message, event.kind.value, hyp.id)
        self._activity.append(
            {
                "kind": "activation_error",
                "t": time.time(),
                "level": hyp.level,
                "id": hyp.id,
                "version": hyp.version,
                "event": event.kind.value,
                "message": message,
                "traceback": traceback.format_exc(limit=8),
                "duration_s": None if started is None else time.perf_counter() - started,
            }
        )
        input_error = self._input_error(err)
        if input_error is not None:  # a user's input (file, field): no retry will help, the run must stop
            self._report_dead(message, input_error=input_error)
        elif self._failures >= self.source.max_failures:
            self._report_dead(f"{self._failures} failures, the last: {message}")

    def _input_error(self, err: Exception) -> str | None:
        try:
            message = self.source.input_error(err)
        except Exception:  # the agent's own code
            logger.exception("agent %s: input_error() raised", self.name)
            return None
        return None if message is None else str(message)[:2000]

    def _report_dead(self, reason: str, *, input_error: str | None = None) -> None:
        self._dead = reason
        self._agenda.clear()
        self._flush(state="dead", reason=reason, input_error=input_error)

    def _flush(self, *, state: str, reason: str | None = None, input_error: str | None = None) -> None:
        """Send the activity records and the counters to the node (status key)."""
        if self._session is None or not self._session_open() or self.board is None:
            return
        message = {
            "agent": self.name,
            "state": state,
            "recv": self._recv,
            "sent": self.board.sent,
            "timeouts": self._timeouts,
            "probe": self._probe,
            "activity": self._activity,
            "reason": reason,
        }
        if input_error is not None:
            message["input_error"] = input_error
        self._status_seq += 1
        message["seq"] = self._status_seq  # the node takes no status twice (no replay)
        try:  # every part is ours (str keys, flat rows): nothing for the encoder's walk to find
            data = encode(message, check=())
            self._session.put(
                self.keys.status,
                data,
                congestion_control=zenoh.CongestionControl.BLOCK,
                attachment=self.board._tags(data),
            )
        except (zenoh.ZError, CodecError) as err:
            logger.error("agent %s: cannot report status: %s", self.name, err)
        self._activity = []
