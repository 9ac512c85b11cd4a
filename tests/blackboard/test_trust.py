"""The trust model (blackboard.trust) against a real outside zenoh session on the run's loopback
port: every forgery of issue 11 is refused, recorded in the trace, and the results are unchanged;
then a seeded fuzz of every key the node listens on (>= 10,000 messages), with no crash, no stall."""

from __future__ import annotations

import json
import math
import random
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from blackboard.codec import decode, encode
from blackboard.config import ZenohOptions, close_session, open_session, zenoh_config
from blackboard.errors import CodecError, TransportError
from blackboard.hypothesis import Hypothesis
from blackboard.keys import RunKeys
from blackboard.runtime import Runtime
from blackboard.trace import read_trace
from blackboard.trust import check_request, check_status, proof, seal, sign, unseal, verify

AGENTS = "tests.blackboard.agents"
Forgery = Callable[[zenoh.Session, RunKeys, Runtime], None]


def _put(session: zenoh.Session, key: str, message: object, attachment: bytes | None = None) -> None:
    session.put(
        key,
        message if isinstance(message, bytes) else encode(message, max_bytes=1 << 30),
        congestion_control=zenoh.CongestionControl.BLOCK,
        attachment=attachment,
    )


def _request(session: zenoh.Session, keys: RunKeys, message: dict) -> dict:
    replies = list(session.get(keys.request, payload=encode(message), timeout=10))
    return decode(replies[0].ok.payload.to_bytes())


def _record(level: str, hyp_id: str, source: str, body: dict, **extra) -> dict:
    return {
        "id": hyp_id,
        "level": level,
        "source": source,
        "credibility": 1.0,
        "links": [],
        "version": 1,
        "timestamp": time.time(),
        "body": body,
        **extra,
    }


def _post(session, keys, level, hyp_id, source, body, **extra) -> None:
    _put(
        session,
        keys.hypothesis(level, hyp_id),
        {"op": "post", "hyp": _record(level, hyp_id, source, body, **extra), "sender": source, "n": 1},
    )


def _status(agent: str, **fields) -> dict:
    return {
        "agent": agent,
        "state": "idle",
        "recv": {},
        "sent": 0,
        "timeouts": 0,
        "probe": None,
        "activity": [],
        "reason": None,
        "seq": 10**6,
        **fields,
    }


#: case -> (the forgery, a fragment of the trace's "rejected" message it must leave)
FORGERIES: dict[str, tuple[Forgery, str]] = {
    "answer-as-unjoined-agent": (
        lambda s, k, rt: [_post(s, k, "answer", f"a-{i}", "detector-x", {"present": False}) for i in range(5)],
        "not signed by a joined agent 'detector-x'",
    ),
    "post-under-a-real-agents-name": (
        lambda s, k, rt: _post(s, k, "doubled", "fake-1", "doubler", {"x": 999}),
        "not signed by a joined agent 'doubler'",
    ),
    "wrong-typed-posts-under-a-real-name": (
        lambda s, k, rt: [
            _post(s, k, "doubled", f"bad-{i}", "doubler", {"x": [["not", "a", "number"]]}) for i in range(3)
        ],
        "not signed by a joined agent 'doubler'",
    ),
    "squat-an-id": (
        lambda s, k, rt: _post(s, k, "echo", "echo-squat", "echo", {"x": 0}),
        "not signed by a joined agent 'echo'",
    ),
    "deadline-1e300": (
        lambda s, k, rt: _post(s, k, "doubled", "dl-1", "doubler", {"x": 1}, deadline_s=1e300, addressed_to="echo"),
        "not signed by a joined agent 'doubler'",
    ),
    "malformed-post-under-a-real-name": (
        lambda s, k, rt: _put(s, k.hypothesis("doubled", "m-1"), {"op": "post", "sender": "doubler", "hyp": 7}),
        "not signed by a joined agent 'doubler'",
    ),
    "status-whose-recv-is-a-list": (
        lambda s, k, rt: _put(s, k.status, _status("doubler", recv=[1, 2, 3])),
        "recv: must map level names to counts",
    ),
    "status-dead": (
        lambda s, k, rt: _put(s, k.status, _status("doubler", state="dead", reason="forged")),
        "not signed by agent 'doubler'",
    ),
    "status-stopped": (
        lambda s, k, rt: _put(s, k.status, _status("echo", state="stopped")),
        "not signed by agent 'echo'",
    ),
    "fake-activity-records": (
        lambda s, k, rt: _put(
            s,
            k.status,
            _status("doubler", state="busy", activity=[["s", "number", "h-1", 1, "posted", 1.0, 1.0, None]] * 50),
        ),
        "not signed by agent 'doubler'",
    ),
    "leave": (
        lambda s, k, rt: _request(s, k, {"op": "leave", "agent": "doubler"}),
        "leave not signed by agent 'doubler'",
    ),
    "retract": (
        lambda s, k, rt: _request(s, k, {"op": "retract", "agent": "doubler", "id": "x"}),
        "retract not signed by agent 'doubler'",
    ),
    "join-unexpected-name": (
        lambda s, k, rt: _request(s, k, {"op": "join", "agent": "intruder", "produces": ["doubled"]}),
        "agent 'intruder' is not an agent of this run",
    ),
    "join-expected-name-without-proof": (
        lambda s, k, rt: (
            rt.node.expect("remote-1", "the-real-secret"),
            _request(s, k, {"op": "join", "agent": "remote-1", "proof": "guess"}),
        ),
        "agent 'remote-1' did not prove it is the one this run started",
    ),
    "join-a-live-name": (
        lambda s, k, rt: _request(s, k, {"op": "join", "agent": "doubler"}),
        "agent 'doubler' did not prove",
    ),
    "run-end": (lambda s, k, rt: _put(s, k.run_end, {"op": "end", "run_id": k.run_id}), "forged node message"),
    "probe": (lambda s, k, rt: _put(s, k.probe, {"probe": 10**9}), "forged node message"),
    "timeout-to-an-inbox": (
        lambda s, k, rt: _put(
            s, k.inbox("echo"), {"op": "timeout", "hyp": _record("query", "q", "echo", {}), "reason": "forged"}
        ),
        "forged node message",
    ),
    "large-valid-posts": (
        lambda s, k, rt: [
            _post(s, k, "doubled", f"big-{i}", "doubler", {"x": 1, "pad": bytes(5 * 1024**2)}) for i in range(10)
        ],
        "not signed by a joined agent 'doubler'",
    ),
}


@pytest.mark.parametrize("case", FORGERIES, ids=FORGERIES)
def test_forgery_from_an_outside_session_is_refused_and_traced(case: str, run_id: str, tmp_path: Path) -> None:
    forge, fragment = FORGERIES[case]
    keys = RunKeys(run_id)
    trace = tmp_path / "t.trace"
    with Runtime(run_id=run_id, trace_path=trace, max_message_bytes=64 * 1024**2) as rt:
        rt.add(f"{AGENTS}:Doubler", name="doubler")
        rt.add(f"{AGENTS}:Echo", name="echo")
        outsider = open_session(zenoh_config(ZenohOptions(), mode="client", connect=[rt.node.endpoint]))
        try:
            forge(outsider, keys, rt)
            for x in (1, 2, 3):
                rt.post("number", {"x": x})
            outcome = rt.run(timeout_s=30)  # no stall
        finally:
            close_session(outsider, owner="outsider")
        assert sorted(h.body["x"] for h in rt.hypotheses("doubled")) == [2, 4, 6]
        assert sorted(h.body["x"] for h in rt.hypotheses("echo")) == [2, 4, 6]
        assert {h.source for h in rt.hypotheses()} == {"user", "doubler", "echo"}
        assert outcome.agents == {"doubler": "ok", "echo": "ok"}
    rejected = [r["message"] for r in read_trace(trace) if r["kind"] == "rejected"]
    assert any(fragment in m for m in rejected), rejected
    assert not [r for r in read_trace(trace) if r["kind"] == "agent_join" and r["agent"] not in ("doubler", "echo")]


def test_a_join_copied_off_the_wire_is_refused_and_gains_nothing(run_id: str, tmp_path: Path) -> None:
    """An outside session that declares the node's queryable sees an agent's challenge and join
    requests and answers them with forged "welcomes": the agent ignores those and joins; the copied
    join, sent again while the agent is live, after it stopped, or with a fresh challenge of the
    attacker's, is refused each time (each nonce counts once, the proof binds it) and its replies
    hold no key."""
    keys = RunKeys(run_id)
    trace = tmp_path / "t.trace"
    seen: list[bytes] = []

    def intercept(query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        seen.append(payload)
        welcome = {"ok": True, "keys": bytes(64), "nonce": "0" * 32, "proof": "0" * 64, "agent_key": "00" * 32}
        query.reply(keys.request, encode(welcome))  # a forged welcome (and a forged challenge)

    def send(session: zenoh.Session, message: dict) -> list[dict]:
        replies = session.get(
            keys.request, payload=encode(message), timeout=10, consolidation=zenoh.ConsolidationMode.NONE
        )
        return [decode(r.ok.payload.to_bytes()) for r in replies if r.ok is not None]

    with Runtime(run_id=run_id, trace_path=trace) as rt:
        outsider = open_session(zenoh_config(ZenohOptions(), mode="client", connect=[rt.node.endpoint]))
        try:
            queryable = outsider.declare_queryable(keys.request, intercept)
            time.sleep(0.3)  # the queryable reaches the router
            rt.add(f"{AGENTS}:Doubler", name="doubler")  # joins despite the forged replies
            queryable.undeclare()
            joins = [m for m in map(decode, seen) if m.get("op") == "join"]
            assert len(joins) == 1 and joins[0]["agent"] == "doubler" and joins[0]["proof"]
            copied = joins[0]
            rt.post("number", {"x": 21})
            outcome = rt.run(timeout_s=30)
            assert [h.body["x"] for h in rt.hypotheses("doubled")] == [42] and outcome.agents == {"doubler": "ok"}
            answers = [send(outsider, copied)]  # while the agent is live
            rt._runners["doubler"].stop()
            deadline = time.monotonic() + 10
            while rt.node.agents["doubler"].live and time.monotonic() < deadline:
                time.sleep(0.05)
            assert rt.node.agents["doubler"].state == "stopped"
            answers.append(send(outsider, copied))  # after it stopped: the old code let this in
            nonce = send(outsider, {"op": "challenge", "agent": "doubler"})[0]["nonce"]
            answers.append(send(outsider, {**copied, "nonce": nonce}))  # a fresh nonce, the old proof
        finally:
            close_session(outsider, owner="outsider")
        assert rt.node.agents["doubler"].state == "stopped"  # nobody joined under its name
    for replies in answers:
        assert len(replies) == 1 and replies[0]["ok"] is False and "keys" not in replies[0], replies
    assert "a copied join sent again" in answers[0][0]["message"] and "a copied join" in answers[1][0]["message"]
    assert "wrong or no secret" in answers[2][0]["message"]
    records = read_trace(trace)
    assert [r["agent"] for r in records if r["kind"] == "agent_join"] == ["doubler"]
    assert sum("join refused: agent 'doubler'" in r.get("message", "") for r in records) == 3


@pytest.mark.parametrize("secret", ["a guess", None], ids=["wrong-secret", "no-secret"])
def test_an_agent_without_the_secret_is_told_why_it_cannot_join(run_id: str, secret: str | None) -> None:
    from blackboard.agent import AgentRunner
    from blackboard.errors import DeclarationError
    from tests.blackboard.agents import Echo

    with Runtime(run_id=run_id) as rt:
        rt.expect_remote(["remote-1"])
        runner = AgentRunner(Echo("remote-1"), run_id=run_id, connect=[rt.node.endpoint], secret=secret)
        with pytest.raises(DeclarationError, match="remote-1' did not prove it is the one this run started"):
            runner.start(wait_s=10)
        assert "remote-1" not in rt.node.agents


def test_the_truth_is_for_the_runs_own_user_side_only(run_id: str, tmp_path: Path) -> None:
    """Posted by the user side and by an agent (as the camera does): never served to a ``get``,
    unreadable on the wire to an outside session and to a joined agent (which holds the run key),
    read by the node into the results and the trace."""
    keys = RunKeys(run_id)
    trace = tmp_path / "t.trace"
    seen: list[bytes] = []
    with Runtime(run_id=run_id, trace_path=trace) as rt:
        rt.add(f"{AGENTS}:Witness", name="witness")  # posts truth {pose: [21.25, 42.5, 0.75]} on number 21
        rt.add(f"{AGENTS}:Doubler", name="doubler")  # a joined agent: it holds the run key
        run_key = rt._runners["doubler"].board.run_key
        outsider = open_session(zenoh_config(ZenohOptions(), mode="client", connect=[rt.node.endpoint]))
        try:
            outsider.declare_subscriber(keys.level("truth"), lambda s: seen.append(s.payload.to_bytes()))
            time.sleep(0.3)  # the subscription reaches the router
            rt.post("truth", {"frame": 0, "pose": [123.25, 456.5, 7.75]})
            rt.post("number", {"x": 21})
            rt.run(timeout_s=10)
            replies = [r for r in outsider.get(keys.level("truth"), timeout=5) if r.ok is not None]
            everything = [r for r in outsider.get(f"{keys.root}/**", timeout=5) if r.ok is not None]
            replies += [r for r in everything if "/truth/" in str(r.ok.key_expr)]
        finally:
            close_session(outsider, owner="outsider")
        assert everything  # the other levels are served
        poses = sorted(h.body["pose"] for h in rt.hypotheses("truth"))
        assert poses == [[21.25, 42.5, 0.75], [123.25, 456.5, 7.75]]  # the user side reads both
    assert replies == []  # never served
    assert len(seen) == 2, "both posts travelled"
    for payload in seen:  # sealed on the wire: nothing of the pose is readable, not even with the run key
        body = decode(payload)["hyp"]["body"]
        assert set(body) == {"__sealed__"} and b"123.25" not in payload and b"21.25" not in payload
        assert run_key is not None and unseal(run_key, body["__sealed__"]) is None
    records = read_trace(trace)
    assert any("read of a private level refused" in r.get("message", "") for r in records)
    assert sorted(r["body"]["pose"] for r in records if r["kind"] == "post" and r.get("level") == "truth") == poses


def test_the_runs_memory_budget_refuses_posts_with_a_trace_record(run_id: str, tmp_path: Path) -> None:
    trace = tmp_path / "t.trace"
    with Runtime(run_id=run_id, trace_path=trace) as rt:
        rt.add(f"{AGENTS}:Doubler", name="doubler")
        rt.node.run_budget_bytes = 2_000  # a few small posts only
        for x in range(40):
            rt.post("number", {"x": x})
        outcome = rt.run(timeout_s=30)
        stored = len(rt.hypotheses())
    assert outcome.quiescent and 0 < stored < 80
    assert any("memory budget" in r.get("message", "") for r in read_trace(trace) if r["kind"] == "rejected")


def test_seal_and_tags() -> None:
    key, other = b"k" * 32, b"o" * 32
    sealed = seal(key, b"the true pose")
    assert unseal(key, sealed) == b"the true pose" and unseal(other, sealed) is None
    assert unseal(key, sealed[:-1] + bytes([sealed[-1] ^ 1])) is None and b"true" not in sealed
    assert verify(key, b"m", sign(key, b"m")) and not verify(other, b"m", sign(key, b"m"))
    assert not verify(key, b"m", None) and not verify(None, b"m", sign(key, b"m"))
    assert proof("s", "join", "r", "a") != proof("s", "join", "r", "b")


# -- fuzz -----------------------------------------------------------------------------------------------

_FIELDS = [
    "op",
    "agent",
    "sender",
    "hyp",
    "n",
    "state",
    "recv",
    "sent",
    "timeouts",
    "probe",
    "activity",
    "reason",
    "seq",
    "id",
    "level",
    "source",
    "credibility",
    "links",
    "version",
    "timestamp",
    "body",
    "addressed_to",
    "deadline_s",
    "consumes",
    "produces",
    "exclusive",
    "pid",
    "host",
    "proof",
    "after",
    "input_error",
    "kind",
]
_ATOMS = [
    None,
    True,
    False,
    0,
    1,
    -1,
    2**63,
    -(2**70),
    1e300,
    -1e300,
    math.inf,
    -math.inf,
    math.nan,
    0.5,
    "",
    "doubler",
    "echo",
    "@node",
    "post",
    "join",
    "leave",
    "update",
    "retract",
    "idle",
    "dead",
    "stopped",
    "number",
    "doubled",
    "truth",
    "a/b",
    "*",
    "x" * 300,
    b"",
    b"\x00\xff",
    [],
    {},
]


def _value(rng: random.Random, depth: int = 0) -> object:
    roll = rng.random()
    if depth > 3 or roll < 0.55:
        return rng.choice(_ATOMS)
    if roll < 0.75:
        return [_value(rng, depth + 1) for _ in range(rng.randrange(0, 9))]
    return {rng.choice(_FIELDS): _value(rng, depth + 1) for _ in range(rng.randrange(0, 9))}


def _message(rng: random.Random) -> dict:
    """A plausible message with some fields spoiled: mostly valid shapes, so the checks deep
    inside are reached, not only the first one."""
    base = rng.choice(
        [
            {
                "op": "post",
                "sender": "doubler",
                "n": 1,
                "hyp": _record("doubled", f"f{rng.randrange(10**6)}", "doubler", {"x": 1}),
            },
            _status(
                rng.choice(["doubler", "echo", "nobody"]),
                activity=[["s", "number", "h-1", 1, "posted", 1.0, 1.0, None]],
            ),
            {
                "op": rng.choice(["challenge", "join", "leave", "update", "retract", "?"]),
                "agent": "doubler",
                "sent": 0,
                "after": {"echo": 1},
                "id": "h-1",
                "body": {},
                "produces": ["doubled"],
                "proof": "x",
                "nonce": rng.choice(["0" * 32, "x", ""]),
            },
        ]
    )
    for _ in range(rng.randrange(0, 4)):
        target = base
        if "hyp" in base and isinstance(base["hyp"], dict) and rng.random() < 0.5:
            target = base["hyp"]
        target[rng.choice(_FIELDS)] = _value(rng)
    return base


def test_fuzzed_control_and_hypothesis_messages_never_crash_or_stall_the_node(run_id: str, tmp_path: Path) -> None:
    rng = random.Random(1234)
    keys = RunKeys(run_id)
    n_bus, n_direct = 4_000, 20_000
    # 1) the validators themselves, directly: every generated message, no exception but ValueError/CodecError
    for _ in range(n_direct):
        message = _message(rng) if rng.random() < 0.8 else _value(rng)
        check_status(message)
        check_request(message)
        record = message.get("hyp") if isinstance(message, dict) else message
        try:
            Hypothesis.from_record(record)
        except CodecError:
            pass
    # 2) over the bus, to every key the node listens on, then a healthy run on the same node
    trace = tmp_path / "t.trace"
    with Runtime(run_id=run_id, trace_path=trace) as rt:
        rt.add(f"{AGENTS}:Doubler", name="doubler")
        rt.add(f"{AGENTS}:Echo", name="echo")
        outsider = open_session(zenoh_config(ZenohOptions(), mode="client", connect=[rt.node.endpoint]))
        started = time.monotonic()
        try:
            for i in range(n_bus):
                message = _message(rng) if rng.random() < 0.8 else _value(rng)
                try:
                    data = (
                        encode(message, max_bytes=1 << 20) if rng.random() < 0.95 else rng.randbytes(rng.randrange(64))
                    )
                except CodecError:  # not even msgpack (an integer beyond 64 bits): send raw bytes
                    data = rng.randbytes(rng.randrange(64))
                where = rng.random()
                if where < 0.45:
                    _put(
                        outsider,
                        keys.hypothesis(rng.choice(["doubled", "number", "echo", "truth"]), f"z{i}"),
                        data,
                        attachment=rng.choice([None, rng.randbytes(32), rng.randbytes(64)]),
                    )
                elif where < 0.75:
                    _put(outsider, keys.status, data, attachment=rng.choice([None, rng.randbytes(32)]))
                elif where < 0.85:
                    _put(outsider, rng.choice([keys.probe, keys.run_end, keys.inbox("echo")]), data)
                elif where < 0.95:
                    outsider.get(keys.request, payload=data, timeout=0.001, handler=lambda reply: None)
                else:
                    outsider.get(
                        f"{keys.level('doubled')}?agent=doubler;sent={rng.randrange(-5, 10**9)};"
                        f"after=echo:{rng.randrange(10**9)};tag=00",
                        timeout=0.001,
                        handler=lambda reply: None,
                    )
            for x in (1, 2, 3):
                rt.post("number", {"x": x})
            outcome = rt.run(timeout_s=60)
        finally:
            close_session(outsider, owner="outsider")
        took = time.monotonic() - started
        assert rt.node._thread is not None and rt.node._thread.is_alive()
        assert sorted(h.body["x"] for h in rt.hypotheses("doubled")) == [2, 4, 6]
        assert sorted(h.body["x"] for h in rt.hypotheses("echo")) == [2, 4, 6]
        assert outcome.agents == {"doubler": "ok", "echo": "ok"}
    assert n_bus + n_direct >= 10_000 and took < 60
    rejected = sum(r["kind"] == "rejected" for r in read_trace(trace))
    assert rejected >= n_bus * 0.5  # refused and recorded (reads without a tag are answered, not refused)


# -- across machines: zenoh user/password with the run's secret; user configs never widen ------------


@pytest.mark.parametrize("mode", ["inprocess", "processes"])
def test_with_auth_only_sessions_that_know_the_secret_connect(run_id: str, mode: str) -> None:
    from blackboard.config import loopback_endpoint
    from blackboard.errors import TransportError

    endpoint = loopback_endpoint()  # auth is forced here: the tests stay on loopback
    with Runtime(run_id=run_id, mode=mode, zenoh=ZenohOptions(listen=[endpoint]), auth=True) as rt:
        rt.add(f"{AGENTS}:Doubler", name="doubler")  # a local agent authenticates with the secret
        with pytest.raises(TransportError, match="cannot open a zenoh session"):
            open_session(zenoh_config(ZenohOptions(connect=[endpoint]), mode="client"))
        with pytest.raises(TransportError):
            open_session(zenoh_config(ZenohOptions(connect=[endpoint], password="a guess"), mode="client"))
        insider = open_session(zenoh_config(ZenohOptions(connect=[endpoint], password=rt.secret), mode="client"))
        insider.close()
        rt.post("number", {"x": 21})
        outcome = rt.run(timeout_s=30)
        assert [h.body["x"] for h in rt.hypotheses("doubled")] == [42] and outcome.agents == {"doubler": "ok"}


def test_auth_is_on_by_default_beyond_loopback_only() -> None:
    from blackboard.config import is_loopback

    assert is_loopback("tcp/127.0.0.1:7447") and is_loopback("tcp/[::1]:7447") and is_loopback("tcp/localhost:1")
    assert not is_loopback("tcp/192.0.2.10:7447") and not is_loopback("tcp/0.0.0.0:7447")
    assert Runtime(zenoh=ZenohOptions(listen=["tcp/192.0.2.10:7447"])).auth  # not started: nothing listens
    assert not Runtime(zenoh=ZenohOptions(listen=["tcp/127.0.0.1:7447"])).auth


@pytest.mark.parametrize(
    "text, listen, multicast",
    [
        ("{}", ["tcp/127.0.0.1:0"], False),  # says nothing: our defaults, never zenoh's (every interface, scouting)
        ("{transport: {link: {tx: {lease: 10000}}}}", ["tcp/127.0.0.1:0"], False),
        ('{listen: {endpoints: ["tcp/127.0.0.1:7999"]}}', ["tcp/127.0.0.1:7999"], False),
        ("{scouting: {multicast: {enabled: true}}}", ["tcp/127.0.0.1:0"], True),  # said explicitly: the user's choice
        # words in comments and listen settings without endpoints say nothing about either
        ("// listen here; multicast stays off\n{/* listen, multicast */}", ["tcp/127.0.0.1:0"], False),
        ("{listen: {timeout_ms: 5000}, scouting: {timeout: 1000}}", ["tcp/127.0.0.1:0"], False),
        ('{listen: {endpoints: {peer: ["tcp/127.0.0.1:7999"]}}}', ["tcp/127.0.0.1:0"], False),  # not the router's
        ('{listen: {endpoints: {router: ["tcp/127.0.0.1:7999"]}}}', {"router": ["tcp/127.0.0.1:7999"]}, False),
        (
            "{transport: {link: {tls: {root_ca_certificate: 'certs/ca.pem', enable_mtls: true}}}}",
            ["tcp/127.0.0.1:0"],
            False,
        ),
    ],
)
def test_a_user_config_never_widens_the_defaults(tmp_path: Path, text: str, listen: object, multicast: bool) -> None:
    path = tmp_path / "z.json5"
    path.write_text(text)
    config = zenoh_config(ZenohOptions(config_file=path), mode="router")
    assert json.loads(config.get_json("listen/endpoints")) == listen
    assert json.loads(config.get_json("scouting/multicast/enabled")) is multicast
    assert json.loads(config.get_json("scouting/gossip/enabled")) is False


# -- TLS and access control: the example configs of scenarios/zenoh, with certificates made here ------


def _outside_tls(folder: Path, endpoint: str, cert: str | None) -> zenoh.Config:
    """A client config of an outside session over TLS: trusting the test CA, showing ``certs/CERT.pem``
    (None: no certificate), giving up after 3 s."""
    import json

    tls: dict[str, object] = {"root_ca_certificate": str(folder / "certs" / "ca.pem")}
    if cert is not None:
        tls.update(
            connect_certificate=str(folder / "certs" / f"{cert}.pem"),
            connect_private_key=str(folder / "certs" / f"{cert}-key.pem"),
            enable_mtls=True,
        )
    config = zenoh_config(ZenohOptions(connect=[endpoint]), mode="client")
    config.insert_json5("transport/link/tls", json.dumps(tls))
    config.insert_json5("connect/timeout_ms", "3000")
    return config


def _doubled_with_remote_echo(rt: Runtime, endpoint: str, agent_config: Path | None) -> tuple[list, dict]:
    """Doubler local, Echo as a remote agent (its own session, connecting to ``endpoint`` with
    ``agent_config``, as ``mapinterp agent`` does): post 1, 2, 3, run; (echo's values, agents' states)."""
    from blackboard.agent import AgentRunner
    from tests.blackboard.agents import Echo

    rt.add(f"{AGENTS}:Doubler", name="doubler")
    rt.expect_remote(["echo"])
    remote = AgentRunner(
        Echo("echo"),
        run_id=rt.run_id,
        connect=[endpoint],
        zenoh_options=ZenohOptions(config_file=agent_config),
        secret=rt.secret,
    )
    remote.start(wait_s=20)
    try:
        rt.wait_joined(["echo"], timeout_s=20)
        for x in (1, 2, 3):
            rt.post("number", {"x": x})
        outcome = rt.run(timeout_s=30)
        return sorted(h.body["x"] for h in rt.hypotheses("echo")), outcome.agents
    finally:
        remote.stop()


def test_the_tls_example_configs_run_and_refuse_sessions_without_a_certificate(
    run_id: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from blackboard.config import free_port, loopback_endpoint
    from tests.blackboard.certs import ZENOH_EXAMPLES, make_certs

    make_certs(tmp_path)
    monkeypatch.chdir(tmp_path)  # the examples name certs/... relative to where mapinterp runs
    endpoint = loopback_endpoint()
    with Runtime(run_id=f"{run_id}-tcp", zenoh=ZenohOptions(listen=[endpoint])) as rt:
        over_tcp = _doubled_with_remote_echo(rt, endpoint, None)
    tls = f"tls/127.0.0.1:{free_port()}"
    options = ZenohOptions(listen=[tls], config_file=ZENOH_EXAMPLES / "tls-run.json5")
    with Runtime(run_id=run_id, zenoh=options) as rt:
        assert json.loads(rt.node._router_config.get_json("listen/endpoints")) == [tls]
        over_tls = _doubled_with_remote_echo(rt, tls, ZENOH_EXAMPLES / "tls-agent.json5")
        for config in (
            zenoh_config(ZenohOptions(connect=[tls.replace("tls/", "tcp/")]), mode="client"),  # plain tcp
            _outside_tls(tmp_path, tls, None),  # TLS, but no client certificate (mTLS)
        ):
            config.insert_json5("connect/timeout_ms", "3000")
            with pytest.raises(TransportError, match="cannot open a zenoh session"):
                open_session(config)
        open_session(_outside_tls(tmp_path, tls, "agent")).close()  # a certificate of the CA: admitted
    assert over_tls == over_tcp == ([2, 4, 6], {"doubler": "ok", "echo": "ok"})


def test_the_acl_example_drops_whatever_other_sessions_send_before_the_node_sees_it(
    run_id: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from blackboard.config import free_port
    from tests.blackboard.certs import ZENOH_EXAMPLES, make_certs

    make_certs(tmp_path)
    monkeypatch.chdir(tmp_path)
    keys = RunKeys(run_id)
    tls, tcp = f"tls/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    trace = tmp_path / "t.trace"
    options = ZenohOptions(listen=[tls, tcp], config_file=ZENOH_EXAMPLES / "acl-run.json5")
    seen_by: dict[str, list[bytes]] = {}
    with Runtime(run_id=run_id, zenoh=options, trace_path=trace) as rt:
        rt.add(f"{AGENTS}:Doubler", name="doubler")
        rt.add(f"{AGENTS}:Echo", name="echo")
        outsiders = {
            "plain-tcp": open_session(zenoh_config(ZenohOptions(connect=[tcp]), mode="client")),
            "intruder": open_session(_outside_tls(tmp_path, tls, "intruder")),  # same CA, another name
            "insider": open_session(_outside_tls(tmp_path, tls, "agent")),  # a name the ACL admits
        }
        try:
            for who, session in outsiders.items():
                seen_by[who] = []
                session.declare_subscriber(
                    keys.all_hypotheses,  # what others post (its own puts it gets locally)
                    lambda s, w=who: None if str(s.key_expr).endswith(w) else seen_by[w].append(b""),
                )
            time.sleep(0.5)  # the subscriptions reach the router
            for who, session in outsiders.items():
                _post(session, keys, "doubled", f"forged-{who}", "doubler", {"x": 999})
                _put(session, keys.status, _status("echo", state="dead", reason=f"forged by {who}"))
                replies = list(session.get(keys.request, payload=encode({"op": "join", "agent": who}), timeout=3))
                seen_by[who + "-replies"] = [b"" for r in replies if r.ok is not None]
            for x in (1, 2, 3):
                rt.post("number", {"x": x})
            outcome = rt.run(timeout_s=30)
        finally:
            for session in outsiders.values():
                session.close()
        assert sorted(h.body["x"] for h in rt.hypotheses("doubled")) == [2, 4, 6]
        assert sorted(h.body["x"] for h in rt.hypotheses("echo")) == [2, 4, 6]
        assert outcome.agents == {"doubler": "ok", "echo": "ok"}
    rejected = " | ".join(f"{r.get('key')} {r['message']}" for r in read_trace(trace) if r["kind"] == "rejected")
    # the admitted name reaches the node, which refuses its forgeries itself (the HMAC layer) ...
    assert "forged-insider" in rejected and "join refused: agent 'insider'" in rejected
    assert seen_by["insider"] and seen_by["insider-replies"]
    # ... the others are dropped by the router: the node never sees them, they see nothing
    for who in ("plain-tcp", "intruder"):
        assert f"forged-{who}" not in rejected and f"agent '{who}'" not in rejected, rejected
        assert seen_by[who] == [] and seen_by[who + "-replies"] == []


@pytest.mark.parametrize("example", ["tls-run.json5", "tls-agent.json5", "acl-run.json5"])
@pytest.mark.parametrize("mode", ["router", "client"])
def test_the_example_configs_never_widen_the_defaults(example: str, mode: str) -> None:
    from tests.blackboard.certs import ZENOH_EXAMPLES

    path = ZENOH_EXAMPLES / example
    for listen, expected in (([], ["tcp/127.0.0.1:0"]), (["tls/127.0.0.1:7447"], ["tls/127.0.0.1:7447"])):
        config = zenoh_config(ZenohOptions(listen=listen, config_file=path), mode=mode)
        assert json.loads(config.get_json("listen/endpoints")) == (expected if mode == "router" else [])
        assert json.loads(config.get_json("scouting/multicast/enabled")) is False
        assert json.loads(config.get_json("scouting/gossip/enabled")) is False
        assert json.loads(config.get_json("connect/endpoints")) == []  # none of its own: only what --connect says
        assert json.loads(config.get_json("transport/link/tls/enable_mtls")) is True  # and the file still counts
