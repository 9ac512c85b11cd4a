"""Agents on several machines (transport mode 3), with real processes over zenoh on loopback:
``mapinterp run --listen --remote`` waits for ``mapinterp agent --connect`` processes, counts them
like local agents, and they stop by themselves when the run ends."""

from __future__ import annotations

import contextlib
import os
import queue
import shlex
import signal
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import pytest

from blackboard.config import ZenohOptions, loopback_endpoint, open_session, zenoh_config
from blackboard.errors import AgentError
from blackboard.runtime import Runtime
from blackboard.trace import read_trace
from knowledge_sources.commands.agent import command_line, format_option, parse_option
from knowledge_sources.mission import agent_plan, run_mission
from knowledge_sources.results import load_results
from models.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
AGENTS = "tests.blackboard.agents"
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
#: a process must have printed/exited within this long (generous: 2 shared cores)
PATIENCE_S = 60.0


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "knowledge_sources.cli", *args]


def _doubler_agent(run_id: str, endpoint: str, secret: str) -> list[str]:
    """``mapinterp agent`` running the test Doubler as ``doubler`` for run ``run_id`` at ``endpoint``."""
    return _cli(
        "agent", f"{AGENTS}:Doubler", "--name", "doubler", "--run-id", run_id, "--connect", endpoint, "--secret", secret
    )


class Proc:
    """A ``mapinterp`` subprocess whose stderr lines are read by a thread (no pipe ever fills)."""

    def __init__(self, argv: list[str], *, cwd: Path) -> None:
        self.lines: queue.SimpleQueue[str | None] = queue.SimpleQueue()
        self.stderr: list[str] = []
        self.proc = subprocess.Popen(
            argv,
            cwd=cwd,
            env=ENV,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.stderr.append(line)
            self.lines.put(line)
        self.lines.put(None)

    def wait_line(self, predicate: Any, timeout_s: float = PATIENCE_S) -> str:
        """The next stderr line satisfying ``predicate``; fails at EOF or after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                line = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                pytest.fail(f"no such line within {timeout_s} s; stderr so far:\n{self.text}")
            if line is None:
                pytest.fail(f"the process exited ({self.proc.wait()}) first; stderr:\n{self.text}")
            if predicate(line):
                return line

    def wait(self, timeout_s: float = PATIENCE_S) -> int:
        code = self.proc.wait(timeout_s)
        self._reader.join(10)
        return code

    @property
    def text(self) -> str:
        return "".join(self.stderr)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self._reader.join(10)
        if self.proc.stderr is not None:
            self.proc.stderr.close()


@pytest.fixture
def procs():
    """Collects the test's subprocesses; kills any still running at the end."""
    started: list[Proc] = []

    def start(argv: list[str], cwd: Path) -> Proc:
        p = Proc(argv, cwd=cwd)
        started.append(p)
        return p

    yield start
    for p in started:
        p.close()


def _run_id() -> str:
    return f"dist-{uuid.uuid4().hex[:8]}"


def _remote_commands(run: Proc, n: int) -> list[list[str]]:
    """The ``mapinterp agent`` command lines ``mapinterp run`` printed, ready to execute."""
    lines = [run.wait_line(lambda s: s.startswith("  mapinterp agent ")) for _ in range(n)]
    return [_cli(*shlex.split(line)[1:]) for line in lines]


# -- options on the command line ---------------------------------------------------------------------

VALUES = {
    "float": 0.55,
    "int": 3,
    "bool": True,
    "none": None,
    "text": "associative",
    "digits-text": "7",
    "list": [1, 2],
    "map": {"a": 1},
    "equals-text": "a=b",
    "empty": "",
}


@pytest.mark.parametrize("value", VALUES.values(), ids=VALUES.keys())
def test_option_round_trip(value: Any) -> None:
    assert parse_option(format_option("k", value)) == ("k", value)
    argv = command_line("m:C", "a", {"k": value}, run_id="r", connect="tcp/127.0.0.1:7447")
    assert parse_option(shlex.split(shlex.join(argv))[argv.index("--option") + 1]) == ("k", value)


@pytest.mark.parametrize("text", ["novalue", "=3", " =x"])
def test_malformed_option_is_refused(text: str) -> None:
    with pytest.raises(ValueError, match="key=value"):
        parse_option(text)


# -- mapinterp agent against a Runtime of the test ------------------------------------------------------


@pytest.mark.parametrize("via_router", [False, True], ids=["node-listens", "via-a-zenoh-router"])
def test_remote_agent_counts_like_a_local_one_and_exits_at_run_end(procs, tmp_path: Path, via_router: bool) -> None:
    """A remote Doubler feeds a local Echo: the run is quiescent only once both have worked. Either
    the node listens where the agent connects, or both connect to a zenoh router (as to a zenohd)."""
    endpoint, run_id = loopback_endpoint(), _run_id()
    trace = tmp_path / "run.trace"
    router = open_session(zenoh_config(ZenohOptions(listen=[endpoint]), mode="router")) if via_router else None
    options = ZenohOptions(connect=[endpoint]) if via_router else ZenohOptions(listen=[endpoint])
    with contextlib.ExitStack() as stack:
        if router is not None:
            stack.callback(router.close)
        rt = stack.enter_context(Runtime(run_id=run_id, zenoh=options, trace_path=trace))
        rt.expect_remote(["doubler"])
        agent = procs(
            _doubler_agent(run_id, endpoint, rt.secret),
            ROOT,
        )
        rt.add(f"{AGENTS}:Echo", name="echo")
        rt.wait_joined(["doubler"], timeout_s=PATIENCE_S)
        for x in (1, 2, 3):
            rt.post("number", {"x": x})
        outcome = rt.run(timeout_s=PATIENCE_S)
        assert sorted(h.body["x"] for h in rt.hypotheses("echo")) == [2, 4, 6]
        assert outcome.agents == {"doubler": "ok", "echo": "ok"}
    # the run ended (then the router, if any, closed): the node announced it, the agent stopped by itself
    assert agent.wait() == 0, agent.text
    assert "the run ended" in agent.text
    records = read_trace(trace)
    join = next(r for r in records if r["kind"] == "agent_join" and r["agent"] == "doubler")
    assert join["pid"] == agent.proc.pid
    assert sum(r["kind"] == "post" and r["agent"] == "doubler" for r in records) == 3
    leave = [r for r in records if r["kind"] == "agent_leave" and r["agent"] == "doubler"]
    assert [r["reason"] for r in leave] == ["stopped"]  # left cleanly, before the node closed


def test_killed_remote_agent_is_detected_and_its_questions_time_out(procs, tmp_path: Path) -> None:
    endpoint, run_id = loopback_endpoint(), _run_id()
    with Runtime(run_id=run_id, zenoh=ZenohOptions(listen=[endpoint]), trace_path=tmp_path / "run.trace") as rt:
        rt.expect_remote(["echo"])
        echo = procs(
            _cli(
                "agent",
                f"{AGENTS}:Echo",
                "--name",
                "echo",
                "--run-id",
                run_id,
                "--connect",
                endpoint,
                "--secret",
                rt.secret,
            ),
            ROOT,
        )
        rt.add(f"{AGENTS}:Asker", name="asker")
        rt.wait_joined(["echo"], timeout_s=PATIENCE_S)
        echo.proc.kill()  # kill -9: no goodbye, only its liveliness token disappears
        echo.wait()
        rt.post("ask", {"to": "echo", "q": 1})  # no deadline: only liveness can end the wait
        outcome = rt.run(timeout_s=PATIENCE_S)
        timeouts = rt.hypotheses("timeout")
    assert outcome.agents["echo"].startswith("dead") and outcome.agents["asker"] == "ok"
    assert [h.body["q"] for h in timeouts] == [1] and "'echo'" in timeouts[0].body["reason"]
    assert any(r["kind"] == "agent_leave" and r["agent"] == "echo" for r in read_trace(tmp_path / "run.trace"))


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_signal_stops_the_agent_cleanly(procs, tmp_path: Path, signum: int) -> None:
    endpoint, run_id = loopback_endpoint(), _run_id()
    trace = tmp_path / "run.trace"
    with Runtime(run_id=run_id, zenoh=ZenohOptions(listen=[endpoint]), trace_path=trace) as rt:
        rt.expect_remote(["doubler"])
        agent = procs(
            _doubler_agent(run_id, endpoint, rt.secret),
            ROOT,
        )
        agent.wait_line(lambda s: "joined run" in s)
        rt.wait_joined(["doubler"], timeout_s=PATIENCE_S)
        agent.proc.send_signal(signum)
        assert agent.wait() == 0, agent.text
        assert "interrupted" in agent.text and "Traceback" not in agent.text
    leave = [r for r in read_trace(trace) if r["kind"] == "agent_leave" and r["agent"] == "doubler"]
    assert [r["reason"] for r in leave] == ["stopped"]


_NODE_ONLY = """
import sys, time
from blackboard.config import ZenohOptions
from blackboard.runtime import Runtime
rt = Runtime(run_id=sys.argv[1], zenoh=ZenohOptions(listen=[sys.argv[2]]), secret="s3cret").__enter__()
rt.expect_remote(["doubler"])
print("up", flush=True)
time.sleep(600)
"""


def test_agent_whose_node_crashes_exits_with_an_error(procs, tmp_path: Path) -> None:
    endpoint, run_id = loopback_endpoint(), _run_id()
    node = subprocess.Popen(
        [sys.executable, "-c", _NODE_ONLY, run_id, endpoint], cwd=ROOT, env=ENV, stdout=subprocess.PIPE, text=True
    )
    try:
        assert node.stdout is not None and node.stdout.readline() == "up\n"
        agent = procs(
            _doubler_agent(run_id, endpoint, "s3cret"),
            ROOT,
        )
        agent.wait_line(lambda s: "joined run" in s)
    finally:
        node.kill()  # kill -9: no run end announced
        node.wait()
        if node.stdout is not None:
            node.stdout.close()
    assert agent.wait() == 2, agent.text
    assert f"the blackboard node of run {run_id} at {endpoint} went away without ending the run" in agent.text
    assert "Traceback" not in agent.text


CANNOT_JOIN = {
    # case: (extra args, needs a node of another run, expected message part)
    "unreachable": ([], False, "cannot reach the blackboard at {endpoint} within 1 s"),
    "wrong-run-id": ([], True, "no blackboard node of run '{run_id}' at {endpoint} within 1 s"),
    "bad-factory": (["--name", "x"], False, "cannot import factory"),
    "listen": (["--listen", "tcp/127.0.0.1:7447"], False, "use --connect, not --listen"),
    "bad-option": (["--option", "nokey"], False, "--option must be key=value"),
    "bad-run-id": (["--run-id", "a/b"], False, "--run-id: run id must be 1-128 characters"),
}


@pytest.mark.parametrize(("extra", "needs_node", "expected"), CANNOT_JOIN.values(), ids=CANNOT_JOIN.keys())
def test_agent_that_cannot_join_fails_clearly(
    procs, tmp_path: Path, extra: list[str], needs_node: bool, expected: str
) -> None:
    endpoint, run_id = loopback_endpoint(), _run_id()
    factory = "no.such.module:Agent" if "--name" in extra else f"{AGENTS}:Doubler"
    argv = _cli(
        "agent",
        factory,
        "--name",
        "doubler",
        "--run-id",
        run_id,
        "--connect",
        endpoint,
        "--connect-timeout",
        "1",
        "--secret",
        "s3cret",
        *extra,
    )
    started = time.monotonic()
    if needs_node:
        with Runtime(run_id=f"{run_id}-other", zenoh=ZenohOptions(listen=[endpoint])):
            agent = procs(argv, ROOT)
            code = agent.wait()
    else:
        agent = procs(argv, ROOT)
        code = agent.wait()
    assert code == 2, agent.text
    assert expected.format(endpoint=endpoint, run_id=run_id) in agent.text
    assert agent.text.splitlines()[-1].startswith("mapinterp agent: error: ") and "Traceback" not in agent.text
    assert time.monotonic() - started < PATIENCE_S


# -- mapinterp run --remote, end to end ---------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("agents_first", [False, True], ids=["run-first", "agents-first"])
def test_run_with_remote_detectors(procs, small: Path, tmp_path: Path, agents_first: bool) -> None:
    endpoint, run_id = loopback_endpoint(), _run_id()
    out, trace = tmp_path / "r.json", tmp_path / "run.trace"
    secret = "a-secret-agreed-on-beforehand"
    run_argv = _cli(
        "run",
        str(small),
        "--listen",
        endpoint,
        "--run-id",
        run_id,
        "--remote",
        "detector-house",
        "--remote",
        "detector-tower",
        "--out",
        str(out),
        "--trace",
        str(trace),
        "--no-progress",
        *(["--secret", secret] if agents_first else []),
    )
    if agents_first:  # started before the run: they keep trying to reach it
        commands = [
            _cli(*command_line(factory, name, options, run_id=run_id, connect=endpoint, secret=secret)[1:])
            for factory, name, options in agent_plan(load_scenario(small))
            if name.startswith("detector-")
        ]
        agents = {argv[argv.index("--name") + 1]: procs(argv, tmp_path) for argv in commands}
        run = procs(run_argv, tmp_path)
        assert _remote_commands(run, 2) == commands  # what the run prints is what was started
    else:
        run = procs(run_argv, tmp_path)
        commands = _remote_commands(run, 2)  # copied from what the run printed
        assert all(
            argv[argv.index("--run-id") + 1] == run_id and argv[argv.index("--connect") + 1] == endpoint
            for argv in commands
        )
        agents = {argv[argv.index("--name") + 1]: procs(argv, tmp_path) for argv in commands}
    assert set(agents) == {"detector-house", "detector-tower"}
    assert run.wait() == 0, run.text
    for name, agent in agents.items():  # they stop by themselves at the end of the run
        assert agent.wait() == 0, (name, agent.text)
    results = load_results(out)
    local = run_mission(small)  # the same mission with every agent in one process
    keys = ("frame", "viewframe", "queries", "backtracks", "correct")
    assert [{k: f[k] for k in keys} for f in results["frames"]] == [{k: f[k] for k in keys} for f in local["frames"]]
    assert len(results["frames"]) == 8 and all(f["viewframe"] is not None for f in results["frames"])
    assert {results["agents"][name] for name in agents} == {"ok"}
    records = read_trace(trace)
    joins = {r["agent"]: r["pid"] for r in records if r["kind"] == "agent_join"}
    assert {name: joins[name] for name in agents} == {name: a.proc.pid for name, a in agents.items()}
    # every question went to a remote detector, and every one was answered by its addressee
    queries = {r["id"]: r["addressed_to"] for r in records if r["kind"] == "post" and r["level"] == "query"}
    answers = {r["links"][0]: r["agent"] for r in records if r["kind"] == "post" and r["level"] == "answer"}
    assert queries and set(queries.values()) <= set(agents) and answers == queries
    assert not [r for r in records if r["kind"] == "timeout"]


@pytest.mark.slow
def test_sharded_indexers_in_other_processes_give_the_results_of_one_process(
    procs, small_data: dict, tmp_path: Path
) -> None:
    """The route split into three shards (``memory.shard_size`` 3 of 8 route points), each indexer
    a ``mapinterp agent`` process standing in for another host: every frame's answer and ranking
    are those of the same scenario in one process, and of the unsharded scenario."""
    import yaml

    whole = tmp_path / "whole.yaml"
    whole.write_text(yaml.safe_dump(small_data))
    sharded = tmp_path / "sharded.yaml"
    sharded.write_text(yaml.safe_dump({**small_data, "memory": {"shard_size": 3}}))
    indexers = [name for _, name, _ in agent_plan(load_scenario(sharded)) if name.startswith("indexer-")]
    assert indexers == ["indexer-0", "indexer-1", "indexer-2"]
    out = tmp_path / "r.json"
    remote = [arg for name in indexers for arg in ("--remote", name)]
    run = procs(
        _cli("run", str(sharded), "--listen", loopback_endpoint(), *remote, "--out", str(out), "--no-progress"),
        tmp_path,
    )
    agents = [procs(argv, tmp_path) for argv in _remote_commands(run, len(indexers))]
    assert run.wait(3 * PATIENCE_S) == 0, run.text
    assert all(a.wait() == 0 for a in agents), [a.text for a in agents]
    results = load_results(out)
    assert {results["agents"][name] for name in indexers} == {"ok"}
    keys = ("frame", "viewframe", "queries", "backtracks", "correct")
    for local in (run_mission(sharded), run_mission(whole)):
        assert [{k: f[k] for k in keys} for f in results["frames"]] == [
            {k: f[k] for k in keys} for f in local["frames"]
        ]
        for fr, fl in zip(results["frames"], local["frames"]):  # every shard's viewframes ranked, in one order
            assert [k for k, _ in fr["ranking"]] == [k for k, _ in fl["ranking"]]
    assert len(results["frames"]) == 8 and all(f["viewframe"] is not None for f in results["frames"])


@pytest.mark.slow
def test_run_fails_when_a_remote_agent_never_joins(procs, small: Path, tmp_path: Path) -> None:
    wait_s = 10.0  # the house agent must join within it, also on a loaded machine
    run = procs(
        _cli(
            "run",
            str(small),
            "--listen",
            loopback_endpoint(),
            "--remote",
            "detector-house",
            "--remote",
            "detector-tower",
            "--wait-remote",
            str(wait_s),
            "--no-progress",
        ),
        tmp_path,
    )
    commands = _remote_commands(run, 2)
    house = procs(next(argv for argv in commands if "detector-house" in argv), tmp_path)  # the tower never starts
    house.wait_line(lambda s: "joined run" in s)
    started = time.monotonic()
    assert run.wait() == 2, run.text
    assert time.monotonic() - started < wait_s + 15  # counted from the start of waiting: no hang
    error = run.text.splitlines()[-1]
    assert error.startswith("mapinterp run: error: agent 'detector-tower': did not join run ")
    assert f"within {wait_s:g} s" in error and "Traceback" not in run.text
    assert house.wait() == 0, house.text  # the failed run still ends, and says so to its agents


def test_remote_names_must_be_agents_of_the_mission(small: Path) -> None:
    with pytest.raises(AgentError, match="'detector-church'.*its agents are: map-renderer, camera"):
        run_mission(small, remote=["detector-church"])


@pytest.mark.slow
def test_run_with_remote_detectors_over_tls(procs, small: Path, tmp_path: Path) -> None:
    """The example configs of scenarios/zenoh with certificates made here: the run over
    ``tls/127.0.0.1`` (with the user/password authentication of runs beyond loopback) gives the
    frames of the same run over tcp, and an agent that knows the secret but comes over plain tcp
    cannot join."""
    from blackboard.config import free_port
    from tests.blackboard.certs import ZENOH_EXAMPLES, make_certs

    make_certs(tmp_path)  # certs/ in the folder both sides run in, as the examples read them
    tls, run_id = f"tls/127.0.0.1:{free_port()}", _run_id()
    out, trace = tmp_path / "r.json", tmp_path / "run.trace"
    run_config, agent_config = str(ZENOH_EXAMPLES / "tls-run.json5"), str(ZENOH_EXAMPLES / "tls-agent.json5")
    run = procs(
        _cli(
            "run",
            str(small),
            "--listen",
            tls,
            "--run-id",
            run_id,
            "--remote",
            "detector-house",
            "--remote",
            "detector-tower",
            "--zenoh-config",
            run_config,
            "--auth",  # the run's secret as zenoh usrpwd too, as beyond loopback
            "--out",
            str(out),
            "--trace",
            str(trace),
            "--no-progress",
        ),
        tmp_path,
    )
    commands = _remote_commands(run, 2)
    for argv in commands:  # the run prints its own config: the agents' machines give theirs
        assert argv[argv.index("--zenoh-config") + 1] == run_config and argv[argv.index("--connect") + 1] == tls
        assert "--auth" in argv
        argv[argv.index("--zenoh-config") + 1] = agent_config
    plain = list(commands[0])
    plain[plain.index("--connect") + 1] = tls.replace("tls/", "tcp/")
    plain[plain.index("--zenoh-config") : plain.index("--zenoh-config") + 2] = ["--connect-timeout", "2"]
    intruder = procs(plain, tmp_path)
    assert intruder.wait() == 2, intruder.text
    assert "cannot reach the blackboard at tcp/127.0.0.1:" in intruder.text and "Traceback" not in intruder.text
    agents = {argv[argv.index("--name") + 1]: procs(argv, tmp_path) for argv in commands}
    assert run.wait() == 0, run.text
    for name, agent in agents.items():
        assert agent.wait() == 0, (name, agent.text)
    results = load_results(out)
    local = run_mission(small)  # every agent in one process, over tcp on loopback
    keys = ("frame", "viewframe", "queries", "backtracks", "correct")
    assert [{k: f[k] for k in keys} for f in results["frames"]] == [{k: f[k] for k in keys} for f in local["frames"]]
    assert len(results["frames"]) == 8 and {results["agents"][name] for name in agents} == {"ok"}
    records = read_trace(trace)
    answers = {r["agent"] for r in records if r["kind"] == "post" and r["level"] == "answer"}
    assert answers == set(agents)  # the remote detectors, over TLS, answered every question
    assert [r["agent"] for r in records if r["kind"] == "agent_join"].count("detector-house") == 1
