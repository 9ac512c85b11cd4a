"""Zenoh configuration: loopback-only defaults, the shared command-line flags.

Defaults: multicast scouting off, listen on ``tcp/127.0.0.1`` only, reliable delivery (TCP);
the blackboard node is a zenoh router and every agent a client of it (so a post reaches every
subscriber as soon as the subscriber has joined, with no peer mesh to form first); publications use :data:`zenoh.CongestionControl.BLOCK` so no hypothesis is dropped.
``--zenoh-config FILE`` loads a user JSON5 config (TLS, access control) that the explicit
``--listen`` / ``--connect`` flags then amend.

Example::

    >>> opts = ZenohOptions(connect=["tcp/127.0.0.1:7447"])
    >>> cfg = zenoh_config(opts)
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import socket
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from blackboard.errors import TransportError

logger = logging.getLogger(__name__)

__all__ = [
    "ZenohOptions",
    "zenoh_config",
    "open_session",
    "close_session",
    "add_zenoh_arguments",
    "zenoh_options_from_args",
    "free_port",
    "loopback_endpoint",
    "is_loopback",
    "AUTH_USER",
]

_ENDPOINT = re.compile(r"(tcp|tls|quic|udp)/(\[[0-9a-fA-F:]+\]|[A-Za-z0-9_.-]+):\d{1,5}")


def free_port() -> int:
    """A currently free TCP port on 127.0.0.1 (bind to port 0, read, release)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def loopback_endpoint(port: int | None = None) -> str:
    """``tcp/127.0.0.1:PORT`` (a free port when ``port`` is None)."""
    return f"tcp/127.0.0.1:{free_port() if port is None else port}"


@dataclass
class ZenohOptions:
    """Where the zenoh sessions of a run listen and connect.

    Example::

        ZenohOptions(listen=["tcp/127.0.0.1:7447"])          # others may --connect here
        ZenohOptions(connect=["tcp/127.0.0.1:7447"])         # join that network
        ZenohOptions(config_file=Path("zenoh.json5"))        # TLS, access control, ...
    """

    listen: list[str] = field(default_factory=list)
    connect: list[str] = field(default_factory=list)
    config_file: Path | None = None
    #: the run's secret as zenoh ``usrpwd`` password (user :data:`AUTH_USER`): sessions without
    #: it cannot connect; None: no authentication (the loopback default)
    password: str | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        for what, endpoints in (("listen", self.listen), ("connect", self.connect)):
            for endpoint in endpoints:
                if not isinstance(endpoint, str) or _ENDPOINT.fullmatch(endpoint) is None:
                    raise TransportError(f"--{what} endpoint must look like tcp/127.0.0.1:7447, got {endpoint!r}")
        if self.config_file is not None:
            self.config_file = Path(self.config_file)


#: zenoh's limit on a blocked put before it closes the transport, and ours (microseconds)
BLOCK_WAIT_KEY = "transport/link/tx/queue/congestion_control/block/wait_before_close"
BLOCK_WAIT_BEFORE_CLOSE_US = 60_000_000
#: our defaults where zenoh's are unsafe or lossy, each kept unless a user config sets the key
#: (to another value than zenoh's default).
#: A put with CongestionControl.BLOCK that waits longer than BLOCK_WAIT_KEY CLOSES the transport
#: (zenoh 1.x; default 5 s), losing every hypothesis behind it: under heavy load a burst can stall
#: that long on a loaded machine. A minute keeps delivery lossless yet bounded (never a hang).
_DEFAULTS: dict[str, str] = {
    "scouting/multicast/enabled": "false",
    "scouting/gossip/enabled": "false",
    BLOCK_WAIT_KEY: str(BLOCK_WAIT_BEFORE_CLOSE_US),
}
#: zenoh's own defaults, as a config file that says nothing reads (listen: every interface)
_ZENOH = zenoh.Config()
_ZENOH_LISTEN_DEFAULT = json.loads(_ZENOH.get_json("listen/endpoints"))


def _user_listen(config: zenoh.Config, mode: str) -> list | None:
    """The listen endpoints a loaded user config sets for ``mode``, or None when it sets none
    (zenoh's default then would listen on every interface)."""
    endpoints = json.loads(config.get_json("listen/endpoints"))
    if endpoints == _ZENOH_LISTEN_DEFAULT:
        return None
    if isinstance(endpoints, dict):  # per mode: {router: [...], peer: [...]}
        endpoints = endpoints.get(mode)
    return endpoints if isinstance(endpoints, list) else None


def zenoh_config(
    options: ZenohOptions | None = None,
    *,
    mode: str = "peer",
    listen: list[str] | None = None,
    connect: list[str] | None = None,
) -> zenoh.Config:
    """A :class:`zenoh.Config` for one session in ``mode`` ("router", "peer" or "client").

    ``listen`` / ``connect`` (when given) add to the endpoints of ``options``. A router or peer
    without a listen endpoint listens on an ephemeral ``tcp/127.0.0.1`` port (never on all
    interfaces, zenoh's own default); a client never listens.

    Raises:
        TransportError: the config file is missing or invalid, or ``mode`` is unknown.
    """
    if mode not in ("router", "peer", "client"):
        raise TransportError(f"zenoh mode must be router, peer or client, got {mode!r}")
    options = options or ZenohOptions()
    if options.config_file is not None:
        _read_text(options.config_file)  # a missing or unreadable file: one line naming it
        try:
            config = zenoh.Config.from_file(str(options.config_file))
        except (OSError, zenoh.ZError, ValueError) as err:
            raise TransportError(f"{options.config_file}: cannot load zenoh config: {err}") from None
        # the user's file decides what it says; what it does not say keeps our defaults, which
        # never widen the listen address (zenoh's own default: every interface) nor scout. Read
        # from the loaded config, not the text: a comment naming "listen" or "multicast" says nothing
        user_listens = _user_listen(config, mode) is not None
    else:
        user_listens = False
        config = zenoh.Config()
    for key, default in _DEFAULTS.items():
        if config.get_json(key) == _ZENOH.get_json(key):  # unset in the user's file (or no file)
            config.insert_json5(key, default)
    config.insert_json5("mode", json.dumps(mode))
    listen_eps = [*options.listen, *(listen or [])] if mode != "client" else []
    connect_eps = [*options.connect, *(connect or [])]
    if mode != "client" and not listen_eps and not user_listens:
        listen_eps = ["tcp/127.0.0.1:0"]
    if not user_listens or listen_eps or mode == "client":
        config.insert_json5("listen/endpoints", json.dumps(listen_eps))
    if options.config_file is None or connect_eps:
        config.insert_json5("connect/endpoints", json.dumps(connect_eps))
    if options.password is not None:
        auth: dict[str, str] = {"user": AUTH_USER, "password": options.password}
        if mode != "client":  # who may connect here: this run's secret only
            auth["dictionary_file"] = str(_dictionary_file(options.password))
        config.insert_json5("transport/auth/usrpwd", json.dumps(auth))
    return config


#: the zenoh ``usrpwd`` user name of every session of a run with authentication
AUTH_USER = "mapinterp"
_DICTIONARIES: dict[str, Path] = {}


def _dictionary_file(password: str) -> Path:
    """A private (0600) file of the one credential a router accepts, made once per password,
    removed at exit."""
    if password not in _DICTIONARIES:
        import atexit
        import os
        import tempfile

        fd, name = tempfile.mkstemp(prefix="mapinterp-usrpwd-", suffix=".txt")
        with os.fdopen(fd, "w") as f:
            f.write(f"{AUTH_USER}:{password}\n")
        _DICTIONARIES[password] = Path(name)
        atexit.register(Path(name).unlink, missing_ok=True)
    return _DICTIONARIES[password]


def _read_text(path: Path) -> str:
    try:
        return Path(path).read_text(encoding="utf-8", errors="replace")
    except OSError as err:
        raise TransportError(f"{path}: cannot load zenoh config: {err.strerror or err}") from None


def is_loopback(endpoint: str) -> bool:
    """True for an endpoint on this machine only (``tcp/127.0.0.1:7447``, ``tcp/[::1]:7447``,
    ``tcp/localhost:7447``)."""
    host = endpoint.split("/", 1)[-1].rsplit(":", 1)[0].strip("[]")
    return host == "localhost" or host == "::1" or host.startswith("127.")


def open_session(config: zenoh.Config) -> zenoh.Session:
    """``zenoh.open`` with its errors as :class:`TransportError`."""
    try:
        return zenoh.open(config)
    except zenoh.ZError as err:
        raise TransportError(f"cannot open a zenoh session: {err}") from None


def close_session(session: zenoh.Session, *, owner: str) -> bool:
    """Close ``session`` (``owner`` names it in the warning) unless it is closed already.

    Zenoh's close waits a bounded time for its links to flush and raises when they do not (a
    loaded machine, a peer still sending megabytes). The session is gone either way and nothing
    of the run is in it (the node writes its trace itself), so a timed-out close is a warning, not
    a reason to skip what the caller does next (end and close the trace). Returns whether it
    closed cleanly."""
    if session.is_closed():
        return True
    try:
        session.close()
    except zenoh.ZError as err:
        logger.warning("%s: the zenoh session did not close cleanly: %s", owner, err)
        return False
    return True


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--connect``, ``--listen`` and ``--zenoh-config`` (the one place they are defined)."""
    group = parser.add_argument_group("zenoh")
    group.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="join an existing zenoh network, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    group.add_argument(
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="let other mapinterp processes connect here, e.g. tcp/127.0.0.1:7447",
    )
    group.add_argument(
        "--zenoh-config",
        type=Path,
        default=None,
        metavar="FILE",
        help="a zenoh JSON5 config file (TLS, access control); multicast stays your choice",
    )


def zenoh_options_from_args(args: argparse.Namespace) -> ZenohOptions:
    """The :class:`ZenohOptions` of parsed ``add_zenoh_arguments`` flags."""
    return ZenohOptions(listen=list(args.listen), connect=list(args.connect), config_file=args.zenoh_config)
