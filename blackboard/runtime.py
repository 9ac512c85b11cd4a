"""The runtime: a blackboard node plus knowledge sources, run until quiescence.

Example::

    with Runtime(trace_path=Path("run.trace")) as rt:
        rt.add("tests.blackboard.agents:Doubler", name="doubler")
        rt.post("number", {"x": 21})
        outcome = rt.run(timeout_s=10)
        [h.body["x"] for h in rt.hypotheses("doubled")]      # [42]

``mode="processes"`` runs each knowledge source in its own OS process
(``python -m blackboard.agent_host``) connected to the node over ``tcp/127.0.0.1``; a child
exits when its stdin closes, so children never outlive the parent.

Agents may also run elsewhere: started with ``mapinterp agent ... --connect ENDPOINT`` against
a runtime whose node listens there (``ZenohOptions(listen=[ENDPOINT])``); :meth:`Runtime.wait_joined`
waits for them, and from then on they count like local agents (quiescence, liveness). When the
runtime closes, the node announces the end of the run and such agents stop by themselves.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import logging
import os
import select
import subprocess
import sys
import time
import uuid
import weakref
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from blackboard.agent import AgentRunner
from blackboard.codec import DEFAULT_MAX_BYTES
from blackboard.config import ZenohOptions, is_loopback
from blackboard.errors import AgentError, BlackboardError
from blackboard.hypothesis import Hypothesis, validate_name
from blackboard.knowledge_source import Event, KnowledgeSource
from blackboard.node import END_GRACE_S, BlackboardNode
from blackboard.trust import new_secret

__all__ = ["Runtime", "RunOutcome", "resolve_factory"]

logger = logging.getLogger(__name__)

#: how long an agent may take to join and set up
START_TIMEOUT_S = 30.0
#: an interrupted run (Ctrl-C, SIGTERM) waits this long for agents to stop before killing them
FAST_STOP_S = 0.25
#: runtimes of this process not yet closed (for :meth:`Runtime.abort_all`)
_LIVE: weakref.WeakSet[Runtime] = weakref.WeakSet()


@dataclass
class RunOutcome:
    """The result of :meth:`Runtime.run`.

    ``agents`` maps each agent to ``"ok"``, ``"stopped"`` or ``"dead: <reason>"``; ``timeouts``
    lists the runtime's own addressed posts that timed out, with the reason.
    """

    quiescent: bool
    hypotheses: list[Hypothesis]
    agents: dict[str, str]
    stats: dict[str, int] = field(default_factory=dict)
    timeouts: list[tuple[Hypothesis, str]] = field(default_factory=list)
    duration_s: float = 0.0
    #: agent -> the one-line message of a user's input error it died of (see AgentInputError)
    input_errors: dict[str, str] = field(default_factory=dict)
    #: agent -> its failed activations (it went on): ``"<n> failed activation(s), the last: ..."``
    failures: dict[str, str] = field(default_factory=dict)


def resolve_factory(factory: str | type[KnowledgeSource]) -> type[KnowledgeSource]:
    """The class named by ``"module:Class"`` (or the class itself).

    Raises:
        AgentError: it cannot be imported or is not a KnowledgeSource subclass.
    """
    if isinstance(factory, type):
        cls = factory
    else:
        module_name, _, attr = str(factory).partition(":")
        if not module_name or not attr:
            raise AgentError(str(factory), "factory must be 'module:Class'")
        try:
            cls = getattr(importlib.import_module(module_name), attr)
        except (ImportError, AttributeError) as err:
            raise AgentError(str(factory), f"cannot import factory: {err}") from None
    if not (isinstance(cls, type) and issubclass(cls, KnowledgeSource)):
        raise AgentError(str(factory), "factory is not a KnowledgeSource subclass")
    return cls


def _factory_name(factory: str | type[KnowledgeSource]) -> str:
    if isinstance(factory, str):
        return factory
    return f"{factory.__module__}:{factory.__qualname__}"


class Runtime:
    """A blackboard node and its agents; a context manager.

    Args:
        run_id: namespaces every key; default a fresh ``run-<hex>``.
        mode: ``"inprocess"`` (each agent its own zenoh session and thread) or ``"processes"``.
        zenoh: endpoints/config of the node (``listen`` to let others connect, ``connect`` to join
            a router); agents always connect to the node over loopback.
        trace_path: where the node writes the trace (None: no trace).
        max_message_bytes: larger messages are rejected by the node and the agents.
    """

    def __init__(
        self,
        *,
        run_id: str | None = None,
        mode: Literal["inprocess", "processes"] = "inprocess",
        zenoh: ZenohOptions | None = None,
        trace_path: str | Path | None = None,
        max_message_bytes: int = DEFAULT_MAX_BYTES,
        secret: str | None = None,
        auth: bool | None = None,
    ) -> None:
        if mode not in ("inprocess", "processes"):
            raise ValueError(f"mode must be 'inprocess' or 'processes', got {mode!r}")
        self.run_id = validate_name(run_id or f"run-{uuid.uuid4().hex[:12]}", "run id")
        self.mode = mode
        self.zenoh = zenoh or ZenohOptions()
        self.secret = secret or new_secret()
        if auth is None:  # on by default as soon as the node listens beyond this machine
            auth = any(not is_loopback(ep) for ep in self.zenoh.listen)
        if auth:
            self.zenoh = dataclasses.replace(self.zenoh, password=self.secret)
        self.max_message_bytes = max_message_bytes
        #: :attr:`secret`: agents started elsewhere (``mapinterp agent --secret``) prove with it
        #: that they belong to this run (local agents get a secret each, blackboard.trust), and
        #: with ``auth`` it is also the zenoh usrpwd password of every session of the run
        self.auth = bool(auth)
        self.node = BlackboardNode(
            run_id=self.run_id, zenoh_options=self.zenoh, trace_path=trace_path, max_message_bytes=max_message_bytes
        )
        self._runners: dict[str, AgentRunner] = {}
        self._children: dict[str, subprocess.Popen] = {}
        self._started = False

    def __enter__(self) -> Runtime:
        self.node.start()
        self._started = True
        _LIVE.add(self)
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- agents ------------------------------------------------------------------------------------

    def add(self, factory: str | type[KnowledgeSource], *, name: str, options: dict | None = None) -> None:
        """Construct and start a knowledge source; returns once it has joined and set up.

        Raises:
            AgentError: the factory cannot be imported, the agent cannot start, or setup failed.
            DeclarationError: the node refused its declaration.
        """
        if not self._started:
            raise BlackboardError("Runtime.add() needs the runtime started (use it as a context manager)")
        validate_name(name, "agent name")
        if name in self._runners or name in self._children:
            raise AgentError(name, "an agent of this name was already added")
        options = dict(options or {})
        secret = new_secret()
        self.node.expect(name, secret)
        if self.mode == "inprocess":
            source = resolve_factory(factory)(name, **options)
            runner = AgentRunner(
                source,
                run_id=self.run_id,
                connect=[self.node.endpoint],
                zenoh_options=self._agent_options(),
                max_message_bytes=self.max_message_bytes,
                secret=secret,
            )
            runner.start()
            self._runners[name] = runner
        else:
            resolve_factory(factory)  # fail early, in this process, on a bad factory
            self._spawn(_factory_name(factory), name, options, secret)

    def expect_remote(self, names: Iterable[str]) -> None:
        """Let the agents ``names``, started elsewhere with this run's :attr:`secret`, join."""
        for name in names:
            self.node.expect(validate_name(name, "agent name"), self.secret)

    def _agent_options(self) -> ZenohOptions:
        return ZenohOptions(config_file=self.zenoh.config_file, password=self.zenoh.password)

    def _spawn(self, factory: str, name: str, options: dict, secret: str) -> None:
        spec = {
            "factory": factory,
            "name": name,
            "options": options,
            "run_id": self.run_id,
            "connect": [self.node.endpoint],
            "zenoh_config": None if self.zenoh.config_file is None else str(self.zenoh.config_file),
            "max_message_bytes": self.max_message_bytes,
        }
        try:
            json.dumps(spec)
        except TypeError as err:
            raise AgentError(name, f"options must be plain data (JSON) in processes mode: {err}") from None
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.getcwd(), *sys.path])}
        proc = subprocess.Popen(
            [sys.executable, "-m", "blackboard.agent_host", json.dumps(spec)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env=env,
        )
        self._children[name] = proc
        assert proc.stdin is not None and proc.stdout is not None
        # on a pipe, not on the command line others can read: its join secret, the zenoh password
        proc.stdin.write(json.dumps({"secret": secret, "password": self.zenoh.password}).encode() + b"\n")
        proc.stdin.flush()
        ready, _, _ = select.select([proc.stdout], [], [], START_TIMEOUT_S)
        line = proc.stdout.readline().decode(errors="replace").strip() if ready else ""
        proc.stdout.close()  # after "ready" the child writes to stderr only
        if line != "ready":
            if not ready:
                reason = f"agent process did not start within {START_TIMEOUT_S} s"
            elif line.startswith("error: "):
                reason = line.removeprefix("error: ")
            else:
                reason = "agent process exited before joining (its stderr shows why)"
            proc.kill()
            proc.wait()
            if proc.stdin is not None:
                proc.stdin.close()
            del self._children[name]
            raise AgentError(name, reason)

    def wait_joined(self, names: Iterable[str], *, timeout_s: float) -> None:
        """Wait until every agent in ``names`` (started elsewhere, e.g. by ``mapinterp agent``) has
        joined this run and holds its liveliness token.

        Raises:
            AgentError: some have not joined within ``timeout_s``; names them.
        """
        if not self._started:
            raise BlackboardError("Runtime.wait_joined() needs the runtime started (use it as a context manager)")
        names = sorted(set(names))
        if not names or self.node.wait_joined(names).wait(timeout_s):
            return
        missing = self.node.missing(names)
        if missing:  # (else they joined at the last moment)
            raise AgentError(", ".join(missing), f"did not join run {self.run_id} within {timeout_s:g} s")

    def source(self, name: str) -> KnowledgeSource:
        """The knowledge source object of an in-process agent (for tests and tools).

        Raises:
            AgentError: no such in-process agent (processes mode keeps them in the children).
        """
        if name not in self._runners:
            raise AgentError(name, "no such in-process agent")
        return self._runners[name].source

    def kill(self, name: str) -> None:
        """For tests: kill -9 an agent process (processes mode) or drop its session (in-process)."""
        if name in self._children:
            self._children[name].kill()
            self._children[name].wait()
        elif name in self._runners:
            self._runners[name].kill()
        else:
            raise AgentError(name, "no such agent")

    # -- work ----------------------------------------------------------------------------------------

    def post(self, level: str, body: dict, **kw: Any) -> Hypothesis:
        """Post an input as source ``"user"`` (keywords as :meth:`Board.post`)."""
        if not self._started:
            raise BlackboardError("Runtime.post() needs the runtime started (use it as a context manager)")
        hyp = Hypothesis.new(level, body, source="user", **kw)
        self.node.post_local(hyp)
        return hyp

    def run(self, *, timeout_s: float, progress: Callable[[Event], None] | None = None) -> RunOutcome:
        """Run until quiescent: nothing pending, nothing running, in every agent.

        ``progress`` is called (on the node's thread) with every post, update, retraction and
        timeout since the previous run (or the start) until quiescence.

        Raises:
            AgentError: not quiescent within ``timeout_s``; names the agents still busy.
            BlackboardError: not quiescent and no agent busy (addressed posts still waiting).
        """
        started = time.perf_counter()
        self.node.listen(progress)
        try:
            if not self.node.wait_quiescent().wait(timeout_s):
                busy = self.node.busy_agents()
                if busy:
                    raise AgentError(
                        busy[0] if len(busy) == 1 else ", ".join(busy),
                        f"run {self.run_id} not quiescent after {timeout_s} s; still busy: " + ", ".join(busy),
                    )
                raise BlackboardError(f"run {self.run_id} not quiescent after {timeout_s} s")
        finally:
            self.node.listen(None)
        return self.snapshot(quiescent=True, duration_s=time.perf_counter() - started)

    def snapshot(self, *, quiescent: bool = False, duration_s: float = 0.0) -> RunOutcome:
        """The run as it stands (e.g. after an interruption): store, agent states, errors."""
        return RunOutcome(
            quiescent=quiescent,
            hypotheses=self.node.hypotheses(),
            agents=self.agent_states(),
            stats=dict(self.node.stats),
            timeouts=list(self.node.user_timeouts),
            duration_s=duration_s,
            input_errors={a.name: a.input_error for a in list(self.node.agents.values()) if a.input_error},
            failures={a.name: a.failed for a in list(self.node.agents.values()) if a.failed},
        )

    def hypotheses(self, level: str | None = None) -> list[Hypothesis]:
        """The node's current store (all levels, or one), oldest first."""
        return self.node.hypotheses(level)

    def agent_states(self) -> dict[str, str]:
        return {a.name: a.state for a in list(self.node.agents.values())}

    def close(self, *, fast: bool = False, reason: str | None = None) -> None:
        """Stop every agent (shutdown), then the node; waits for child processes.

        ``fast`` (an interrupted run): an activation still running is not waited for, child
        processes get :data:`FAST_STOP_S` to stop before they are killed, and the node gives
        the agents no grace to leave; ``reason`` goes into the trace's ``run_end``.
        """
        wait_s = FAST_STOP_S if fast else 10.0
        t0 = time.monotonic()
        for runner in self._runners.values():
            runner.stop(timeout_s=wait_s, leave=not fast)
        self._runners.clear()
        logger.debug("runtime %s: in-process agents stopped after %.2f s", self.run_id, time.monotonic() - t0)
        for proc in self._children.values():  # all at once: each stops in parallel
            if proc.stdin is not None:
                try:
                    proc.stdin.close()
                except OSError:
                    pass
        deadline = time.monotonic() + wait_s
        for name, proc in self._children.items():
            try:
                proc.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                if not fast:
                    logger.warning("agent process %s did not stop; killing it", name)
                if fast:  # every one left at once: they die in parallel
                    for other in self._children.values():
                        if other.poll() is None:
                            other.kill()
                proc.kill()
                proc.wait()
            logger.debug("runtime %s: agent process %s gone after %.2f s", self.run_id, name, time.monotonic() - t0)
        self._children.clear()
        _LIVE.discard(self)
        logger.debug("runtime %s: agents stopped in %.2f s", self.run_id, time.monotonic() - t0)
        if self._started:
            self.node.close(grace_s=FAST_STOP_S if fast else END_GRACE_S, reason=reason)
            self._started = False
        logger.debug("runtime %s: closed in %.2f s", self.run_id, time.monotonic() - t0)

    def abort(self) -> None:
        """Kill every child process at once (a second Ctrl-C: the process exits right after)."""
        for proc in list(self._children.values()):
            try:
                proc.kill()
                proc.wait(timeout=1.0)
            except (OSError, subprocess.TimeoutExpired):
                pass

    @staticmethod
    def abort_all() -> None:
        """:meth:`abort` every runtime of this process that is not closed."""
        for runtime in list(_LIVE):
            runtime.abort()
