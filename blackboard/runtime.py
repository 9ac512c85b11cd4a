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

import importlib
import json
import logging
import os
import select
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from blackboard.agent import AgentRunner
from blackboard.codec import DEFAULT_MAX_BYTES
from blackboard.config import ZenohOptions
from blackboard.errors import AgentError, BlackboardError
from blackboard.hypothesis import Hypothesis, validate_name
from blackboard.knowledge_source import Event, KnowledgeSource
from blackboard.node import BlackboardNode

__all__ = ["Runtime", "RunOutcome", "resolve_factory"]

logger = logging.getLogger(__name__)

#: how long an agent may take to join and set up
START_TIMEOUT_S = 30.0


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
    ) -> None:
        if mode not in ("inprocess", "processes"):
            raise ValueError(f"mode must be 'inprocess' or 'processes', got {mode!r}")
        self.run_id = validate_name(run_id or f"run-{uuid.uuid4().hex[:12]}", "run id")
        self.mode = mode
        self.zenoh = zenoh or ZenohOptions()
        self.max_message_bytes = max_message_bytes
        self.node = BlackboardNode(run_id=self.run_id, zenoh_options=self.zenoh, trace_path=trace_path,
                                   max_message_bytes=max_message_bytes)
        self._runners: dict[str, AgentRunner] = {}
        self._children: dict[str, subprocess.Popen] = {}
        self._started = False

    def __enter__(self) -> Runtime:
        self.node.start()
        self._started = True
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
        if self.mode == "inprocess":
            source = resolve_factory(factory)(name, **options)
            runner = AgentRunner(source, run_id=self.run_id, connect=[self.node.endpoint],
                                 zenoh_options=self._agent_options(), max_message_bytes=self.max_message_bytes)
            runner.start()
            self._runners[name] = runner
        else:
            resolve_factory(factory)  # fail early, in this process, on a bad factory
            self._spawn(_factory_name(factory), name, options)

    def _agent_options(self) -> ZenohOptions:
        return ZenohOptions(config_file=self.zenoh.config_file)

    def _spawn(self, factory: str, name: str, options: dict) -> None:
        spec = {"factory": factory, "name": name, "options": options, "run_id": self.run_id,
                "connect": [self.node.endpoint], "zenoh_config": None if self.zenoh.config_file is None
                else str(self.zenoh.config_file), "max_message_bytes": self.max_message_bytes}
        try:
            json.dumps(spec)
        except TypeError as err:
            raise AgentError(name, f"options must be plain data (JSON) in processes mode: {err}") from None
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.getcwd(), *sys.path])}
        proc = subprocess.Popen([sys.executable, "-m", "blackboard.agent_host", json.dumps(spec)],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        self._children[name] = proc
        assert proc.stdout is not None
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
                    raise AgentError(busy[0] if len(busy) == 1 else ", ".join(busy),
                                     f"run {self.run_id} not quiescent after {timeout_s} s; still busy: "
                                     + ", ".join(busy))
                raise BlackboardError(f"run {self.run_id} not quiescent after {timeout_s} s")
        finally:
            self.node.listen(None)
        return RunOutcome(
            quiescent=True,
            hypotheses=self.node.hypotheses(),
            agents=self.agent_states(),
            stats=dict(self.node.stats),
            timeouts=list(self.node.user_timeouts),
            duration_s=time.perf_counter() - started,
        )

    def hypotheses(self, level: str | None = None) -> list[Hypothesis]:
        """The node's current store (all levels, or one), oldest first."""
        return self.node.hypotheses(level)

    def agent_states(self) -> dict[str, str]:
        return {a.name: a.state for a in list(self.node.agents.values())}

    def close(self) -> None:
        """Stop every agent (shutdown), then the node; waits for child processes."""
        for runner in self._runners.values():
            runner.stop()
        self._runners.clear()
        for name, proc in self._children.items():
            if proc.stdin is not None:
                proc.stdin.close()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                logger.warning("agent process %s did not stop; killing it", name)
                proc.kill()
                proc.wait()
        self._children.clear()
        if self._started:
            self.node.close()
            self._started = False
