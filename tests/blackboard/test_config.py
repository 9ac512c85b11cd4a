"""Zenoh configuration: loopback defaults, flags, endpoint validation, user config files."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest
import zenoh

from blackboard.config import (
    BLOCK_WAIT_BEFORE_CLOSE_US,
    BLOCK_WAIT_KEY,
    ZenohOptions,
    add_zenoh_arguments,
    free_port,
    open_session,
    zenoh_config,
    zenoh_options_from_args,
)
from blackboard.errors import TransportError


def _get(config, key: str):
    value = config.get_json(key)
    return json.loads(value) if isinstance(value, str) else value


@pytest.mark.parametrize("mode", ["router", "peer"])
def test_defaults_listen_on_loopback_only(mode: str) -> None:
    config = zenoh_config(ZenohOptions(), mode=mode)
    assert _get(config, "listen/endpoints") == ["tcp/127.0.0.1:0"]
    assert _get(config, "scouting/multicast/enabled") is False
    assert _get(config, "mode") == mode


@pytest.mark.parametrize("mode", ["router", "peer", "client"])
def test_blocked_puts_do_not_close_the_transport_after_zenohs_5_s(mode: str) -> None:
    # zenoh closes a transport when a BLOCK put waits longer than this; its 5 s default lost the tail
    # of a 10,000-post burst on a heavily loaded machine (the agent looked dead, the run ended)
    assert zenoh.Config().get_json(BLOCK_WAIT_KEY) == "5000000"  # zenoh's own default, what we change
    assert _get(zenoh_config(ZenohOptions(), mode=mode), BLOCK_WAIT_KEY) == BLOCK_WAIT_BEFORE_CLOSE_US >= 30_000_000


def test_client_never_listens() -> None:
    config = zenoh_config(ZenohOptions(listen=["tcp/127.0.0.1:7000"]), mode="client", connect=["tcp/127.0.0.1:7001"])
    assert _get(config, "listen/endpoints") == []
    assert _get(config, "connect/endpoints") == ["tcp/127.0.0.1:7001"]


def test_flags_round_trip() -> None:
    parser = argparse.ArgumentParser()
    add_zenoh_arguments(parser)
    args = parser.parse_args(
        ["--connect", "tcp/127.0.0.1:7447", "--listen", "tcp/127.0.0.1:7448", "--zenoh-config", "z.json5"]
    )
    assert zenoh_options_from_args(args) == ZenohOptions(
        ["tcp/127.0.0.1:7448"], ["tcp/127.0.0.1:7447"], Path("z.json5")
    )


@pytest.mark.parametrize("endpoint", ["127.0.0.1:7447", "tcp/127.0.0.1", "http://x:1", "", "tcp/a b:1"])
def test_bad_endpoints_are_refused(endpoint: str) -> None:
    with pytest.raises(TransportError, match="endpoint"):
        ZenohOptions(connect=[endpoint])


def test_user_config_file(tmp_path: Path) -> None:
    port = free_port()
    path = tmp_path / "zenoh.json5"
    path.write_text(
        '{ mode: "peer", scouting: { multicast: { enabled: false } }, '
        f'listen: {{ endpoints: ["tcp/127.0.0.1:{port}"] }} }}'
    )
    config = zenoh_config(ZenohOptions(config_file=path), mode="router")
    assert _get(config, "listen/endpoints") == [f"tcp/127.0.0.1:{port}"]
    session = open_session(config)
    session.close()


@pytest.mark.parametrize("text", [None, "{ this is not json5"])
def test_bad_config_file(tmp_path: Path, text: str | None) -> None:
    path = tmp_path / "zenoh.json5"
    if text is not None:
        path.write_text(text)
    with pytest.raises(TransportError, match="zenoh.json5"):
        zenoh_config(ZenohOptions(config_file=path))
