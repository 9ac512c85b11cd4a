"""The blackboard node: authoritative store, version authority, trace, liveness and quiescence.

The node opens a zenoh router (listening on ``tcp/127.0.0.1``; agents connect to it as
clients) and, as another client of it, its own session. Its callbacks only enqueue; one worker thread does everything else, so the store needs no
locking beyond what readers from other threads use.

Quiescence (global, across processes, no sleeping): the node counts every sample on each
level (including the updates and retractions it publishes itself), the one-hop posts it
received from each agent and the timeouts it sent to each agent. Agents report ``idle`` with
their own counters whenever their inbox and agenda are empty. When every live agent is idle
and caught up (received on each consumed level what the node counted, the node received all
its posts, it received all its timeouts), nothing is deferred and no addressed post waits for
its deadline, the node sends a probe; if every live agent answers the probe idle and no new
sample, timeout or request arrived in between, the run is quiescent.

Agents on other machines (``mapinterp agent --connect``) join like local ones and count alike
for quiescence and liveness. The node holds a liveliness token (:func:`~blackboard.agent.node_token_key`)
while it is up; :meth:`BlackboardNode.wait_joined` waits for named agents to join; on
:meth:`~BlackboardNode.close` the node announces the end of the run
(:func:`~blackboard.agent.run_end_key`) and gives the agents still connected a moment to leave.
"""

from __future__ import annotations

import heapq
import logging
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from blackboard.agent import ACTIVITY_CODES, ACTIVITY_ROW, NODE_SENDER, node_token_key, run_end_key
from blackboard.codec import DEFAULT_MAX_BYTES, decode, encode
from blackboard.config import ZenohOptions, loopback_endpoint, open_session, zenoh_config
from blackboard.errors import CodecError
from blackboard.hypothesis import NAME_PATTERN, Hypothesis
from blackboard.keys import RunKeys
from blackboard.knowledge_source import Event, EventKind
from blackboard.trace import TraceKind, TraceWriter

__all__ = ["BlackboardNode", "AgentState", "NODE_SENDER"]

logger = logging.getLogger(__name__)

_MAX_UNREPORTED = 100_000
#: on close, how long the node waits for the agents still connected to leave after the run end
END_GRACE_S = 5.0
_ACTIVITY_KINDS = {k.value: k for k in (TraceKind.ACTIVATION_START, TraceKind.ACTIVATION_FINISH,
                                        TraceKind.ACTIVATION_ERROR, TraceKind.ACTIVATION_OBVIATED)}
_ROW_CODES = {code: (TraceKind(kind), extra) for code, (kind, extra) in ACTIVITY_CODES.items()}
_ROW_FIELDS = ACTIVITY_ROW[1:7]


@dataclass
class AgentState:
    """What the node knows of one agent."""

    name: str
    consumes: tuple[str, ...]
    produces: tuple[str, ...]
    exclusive: tuple[str, ...]
    pid: int | None = None
    status: dict | None = None
    timeouts_sent: int = 0
    state: str = "ok"  # ok | stopped | dead: reason

    @property
    def live(self) -> bool:
        return self.state == "ok"


@dataclass
class _Pending:
    hyp: Hypothesis
    deadline: float | None


@dataclass
class _Deferred:
    """A request waiting until the node has received the posts its sender had sent or seen."""

    after: dict[str, int]
    handler: Any
    args: tuple = field(default_factory=tuple)


def _after(agent: str, sent: int, seen: Any) -> dict[str, int]:
    after = {agent: sent}
    if isinstance(seen, dict):
        for name, n in seen.items():
            if isinstance(name, str) and isinstance(n, int):
                after[name] = max(n, after.get(name, 0))
    return after


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
        self._config = zenoh_config(ZenohOptions(config_file=options.config_file), mode="client",
                                    connect=[self.endpoint])
        self._max = max_message_bytes
        self._trace = TraceWriter(trace_path) if trace_path is not None else None
        self._inbox: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._store: dict[str, tuple[Hypothesis, bytes]] = {}
        self.agents: dict[str, AgentState] = {}
        self._any_exclusive = False
        self._level_counts: Counter[str] = Counter()
        self._received: Counter[str] = Counter()
        self._pending: dict[str, _Pending] = {}
        self._deadlines: list[tuple[float, str]] = []
        self._deferred: list[_Deferred] = []
        self._changes = 0
        self._probe = 0
        self._probe_changes: int | None = None
        self._waiters: list[threading.Event] = []
        self._tokens: set[str] = set()  # agents whose liveliness token is present
        self._join_waiters: list[tuple[frozenset[str], threading.Event]] = []
        self._gone_waiters: list[threading.Event] = []
        self.user_timeouts: list[tuple[Hypothesis, str]] = []
        self.stats: Counter[str] = Counter()
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
        except Exception:
            self._router.close()
            raise
        put = self._inbox.put
        self._entities = [
            session.declare_subscriber(self.keys.all_hypotheses, lambda s: put(("hyp", s)),
                                       allowed_origin=zenoh.Locality.REMOTE),
            session.declare_subscriber(self.keys.status, lambda s: put(("status", s))),
            session.declare_queryable(self.keys.request, lambda q: put(("request", q))),
            session.declare_queryable(self.keys.all_hypotheses, lambda q: put(("read", q))),
            session.liveliness().declare_subscriber(self.keys.liveliness_all, lambda s: put(("live", s)),
                                                    history=True),
        ]
        self._trace_write(TraceKind.RUN_START, run_id=self.keys.run_id, endpoint=self.endpoint)
        self._thread = threading.Thread(target=self._work, name=f"node-{self.keys.run_id}", daemon=True)
        self._thread.start()
        self._entities.append(session.liveliness().declare_token(node_token_key(self.keys)))

    def close(self) -> None:
        """Announce the end of the run, give the agents still connected up to :data:`END_GRACE_S`
        to leave, stop the worker, close the sessions, end and close the trace."""
        if self._thread is not None:
            gone = threading.Event()
            self._inbox.put(("end", gone))
            if not gone.wait(END_GRACE_S):
                with self._lock:
                    left = sorted(self._tokens)
                logger.warning("blackboard node: agents still connected at the end of the run: %s", ", ".join(left))
            self._inbox.put(("stop", None))
            self._thread.join(10.0)
            self._thread = None
        for session in (self._session, self._router):
            if session is not None and not session.is_closed():
                session.close()
        self._entities.clear()
        self._trace_write(TraceKind.RUN_END, stats=dict(self.stats))
        if self._trace is not None:
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
        with self._lock:
            found = [h for h, _ in self._store.values() if level is None or h.level == level]
        return sorted(found, key=lambda h: (h.timestamp, h.id))

    def wait_joined(self, names: Iterable[str]) -> threading.Event:
        """An event set once every agent in ``names`` has joined and holds its liveliness token
        (or joined and is already dead)."""
        event = threading.Event()
        self._inbox.put(("await_join", (frozenset(names), event)))
        return event

    def missing(self, names: Iterable[str]) -> list[str]:
        """Those of ``names`` that have not joined (see :meth:`wait_joined`), sorted."""
        with self._lock:
            return sorted(n for n in set(names) if not self._present(n))

    def busy_agents(self) -> list[str]:
        """Live agents that are not idle and caught up (for timeout messages)."""
        with self._lock:
            return [a.name for a in self.agents.values() if a.live and not self._caught_up(a)]

    def trace(self, kind: TraceKind, **fields: Any) -> None:
        self._trace_write(kind, **fields)

    # -- worker ------------------------------------------------------------------------------------

    def _trace_write(self, kind: TraceKind, **fields: Any) -> None:
        if self._trace is not None:
            self._trace.write(kind, **fields)

    def _work(self) -> None:
        handlers: dict[str, Callable[[Any], None]] = {"hyp": self._on_hyp, "status": self._on_status, "request": self._on_request,
                    "read": self._on_read, "live": self._on_live, "local_post": self._on_local_post,
                    "await": self._waiters.append, "listen": self._set_listener, "call": lambda fn: fn(),
                    "await_join": self._await_join, "end": self._on_end}
        bookkept = time.monotonic()
        while True:
            timeout = max(0.0, self._deadlines[0][0] - time.monotonic()) if self._deadlines else None
            try:
                kind, payload = self._inbox.get(timeout=timeout)
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
            self._fire_deadlines()
            if self._waiters:
                self._check_quiescence()

    def _publish(self, key: str, data: bytes) -> None:
        assert self._session is not None
        self._session.put(key, data, congestion_control=zenoh.CongestionControl.BLOCK)

    def _reject(self, key: str, message: str, **fields: Any) -> None:
        self.stats["rejected"] += 1
        logger.warning("blackboard node: rejected a message on %s: %s", key, message)
        self._trace_write(TraceKind.REJECTED, key=key, message=message, **fields)

    def _on_hyp(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        split = self.keys.split(key)
        level = split[0] if split else "?"
        self._level_counts[level] += 1
        self._changes += 1
        data = sample.payload.to_bytes()
        try:
            message = decode(data, max_bytes=self._max, key=key)
            if not isinstance(message, dict) or message.get("op") != "post":
                raise CodecError("not a post (only the node publishes updates and retractions)", key=key)
            sender = message.get("sender")
            if not isinstance(sender, str) or NAME_PATTERN.fullmatch(sender) is None:
                raise CodecError(f"bad sender {sender!r}", key=key)
            self._received[sender] += 1
            hyp = Hypothesis.from_record(message.get("hyp"), key=key)
        except CodecError as err:
            self._reject(key, err.message, size=len(data))
            self._run_deferred()
            return
        if split is None or (hyp.level, hyp.id) != split:
            self._reject(key, f"key does not match hypothesis {hyp.level}/{hyp.id}", agent=sender)
        else:
            self._accept_post(hyp, data, key, sender)
        self._run_deferred()

    def _on_local_post(self, hyp: Hypothesis) -> None:
        key = self.keys.hypothesis(hyp.level, hyp.id)
        data = encode({"op": "post", "hyp": hyp.to_record(), "sender": NODE_SENDER}, max_bytes=self._max)
        self._level_counts[hyp.level] += 1
        self._changes += 1
        self._publish(key, data)
        self._accept_post(hyp, data, key, hyp.source)

    def _declaration_problem(self, agent: str, level: str) -> str | None:
        state = self.agents.get(agent)
        if state is not None and level not in state.produces:
            return f"level not declared in produces {list(state.produces)}"
        if not self._any_exclusive:  # no agent ever declared an exclusive level: nothing to scan
            return None
        owner = next((a.name for a in self.agents.values() if a.live and level in a.exclusive and a.name != agent), None)
        if owner is not None:
            return f"level is written exclusively by agent {owner!r}"
        return None

    def _accept_post(self, hyp: Hypothesis, data: bytes, key: str, sender: str) -> None:
        problem = self._declaration_problem(hyp.source, hyp.level) if sender != NODE_SENDER else None
        if problem is None and hyp.id in self._store:
            problem = f"hypothesis id {hyp.id!r} already exists"
        if problem is None and hyp.source != sender and sender != NODE_SENDER:
            problem = f"sender {sender!r} posted as {hyp.source!r}"
        if problem is not None:
            self._reject(key, problem, agent=hyp.source, level=hyp.level, id=hyp.id)
            return
        with self._lock:
            self._store[hyp.id] = (hyp, data)
        self.stats["post"] += 1
        self._trace_hyp(TraceKind.POST, hyp)
        self._notify(EventKind.POSTED, hyp)
        for link in hyp.links:
            if link in self._pending:
                del self._pending[link]
        if hyp.addressed_to is not None or hyp.deadline_s is not None:
            deadline = None if hyp.deadline_s is None else time.monotonic() + hyp.deadline_s
            self._pending[hyp.id] = _Pending(hyp, deadline)
            if deadline is not None:
                heapq.heappush(self._deadlines, (deadline, hyp.id))
            addressee = self.agents.get(hyp.addressed_to) if hyp.addressed_to else None
            if addressee is not None and not addressee.live:
                self._timeout(hyp.id, f"agent {addressee.name!r} {_gone(addressee.state)}")

    def _trace_hyp(self, kind: TraceKind, hyp: Hypothesis, **extra: Any) -> None:
        if self._trace is None:
            return
        self._trace_write(kind, t=hyp.timestamp, agent=hyp.source, level=hyp.level, id=hyp.id,
                          version=hyp.version, links=list(hyp.links), credibility=hyp.credibility,
                          addressed_to=hyp.addressed_to, deadline_s=hyp.deadline_s, body=hyp.body, **extra)

    def _notify(self, kind: EventKind, hyp: Hypothesis, reason: str = "") -> None:
        event = Event(kind, hyp, reason)
        if self._listener is None:
            if len(self._unreported) < _MAX_UNREPORTED:
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

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            message = decode(sample.payload.to_bytes(), max_bytes=self._max, key=self.keys.status)
            agent = self.agents.get(message["agent"])
        except (CodecError, KeyError, TypeError) as err:
            self._reject(self.keys.status, f"malformed status: {err}")
            return
        if agent is None:
            return
        self._on_activity(agent.name, message.get("activity") or ())
        with self._lock:
            agent.status = message
        state = message.get("state")
        if state == "dead" and agent.live:
            self._agent_gone(agent, f"dead: {message.get('reason')}", TraceKind.AGENT_DEAD)
            self._check_presence()
        elif state == "stopped" and agent.live:
            agent.state = "stopped"

    def _on_activity(self, agent: str, records: Any) -> None:
        """Count and trace an agent's activity: rows (:data:`~blackboard.agent.ACTIVITY_ROW`) or
        dict records; a trace record is made only when there is a trace."""
        stats, tracing = self.stats, self._trace is not None
        for record in records:
            if type(record) is list and len(record) == 8:
                code = _ROW_CODES.get(record[0])
                if code is None:
                    continue
                kind, extra = code
                stats[kind.value] += 1
                if tracing:
                    fields = dict(zip(_ROW_FIELDS, record[1:7]))
                    if extra is not None:
                        fields[extra] = record[7]
                    self._trace_write(kind, agent=agent, **fields)
            elif isinstance(record, dict):
                old_kind = _ACTIVITY_KINDS.get(record.pop("kind", None))
                if old_kind is not None:
                    stats[old_kind.value] += 1
                    self._trace_write(old_kind, agent=agent, **record)

    def _on_live(self, sample: zenoh.Sample) -> None:
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        agent = self.agents.get(name)
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._tokens.add(name)
            else:
                self._tokens.discard(name)
        if sample.kind == zenoh.SampleKind.DELETE and agent is not None:
            if agent.live:
                self._agent_gone(agent, "dead: left (liveliness token dropped)", TraceKind.AGENT_LEAVE)
            else:
                self._trace_write(TraceKind.AGENT_LEAVE, agent=name, reason=agent.state)
        self._check_presence()

    def _present(self, name: str) -> bool:
        """Joined and holding its token, or joined and already dead (caller holds the lock)."""
        agent = self.agents.get(name)
        return agent is not None and (name in self._tokens or not agent.live)

    def _await_join(self, item: tuple[frozenset[str], threading.Event]) -> None:
        self._join_waiters.append(item)
        self._check_presence()

    def _on_end(self, gone: threading.Event) -> None:
        """Announce the end of the run; ``gone`` is set once no agent holds a token any more."""
        self._publish(run_end_key(self.keys), encode({"op": "end", "run_id": self.keys.run_id}))
        self._gone_waiters.append(gone)
        self._check_presence()

    def _check_presence(self) -> None:
        with self._lock:
            if self._join_waiters:
                waiting = []
                for names, event in self._join_waiters:
                    if all(self._present(n) for n in names):
                        event.set()
                    else:
                        waiting.append((names, event))
                self._join_waiters = waiting
            if self._gone_waiters and not self._tokens:
                for event in self._gone_waiters:
                    event.set()
                self._gone_waiters.clear()

    def _agent_gone(self, agent: AgentState, state: str, kind: TraceKind) -> None:
        with self._lock:
            agent.state = state
        self._changes += 1
        self._trace_write(kind, agent=agent.name, reason=state)
        logger.info("blackboard node: agent %s %s", agent.name, state)
        for hyp_id, pending in list(self._pending.items()):
            if pending.hyp.addressed_to == agent.name:
                self._timeout(hyp_id, f"agent {agent.name!r} {_gone(state)}")

    # -- requests ----------------------------------------------------------------------------------

    def _on_request(self, query: zenoh.Query) -> None:
        try:
            request = decode(query.payload.to_bytes() if query.payload is not None else b"", max_bytes=self._max,
                             key=self.keys.request)
            op, agent, sent = request["op"], str(request["agent"]), int(request.get("sent", 0))
        except (CodecError, KeyError, TypeError, ValueError) as err:
            self._reject(self.keys.request, f"malformed request: {err}")
            self._reply(query, {"ok": False, "error": "malformed", "message": str(err)})
            return
        if op == "join":
            self._reply(query, self._join(agent, request))
        elif op == "leave":  # a clean stop: the token dropped next is no death
            state = self.agents.get(agent)
            if state is not None and state.live:
                with self._lock:
                    state.state = "stopped"
            self._reply(query, {"ok": True})
        elif op in ("update", "retract"):
            self._deferred.append(_Deferred(_after(agent, sent, request.get("after")), self._change,
                                            (query, op, agent, request)))
            self._run_deferred()
        else:
            self._reply(query, {"ok": False, "error": "malformed", "message": f"unknown op {op!r}"})

    def _reply(self, query: zenoh.Query, reply: dict, key: str | None = None) -> None:
        try:
            query.reply(key or self.keys.request, encode(reply, max_bytes=self._max))
        except (zenoh.ZError, CodecError) as err:
            logger.error("blackboard node: cannot reply: %s", err)
        finally:
            query.drop()

    def _join(self, name: str, request: dict) -> dict:
        try:
            decl = {k: tuple(str(x) for x in request.get(k, ())) for k in ("consumes", "produces", "exclusive")}
        except TypeError as err:
            return {"ok": False, "error": "malformed", "message": str(err)}
        if NAME_PATTERN.fullmatch(name) is None:
            return {"ok": False, "error": "malformed", "message": f"bad agent name {name!r}"}
        old = self.agents.get(name)
        if old is not None and old.live:
            return {"ok": False, "error": "declaration", "level": "", "message": f"an agent named {name!r} already joined"}
        for other in self.agents.values():
            if not other.live or other.name == name:
                continue
            for level in decl["produces"]:
                if level in other.exclusive or (level in decl["exclusive"] and level in other.produces):
                    self._trace_write(TraceKind.REJECTED, agent=name, level=level,
                                      message=f"second writer of exclusive level (agent {other.name!r})")
                    return {"ok": False, "error": "declaration", "level": level,
                            "message": f"level is written exclusively, and agent {other.name!r} also writes it"}
        with self._lock:
            self.agents[name] = AgentState(name, decl["consumes"], decl["produces"], decl["exclusive"],
                                           pid=request.get("pid"))
        self._any_exclusive = self._any_exclusive or bool(decl["exclusive"])
        self._changes += 1
        self._trace_write(TraceKind.AGENT_JOIN, agent=name, pid=request.get("pid"), host=request.get("host"),
                          **{k: list(v) for k, v in decl.items()})
        self._check_presence()
        return {"ok": True}

    def _run_deferred(self) -> None:
        if not self._deferred:
            return
        ready: list[_Deferred] = []
        waiting: list[_Deferred] = []
        for d in self._deferred:
            (ready if all(self._received[a] >= n for a, n in d.after.items()) else waiting).append(d)
        if not ready:
            return
        self._deferred = waiting
        for item in ready:
            item.handler(*item.args)

    def _change(self, query: zenoh.Query, op: str, agent: str, request: dict) -> None:
        self._changes += 1
        hyp_id = request.get("id")
        entry = self._store.get(hyp_id) if isinstance(hyp_id, str) else None
        if entry is None:
            self._reply(query, {"ok": False, "error": "unknown", "message": f"no hypothesis {hyp_id!r} on the board"})
            return
        hyp = entry[0]
        problem = self._declaration_problem(agent, hyp.level)
        if problem is None and agent not in self.agents:
            problem = f"agent {agent!r} has not joined"
        if problem is not None:
            self._trace_write(TraceKind.REJECTED, agent=agent, level=hyp.level, id=hyp.id, message=f"{op}: {problem}")
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
        with self._lock:
            if op == "update":
                self._store[hyp.id] = (new, data)
            else:
                del self._store[hyp.id]
                self._pending.pop(hyp.id, None)
        self._level_counts[hyp.level] += 1
        self._publish(key, data)
        self.stats[op] += 1
        if op == "update":
            self._trace_hyp(TraceKind.UPDATE, new, by=agent)
            self._notify(EventKind.UPDATED, new)
        else:
            self._trace_write(TraceKind.RETRACT, agent=agent, level=hyp.level, id=hyp.id, version=hyp.version)
            self._notify(EventKind.RETRACTED, hyp)
        self._reply(query, {"ok": True, "hyp": new.to_record()})

    def _on_read(self, query: zenoh.Query) -> None:
        params = query.parameters
        agent = params.get("agent") or ""
        try:
            sent = int(params.get("sent") or 0)
            seen = dict((name, int(n)) for name, _, n in
                        (item.rpartition(":") for item in (params.get("after") or "").split(",") if item))
        except ValueError:
            sent, seen = 0, {}
        self._deferred.append(_Deferred(_after(agent, sent, seen), self._answer_read, (query,)))
        self._run_deferred()

    def _answer_read(self, query: zenoh.Query) -> None:
        parts = str(query.key_expr).split("/")
        try:
            if len(parts) == 4 and all("*" not in p or p == "*" for p in parts[2:]):
                level, hyp_id = parts[2], parts[3]
                with self._lock:
                    found = [(h, d) for h, d in self._store.values()
                             if level in ("*", h.level) and hyp_id in ("*", h.id)]
            else:
                selector = zenoh.KeyExpr(str(query.key_expr))
                with self._lock:
                    found = [(h, d) for h, d in self._store.values()
                             if selector.intersects(self.keys.hypothesis(h.level, h.id))]
            for hyp, data in found:
                query.reply(self.keys.hypothesis(hyp.level, hyp.id), data)
        except zenoh.ZError as err:
            logger.error("blackboard node: cannot answer a read: %s", err)
        finally:
            query.drop()

    # -- deadlines and quiescence -----------------------------------------------------------------

    def _timeout(self, hyp_id: str, reason: str) -> None:
        pending = self._pending.pop(hyp_id, None)
        if pending is None:
            return
        hyp = pending.hyp
        self._changes += 1
        self.stats["timeout"] += 1
        self._trace_write(TraceKind.TIMEOUT, agent=hyp.source, level=hyp.level, id=hyp.id, version=hyp.version,
                          addressed_to=hyp.addressed_to, reason=reason)
        self._notify(EventKind.TIMEOUT, hyp, reason)
        poster = self.agents.get(hyp.source)
        if poster is not None and poster.live:
            poster.timeouts_sent += 1
            self._publish(self.keys.inbox(poster.name),
                          encode({"op": "timeout", "hyp": hyp.to_record(), "reason": reason}, max_bytes=self._max))
        else:
            self.user_timeouts.append((hyp, reason))

    def _fire_deadlines(self) -> None:
        now = time.monotonic()
        while self._deadlines and self._deadlines[0][0] <= now:
            _, hyp_id = heapq.heappop(self._deadlines)
            pending = self._pending.get(hyp_id)
            if pending is not None:
                self._timeout(hyp_id, f"no answer within {pending.hyp.deadline_s} s"
                              + (f" from agent {pending.hyp.addressed_to!r}" if pending.hyp.addressed_to else ""))

    def _caught_up(self, agent: AgentState) -> bool:
        status = agent.status
        if status is None or status.get("state") != "idle":
            return False
        if status.get("sent", 0) != self._received[agent.name] or status.get("timeouts", 0) != agent.timeouts_sent:
            return False
        recv = status.get("recv") or {}
        return all(recv.get(level, 0) == self._level_counts[level] for level in agent.consumes)

    def _check_quiescence(self) -> None:
        live = [a for a in self.agents.values() if a.live]
        if self._deferred or not all(self._caught_up(a) for a in live):
            return
        if any(p.deadline is not None for p in self._pending.values()):
            return  # the deadline will fire
        if self._pending:
            for hyp_id, pending in list(self._pending.items()):
                self._timeout(hyp_id, f"agent {pending.hyp.addressed_to!r} went idle without answering")
            return
        if live and (self._probe_changes != self._changes):
            self._probe += 1
            self._probe_changes = self._changes
            self._publish(self.keys.probe, encode({"probe": self._probe}))
            return
        if live and not all((a.status or {}).get("probe") == self._probe for a in live):
            return
        self._trace_write(TraceKind.QUIESCENT, stats=dict(self.stats))
        for waiter in self._waiters:
            waiter.set()
        self._waiters.clear()


def _gone(state: str) -> str:
    return "left" if "left" in state else state.replace("dead: ", "is dead: ", 1) if state.startswith("dead") else state
