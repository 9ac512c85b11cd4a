"""The blackboard node: a composition of the parts that make a run's blackboard.

* :mod:`blackboard.store`: the hypotheses (versions, reads, late joiners) and the barrier that
  holds a request until the posts its requester saw have arrived;
* :mod:`blackboard.membership`: who joined, their declarations, liveliness;
* :mod:`blackboard.deadlines`: addressed posts waiting for an answer;
* :mod:`blackboard.quiescence`: the counters and the global quiescence decision;
* :mod:`blackboard.run_trace`: the trace writer and the event counters.

This module is the transport around them. The node opens a zenoh router (listening on
``tcp/127.0.0.1``; agents connect to it as clients) and, as another client of it, its own session.
Its callbacks only enqueue; one worker thread does everything else, so the parts need no locking
beyond what readers from other threads use.

Agents on other machines (``mapinterp agent --connect``) join like local ones and count alike
for quiescence and liveness. The node holds a liveliness token (:attr:`~blackboard.keys.RunKeys.node_token`)
while it is up; :meth:`BlackboardNode.wait_joined` waits for named agents to join; on
:meth:`~BlackboardNode.close` the node announces the end of the run
(:attr:`~blackboard.keys.RunKeys.run_end`) and gives the agents still connected a moment to leave.
"""

from __future__ import annotations

import hmac
import json
import logging
import os
import queue
import secrets
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import zenoh

from blackboard.agent import NODE_SENDER
from blackboard.codec import DEFAULT_MAX_BYTES, decode, encode
from blackboard.config import ZenohOptions, close_session, loopback_endpoint, open_session, zenoh_config
from blackboard.deadlines import Deadlines
from blackboard.errors import BlackboardError, CodecError, TransportError
from blackboard.hypothesis import NAME_PATTERN, Hypothesis
from blackboard.keys import RunKeys, read_parameters
from blackboard.knowledge_source import Event, EventKind
from blackboard.membership import AgentState, JoinRefused, Membership, gone_phrase
from blackboard.quiescence import Quiescence, StepKind
from blackboard.run_trace import RunTrace
from blackboard.store import Barrier, Store
from blackboard.trace import TraceKind
from blackboard.trust import (
    PRIVATE_LEVELS,
    RUN_BUDGET_BYTES,
    SEALED,
    TAG_BYTES,
    attachment_bytes,
    check_request,
    check_status,
    join_key,
    proof,
    read_message,
    seal,
    sign,
    unseal,
    verify,
)

__all__ = ["NODE_SENDER", "AgentState", "BlackboardNode"]

logger = logging.getLogger(__name__)

_MAX_UNREPORTED = 100_000
#: join challenges a name may have outstanding (older ones are forgotten, and so refused)
_MAX_CHALLENGES = 8
#: on close, how long the node waits for the agents still connected to leave after the run end
END_GRACE_S = 5.0
#: at start, how long the node waits for its links to the network it connects to, then how long
#: it asks that network for another node of its run id
JOIN_NETWORK_S = 3.0
RUN_ID_PROBE_S = 1.0


class BlackboardNode:
    """The blackboard of one run.

    Args:
        run_id: namespaces every key (``mapinterp/<run-id>/...``).
        zenoh_options: user endpoints/config; ``listen`` defaults to a free ``tcp/127.0.0.1`` port.
        trace_path: where to write the trace (None: no trace).
        max_message_bytes: larger messages are rejected (and traced).
    """

    def __init__(
        self,
        *,
        run_id: str,
        zenoh_options: ZenohOptions | None = None,
        trace_path: str | Path | None = None,
        max_message_bytes: int = DEFAULT_MAX_BYTES,
    ) -> None:
        self.keys = RunKeys(run_id)
        options = zenoh_options or ZenohOptions()
        self.endpoint = options.listen[0] if options.listen else loopback_endpoint()
        extra_listen = [] if options.listen else [self.endpoint]
        self._router_config = zenoh_config(options, mode="router", listen=extra_listen)
        # another run may only be reached through links this router makes itself
        scouts = json.loads(self._router_config.get_json("scouting/multicast/enabled")) is True
        self._joins_network = bool(json.loads(self._router_config.get_json("connect/endpoints"))) or scouts
        self._config = zenoh_config(
            ZenohOptions(config_file=options.config_file, password=options.password),
            mode="client",
            connect=[self.endpoint],
        )
        self._max = max_message_bytes
        # the trust model (blackboard.trust)
        self._run_key = os.urandom(32)  # shared with joined agents: tags the node's own messages
        self._private_key = os.urandom(32)  # the node's alone: seals its own posts of private levels
        self._expected: dict[str, str] = {}  # agent name -> its join secret
        self._agent_keys: dict[str, bytes] = {}  # joined agent -> its own key
        self._challenges: dict[str, deque[str]] = {}  # expected agent -> join nonces handed out, unused
        self._status_seq: dict[str, int] = {}
        self._stored_bytes = 0
        self.run_budget_bytes = RUN_BUDGET_BYTES
        self._trace = RunTrace(trace_path)
        self.stats = self._trace.stats
        self._store = Store(unpack=self._unpack_message)
        self._barrier = Barrier()
        self._members = Membership()
        self.agents: dict[str, AgentState] = self._members.agents
        self._deadlines = Deadlines()
        self._quiescence = Quiescence(self._barrier.received)
        self._inbox: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()
        self.user_timeouts: list[tuple[Hypothesis, str]] = []
        self._listener: Callable[[Event], None] | None = None
        self._unreported: list[Event] = []  # events while nobody listened (bounded)
        self._router: zenoh.Session | None = None
        self._session: zenoh.Session | None = None
        self._thread: threading.Thread | None = None
        self._entities: list[Any] = []

    # -- public (any thread) -----------------------------------------------------------------------

    def start(self) -> None:
        """Open the router and the node's own (client) session, declare subscribers and
        queryables, start the worker.

        The router session runs no Python: it forwards posts from producers to consumers
        without waiting for the interpreter lock the node's work holds."""
        self._router = open_session(self._router_config)
        try:
            self._session = session = open_session(self._config)
            self._refuse_run_id_in_use()
        except BaseException:
            for opened in (self._session, self._router):
                if opened is not None:
                    close_session(opened, owner="blackboard node")
            self._session = None
            raise
        put = self._inbox.put
        self._entities = [
            session.declare_subscriber(
                self.keys.all_hypotheses, lambda s: put(("hyp", s)), allowed_origin=zenoh.Locality.REMOTE
            ),
            session.declare_subscriber(self.keys.status, lambda s: put(("status", s))),
            # only this node speaks on these keys: whatever else arrives there is a forgery
            *(
                session.declare_subscriber(key, lambda s: put(("forged", s)), allowed_origin=zenoh.Locality.REMOTE)
                for key in (self.keys.probe, self.keys.run_end, self.keys.inbox("*"))
            ),
            session.declare_queryable(self.keys.request, lambda q: put(("request", q))),
            session.declare_queryable(self.keys.all_hypotheses, lambda q: put(("read", q))),
            session.liveliness().declare_subscriber(self.keys.liveliness_all, lambda s: put(("live", s)), history=True),
        ]
        self._trace.write(TraceKind.RUN_START, run_id=self.keys.run_id, endpoint=self.endpoint)
        self._thread = threading.Thread(target=self._work, name=f"node-{self.keys.run_id}", daemon=True)
        self._thread.start()
        self._entities.append(session.liveliness().declare_token(self.keys.node_token))

    def _refuse_run_id_in_use(self) -> None:
        """Raise :class:`BlackboardError` when a node of this run id is already up on the zenoh
        network this one joins, before this node declares anything (so the other run is never
        touched). Only reachable when this router connects somewhere (``connect`` endpoints, its
        own or a user config's, or multicast scouting a user config turns on): first wait up to
        :data:`JOIN_NETWORK_S` for those links to come up."""
        assert self._router is not None and self._session is not None
        if not self._joins_network:
            return
        deadline = time.monotonic() + JOIN_NETWORK_S
        info = self._router.info
        while not (list(info.routers_zid()) or list(info.peers_zid())) and time.monotonic() < deadline:
            time.sleep(0.02)
        try:
            replies = list(self._session.liveliness().get(self.keys.node_token, timeout=RUN_ID_PROBE_S))
        except zenoh.ZError as err:
            raise TransportError(f"cannot check whether run id {self.keys.run_id!r} is in use: {err}") from None
        if any(reply.ok is not None for reply in replies):
            raise BlackboardError(
                f"run id {self.keys.run_id!r} is already in use on this zenoh network (its node "
                "is up): choose another --run-id; the other run was not touched"
            )

    def expect(self, name: str, secret: str) -> None:
        """Let agent ``name`` join, proving it knows ``secret`` (see :mod:`blackboard.trust`)."""
        with self._members.lock:
            self._expected[name] = secret

    def close(self, *, grace_s: float = END_GRACE_S, reason: str | None = None) -> None:
        """Announce the end of the run, give the agents still connected up to ``grace_s`` to
        leave, stop the worker, close the sessions, end and close the trace (``reason``, e.g.
        ``"interrupted by SIGINT"``, goes into its ``run_end`` record)."""
        if self._thread is not None:
            gone = threading.Event()
            self._inbox.put(("end", gone))
            if not gone.wait(grace_s):
                logger.warning(
                    "blackboard node: agents still connected at the end of the run: %s",
                    ", ".join(self._members.connected()),
                )
            self._inbox.put(("stop", None))
            self._thread.join(max(1.0, 2 * grace_s))
            self._thread = None
        try:
            for session in (self._session, self._router):
                if session is not None:
                    close_session(session, owner="blackboard node")
            self._entities.clear()
        finally:
            end: dict[str, Any] = {"stats": dict(self.stats)}
            if reason is not None:
                end["reason"] = reason
            self._trace.write(TraceKind.RUN_END, **end)
            self._trace.close()

    def post_local(self, hyp: Hypothesis) -> None:
        """Post ``hyp`` from this process (the runtime's inputs); published by the worker."""
        self._inbox.put(("local_post", hyp))

    def wait_quiescent(self) -> threading.Event:
        """An event set when the run is next quiescent (after everything enqueued so far)."""
        event = threading.Event()
        self._inbox.put(("await", event))
        return event

    def listen(self, listener: Callable[[Event], None] | None) -> None:
        """Call ``listener`` (on the worker thread) with each POSTED, UPDATED, RETRACTED and TIMEOUT
        event, first with those that happened since the last listener was removed."""
        self._inbox.put(("listen", listener))

    def call(self, fn: Any) -> None:
        """Run ``fn()`` on the worker thread (after everything enqueued so far)."""
        self._inbox.put(("call", fn))

    def hypotheses(self, level: str | None = None) -> list[Hypothesis]:
        """The current store (all levels, or one), oldest first."""
        return self._store.hypotheses(level)

    def wait_joined(self, names: Iterable[str]) -> threading.Event:
        """An event set once every agent in ``names`` has joined and holds its liveliness token
        (or joined and is already dead)."""
        event = threading.Event()
        self._inbox.put(("await_join", (frozenset(names), event)))
        return event

    def missing(self, names: Iterable[str]) -> list[str]:
        """Those of ``names`` that have not joined (see :meth:`wait_joined`), sorted."""
        return self._members.missing(names)

    def busy_agents(self) -> list[str]:
        """Live agents that are not idle and caught up (for timeout messages)."""
        with self._members.lock:
            return [a.name for a in self.agents.values() if a.live and not self._quiescence.caught_up(a)]

    def trace(self, kind: TraceKind, **fields: Any) -> None:
        self._trace.write(kind, **fields)

    # -- worker ------------------------------------------------------------------------------------

    def _work(self) -> None:
        handlers: dict[str, Callable[[Any], Any]] = {
            "hyp": self._on_hyp,
            "status": self._on_status,
            "request": self._on_request,
            "read": self._on_read,
            "live": self._on_live,
            "local_post": self._on_local_post,
            "await": self._quiescence.waiters.append,
            "listen": self._set_listener,
            "call": lambda fn: fn(),
            "await_join": lambda item: self._members.await_join(*item),
            "end": self._on_end,
            "forged": self._on_forged,
        }
        bookkept = time.monotonic()
        while True:
            try:
                kind, payload = self._inbox.get(timeout=self._deadlines.wait_s())
            except queue.Empty:
                kind, payload = "tick", None
            if kind == "stop":
                return
            if kind != "tick":
                try:
                    handlers[kind](payload)
                except Exception:  # never let one message kill the node
                    logger.exception("blackboard node: failed to handle a %s item", kind)
            if kind != "tick" and not self._inbox.empty() and time.monotonic() - bookkept < 0.01:
                continue  # in a burst, deadlines and quiescence are checked every 10 ms
            bookkept = time.monotonic()
            try:
                for hyp_id, reason in self._deadlines.due():
                    self._timeout(hyp_id, reason)
                if self._quiescence.waiters:
                    self._check_quiescence()
            except Exception:  # never let the bookkeeping kill the node either
                logger.exception("blackboard node: bookkeeping failed")

    def _publish(self, key: str, data: bytes) -> None:
        assert self._session is not None
        self._session.put(
            key, data, congestion_control=zenoh.CongestionControl.BLOCK, attachment=sign(self._run_key, data)
        )

    # -- posts ---------------------------------------------------------------------------------------

    def _on_hyp(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        split = self.keys.split(key)
        self._quiescence.sample(split[0] if split else "?")
        data = sample.payload.to_bytes()
        try:
            message = decode(data, max_bytes=self._max, key=key)
            if not isinstance(message, dict) or message.get("op") != "post":
                raise CodecError("not a post (only the node publishes updates and retractions)", key=key)
            sender = message.get("sender")
            if not isinstance(sender, str) or NAME_PATTERN.fullmatch(sender) is None:
                raise CodecError(f"bad sender {sender!r}", key=key)
            if not verify(self._agent_keys.get(sender), data, (attachment_bytes(sample) or b"")[:TAG_BYTES]):
                raise CodecError(
                    f"not signed by a joined agent {sender!r} (a forgery, or from outside the run)", key=key
                )
            self._barrier.received_from(sender)
            record = message.get("hyp")
            if isinstance(record, dict) and record.get("level") in PRIVATE_LEVELS:
                record = {**record, "body": self._unseal(record.get("body"), key, sender)}
            hyp = Hypothesis.from_record(record, key=key)
        except CodecError as err:
            self._trace.reject(key, err.message, size=len(data))
            self._barrier.release()
            return
        if split is None or (hyp.level, hyp.id) != split:
            self._trace.reject(key, f"key does not match hypothesis {hyp.level}/{hyp.id}", agent=sender)
        else:
            self._accept_post(hyp, data, key, sender)
        self._barrier.release()

    def _unseal(self, body: Any, key: str, sender: str) -> Any:
        sealed = body.get(SEALED) if isinstance(body, dict) and len(body) == 1 else None
        plain = unseal(self._agent_keys.get(sender), sealed)
        if plain is None:
            raise CodecError("a private level's body must travel sealed with its sender's agent key", key=key)
        return decode(plain, max_bytes=self._max, key=key)

    def _on_forged(self, sample: zenoh.Sample) -> None:
        """A sample on a key only the node publishes on (probe, run end, an agent's inbox): the
        agents ignore it (no run-key tag); the trace records it."""
        self._trace.reject(
            str(sample.key_expr),
            "forged node message: only the node speaks on this key (agents ignore it)",
            size=len(sample.payload),
        )

    def _unpack_message(self, data: bytes) -> Hypothesis:
        """The hypothesis a stored message carries (the store keeps large messages only as bytes)."""
        return Hypothesis.from_record(decode(data, max_bytes=self._max)["hyp"])

    def _on_local_post(self, hyp: Hypothesis) -> None:
        key = self.keys.hypothesis(hyp.level, hyp.id)
        record = hyp.to_record()
        if hyp.level in PRIVATE_LEVELS:  # on the wire sealed with a key nobody else holds
            record["body"] = {SEALED: seal(self._private_key, encode(hyp.body, max_bytes=self._max))}
        data = encode({"op": "post", "hyp": record, "sender": NODE_SENDER}, max_bytes=self._max)
        self._quiescence.sample(hyp.level)
        self._publish(key, data)
        self._accept_post(hyp, data, key, hyp.source, local=True)

    def _accept_post(self, hyp: Hypothesis, data: bytes, key: str, sender: str, *, local: bool = False) -> None:
        problem = self._members.declaration_problem(hyp.source, hyp.level) if sender != NODE_SENDER else None
        if problem is None and not local and hyp.source not in self.agents:
            problem = f"agent {hyp.source!r} has not joined"
        if problem is None and hyp.id in self._store:
            problem = f"hypothesis id {hyp.id!r} already exists"
        if problem is None and self._stored_bytes + len(data) > self.run_budget_bytes:
            problem = (
                f"the run's memory budget of {self.run_budget_bytes} bytes is spent "
                f"({self._stored_bytes} stored, this post {len(data)})"
            )
        if problem is None and hyp.source != sender and sender != NODE_SENDER:
            problem = f"sender {sender!r} posted as {hyp.source!r}"
        if problem is not None:
            self._trace.reject(key, problem, agent=hyp.source, level=hyp.level, id=hyp.id)
            return
        # a large payload is held once, compressed: the store may drop the decoded hypothesis and decode the
        # message again when asked (not for the node's own or private posts, whose bytes carry a sealed body)
        # the budget counts what the store keeps (a long route's rendered viewframes are gigabytes of
        # messages, about a tenth of that compressed); a post is refused when its own size would overspend it
        self._stored_bytes += self._store.put(
            hyp, data, sender=None if local or hyp.level in PRIVATE_LEVELS else sender
        )
        self.stats["post"] += 1
        self._trace.hypothesis(TraceKind.POST, hyp)
        self._notify(EventKind.POSTED, hyp)
        self._deadlines.answered(hyp.links)
        if self._deadlines.expect(hyp):
            addressee = self.agents.get(hyp.addressed_to) if hyp.addressed_to else None
            if addressee is not None and not addressee.live:
                self._timeout(hyp.id, f"agent {addressee.name!r} {gone_phrase(addressee.state)}")

    def _notify(self, kind: EventKind, hyp: Hypothesis, reason: str = "") -> None:
        event = Event(kind, hyp, reason)
        if self._listener is None:
            if len(self._unreported) < _MAX_UNREPORTED:
                kept = self._store.listed(hyp.id) if kind in (EventKind.POSTED, EventKind.UPDATED) else None
                if kept is not None and kept.version == hyp.version:  # a large body: held once, compressed
                    event = Event(kind, kept, reason)
                self._unreported.append(event)
            return
        try:
            self._listener(event)
        except Exception:  # the caller's progress callback
            logger.exception("blackboard node: progress callback raised")

    def _set_listener(self, listener: Callable[[Event], None] | None) -> None:
        self._listener = listener
        if listener is not None:
            backlog, self._unreported = self._unreported, []
            for event in backlog:
                self._notify(event.kind, event.hypothesis, event.reason)

    # -- agents: status, liveliness, the end ------------------------------------------------------------

    def _on_status(self, sample: zenoh.Sample) -> None:
        data = sample.payload.to_bytes()
        try:
            message = decode(data, max_bytes=self._max, key=self.keys.status)
        except CodecError as err:
            self._trace.reject(self.keys.status, f"malformed status: {err.message}", size=len(data))
            return
        problem = check_status(message)
        name = message.get("agent") if isinstance(message, dict) else None
        agent = self.agents.get(name) if isinstance(name, str) else None
        if problem is None and agent is None:
            problem = f"agent {name!r} has not joined"
        elif problem is None and agent is not None:
            if not verify(self._agent_keys.get(agent.name), data, attachment_bytes(sample)):
                problem = f"not signed by agent {name!r} (a forgery, or from outside the run)"
            elif message.get("seq", 0) <= self._status_seq.get(agent.name, 0):
                problem = f"status {message.get('seq')} of agent {name!r} seen already (a replay)"
        if problem is not None or agent is None:
            self._trace.reject(
                self.keys.status,
                f"status refused: {problem}",
                agent=name if isinstance(name, str) and NAME_PATTERN.fullmatch(name) else None,
            )
            return
        self._status_seq[agent.name] = message.get("seq", 0)
        agent.count_failures(message.get("activity"))
        self._trace.activity(agent.name, message.get("activity") or ())
        self._members.set_status(agent, message)
        state = message.get("state")
        if state == "dead" and agent.live:
            error = message.get("input_error")
            if isinstance(error, str) and error:
                agent.input_error = error[:2000]
            self._agent_gone(agent, f"dead: {message.get('reason')}", TraceKind.AGENT_DEAD)
            self._members.check_presence()
        elif state == "stopped" and agent.live:
            agent.state = "stopped"

    def _on_live(self, sample: zenoh.Sample) -> None:
        name = self.keys.liveliness_agent(str(sample.key_expr))
        agent = self.agents.get(name)
        self._members.token(name, sample.kind == zenoh.SampleKind.PUT)
        if sample.kind == zenoh.SampleKind.DELETE and agent is not None:
            if agent.live:
                self._agent_gone(agent, "dead: left (liveliness token dropped)", TraceKind.AGENT_LEAVE)
            else:
                self._trace.write(TraceKind.AGENT_LEAVE, agent=name, reason=agent.state)
        self._members.check_presence()

    def _on_end(self, gone: threading.Event) -> None:
        """Announce the end of the run; ``gone`` is set once no agent holds a token any more."""
        self._publish(self.keys.run_end, encode({"op": "end", "run_id": self.keys.run_id}))
        self._members.await_gone(gone)

    def _agent_gone(self, agent: AgentState, state: str, kind: TraceKind) -> None:
        self._members.set_state(agent, state)
        self._quiescence.change()
        self._trace.write(kind, agent=agent.name, reason=state)
        logger.info("blackboard node: agent %s %s", agent.name, state)
        for hyp_id in self._deadlines.addressed_to(agent.name):
            self._timeout(hyp_id, f"agent {agent.name!r} {gone_phrase(state)}")

    # -- requests ----------------------------------------------------------------------------------

    def _on_request(self, query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        problem: str | None
        try:
            request = decode(payload, max_bytes=self._max, key=self.keys.request)
        except CodecError as err:
            request, problem = None, err.message
        else:
            problem = check_request(request)
        if (
            problem is None
            and request["op"] not in ("challenge", "join")
            and not verify(self._agent_keys.get(request["agent"]), payload, attachment_bytes(query))
        ):
            problem = f"{request['op']} not signed by agent {request['agent']!r} (a forgery, or from outside the run)"
        if problem is not None:
            self._trace.reject(self.keys.request, f"request refused: {problem}")
            self._reply(query, {"ok": False, "error": "malformed", "message": problem})
            return
        op, agent, sent = request["op"], request["agent"], request.get("sent", 0)
        if op == "challenge":
            self._reply(query, self._challenge(agent, request.get("nonce")))
        elif op == "join":
            self._reply(query, self._join(agent, request))
        elif op == "leave":  # a clean stop: the token dropped next is no death
            state = self.agents.get(agent)
            if state is not None and state.live:
                self._members.set_state(state, "stopped")
            self._reply(query, {"ok": True})
        elif op in ("update", "retract"):
            self._barrier.hold(
                Barrier.after(agent, sent, request.get("after")), self._change, query, op, agent, request
            )
        else:
            self._reply(query, {"ok": False, "error": "malformed", "message": f"unknown op {op!r}"})

    def _reply(self, query: zenoh.Query, reply: dict, key: str | None = None) -> None:
        try:
            query.reply(key or self.keys.request, encode(reply, max_bytes=self._max))
        except (zenoh.ZError, CodecError) as err:
            logger.error("blackboard node: cannot reply: %s", err)
        finally:
            query.drop()

    def _refuse_join(self, name: str, why: str) -> dict:
        self._trace.write(TraceKind.REJECTED, agent=name, message=f"join refused: {why}")
        return {"ok": False, "error": "declaration", "level": "", "message": f"join refused: {why}"}

    def _challenge(self, name: str, theirs: Any) -> dict:
        """A fresh nonce for the join of ``name`` (an agent this run expects) to prove against,
        with a proof over the agent's own nonce ``theirs`` that it comes from this node."""
        with self._members.lock:
            secret = self._expected.get(name)
        if secret is None:
            return self._refuse_join(name, f"agent {name!r} is not an agent of this run")
        nonce = secrets.token_hex(16)
        self._challenges.setdefault(name, deque(maxlen=_MAX_CHALLENGES)).append(nonce)
        return {
            "ok": True,
            "nonce": nonce,
            "proof": proof(secret, "challenge", self.keys.run_id, name, str(theirs), nonce),
        }

    def _join(self, name: str, request: dict) -> dict:
        with self._members.lock:
            secret = self._expected.get(name)
        if secret is None:
            return self._refuse_join(name, f"agent {name!r} is not an agent of this run")
        nonce, issued = request.get("nonce"), self._challenges.get(name)
        if not isinstance(nonce, str) or issued is None or nonce not in issued:
            return self._refuse_join(
                name,
                f"agent {name!r} did not prove it is the one this run started (its join answers no "
                "challenge of this node: a copied join sent again, or no challenge asked)",
            )
        issued.remove(nonce)  # each challenge counts once, whatever the outcome
        if not isinstance(request.get("proof"), str) or not hmac.compare_digest(
            request["proof"], proof(secret, "join", self.keys.run_id, name, nonce)
        ):
            return self._refuse_join(
                name, f"agent {name!r} did not prove it is the one this run started (wrong or no secret)"
            )
        if not set(request.get("exclusive", ())) <= set(request.get("produces", ())):
            return {"ok": False, "error": "declaration", "level": "", "message": "exclusive levels must be produced"}
        joined = self._members.join(name, request)
        if isinstance(joined, JoinRefused):
            if joined.other is not None:
                self._trace.write(
                    TraceKind.REJECTED,
                    agent=name,
                    level=joined.level,
                    message=f"second writer of exclusive level (agent {joined.other!r})",
                )
            return joined.reply
        self._quiescence.change()
        self._trace.write(
            TraceKind.AGENT_JOIN,
            agent=name,
            pid=request.get("pid"),
            host=request.get("host"),
            consumes=list(joined.consumes),
            produces=list(joined.produces),
            exclusive=list(joined.exclusive),
        )
        self._agent_keys[name] = agent_key = os.urandom(32)
        self._status_seq[name] = 0
        self._members.check_presence()
        # a query reply goes to the querying session only: the keys bind the name to that session;
        # sealed for the holder of the secret, so a session that sent a copied join learns nothing
        sealed = seal(join_key(secret, self.keys.run_id, name, nonce), agent_key + self._run_key)
        return {"ok": True, "keys": sealed}

    def _change(self, query: zenoh.Query, op: str, agent: str, request: dict) -> None:
        self._quiescence.change()
        hyp_id = request.get("id")
        hyp = self._store.get(hyp_id)
        if hyp is None:
            self._reply(query, {"ok": False, "error": "unknown", "message": f"no hypothesis {hyp_id!r} on the board"})
            return
        problem = self._members.declaration_problem(agent, hyp.level)
        if problem is None and agent not in self.agents:
            problem = f"agent {agent!r} has not joined"
        if problem is not None:
            self._trace.write(TraceKind.REJECTED, agent=agent, level=hyp.level, id=hyp.id, message=f"{op}: {problem}")
            self._reply(query, {"ok": False, "error": "declaration", "level": hyp.level, "message": problem})
            return
        try:
            if op == "update":
                body = request.get("body")
                if body is not None and not isinstance(body, dict):
                    raise ValueError("body must be a map")
                new = hyp.evolve(body=body, credibility=request.get("credibility"))
            else:
                new = hyp
            data = encode({"op": op, "hyp": new.to_record(), "sender": NODE_SENDER}, max_bytes=self._max)
        except (ValueError, CodecError) as err:
            self._reply(query, {"ok": False, "error": "invalid", "message": f"{op} of {hyp_id!r}: {err}"})
            return
        key = self.keys.hypothesis(hyp.level, hyp.id)
        if op == "update":
            self._store.put(new, data, op=op, sender=NODE_SENDER)
        else:
            self._store.remove(hyp.id)
            self._deadlines.pop(hyp.id)
        self._quiescence.level_counts[hyp.level] += 1
        self._publish(key, data)
        self.stats[op] += 1
        if op == "update":
            self._trace.hypothesis(TraceKind.UPDATE, new, by=agent)
            self._notify(EventKind.UPDATED, new)
        else:
            self._trace.write(TraceKind.RETRACT, agent=agent, level=hyp.level, id=hyp.id, version=hyp.version)
            self._notify(EventKind.RETRACTED, hyp)
        self._reply(query, {"ok": True, "hyp": new.to_record()})

    def _on_read(self, query: zenoh.Query) -> None:
        params = query.parameters
        agent, sent, seen = read_parameters(params)
        signed = read_message(str(query.key_expr), agent, params.get("sent") or "0", params.get("after") or "")
        try:
            authentic = verify(self._agent_keys.get(agent), signed, bytes.fromhex(params.get("tag") or ""))
        except ValueError:
            authentic = False
        if not authentic:  # anyone may read the store, but only a joined agent's read waits for posts
            self._answer_read(query)
            return
        self._barrier.hold(Barrier.after(agent, sent, seen), self._answer_read, query)

    def _answer_read(self, query: zenoh.Query) -> None:
        key = str(query.key_expr)
        refused = 0
        try:
            for hyp, data in self._store.select(self.keys, key):
                if hyp.level in PRIVATE_LEVELS:  # the truth is for the run's own user side only
                    refused += 1
                    continue
                query.reply(self.keys.hypothesis(hyp.level, hyp.id), data)
        except zenoh.ZError as err:
            logger.error("blackboard node: cannot answer a read: %s", err)
        finally:
            query.drop()
        if refused:
            self._trace.reject(key, f"read of a private level refused ({refused} hypotheses not served)")

    # -- deadlines and quiescence -----------------------------------------------------------------

    def _timeout(self, hyp_id: str, reason: str) -> None:
        pending = self._deadlines.pop(hyp_id)
        if pending is None:
            return
        hyp = pending.hyp
        self._quiescence.change()
        self.stats["timeout"] += 1
        self._trace.write(
            TraceKind.TIMEOUT,
            agent=hyp.source,
            level=hyp.level,
            id=hyp.id,
            version=hyp.version,
            addressed_to=hyp.addressed_to,
            reason=reason,
        )
        self._notify(EventKind.TIMEOUT, hyp, reason)
        poster = self.agents.get(hyp.source)
        if poster is not None and poster.live:
            poster.timeouts_sent += 1
            self._publish(
                self.keys.inbox(poster.name),
                encode({"op": "timeout", "hyp": hyp.to_record(), "reason": reason}, max_bytes=self._max),
            )
        else:
            self.user_timeouts.append((hyp, reason))

    def _check_quiescence(self) -> None:
        step = self._quiescence.step(self._members.live(), held=bool(self._barrier), deadlines=self._deadlines)
        if step.kind is StepKind.TIME_OUT:
            for hyp_id in step.time_out:
                pending = self._deadlines.pending.get(hyp_id)
                if pending is not None:
                    self._timeout(hyp_id, f"agent {pending.hyp.addressed_to!r} went idle without answering")
        elif step.kind is StepKind.PROBE:
            self._publish(self.keys.probe, encode({"probe": step.probe}))
        elif step.kind is StepKind.QUIESCENT:
            self._trace.write(TraceKind.QUIESCENT, stats=dict(self.stats))
            self._quiescence.release()
