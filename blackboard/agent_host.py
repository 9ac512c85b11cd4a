"""``python -m blackboard.agent_host SPEC``: run one knowledge source in this process.

``SPEC`` is JSON: ``{"factory": "module:Class", "name", "options", "run_id", "connect",
"zenoh_config", "max_message_bytes"}``. Prints ``ready`` (or ``error: <message>``) on stdout
once joined and set up, then works until stdin reaches EOF: the parent closed it, or died.
The first line of stdin is JSON: the agent's join secret and the run's zenoh password (see
:mod:`blackboard.trust`), kept off the command line other users can read.
SIGINT is ignored: a Ctrl-C in the terminal reaches the whole process group, and it is the
parent that decides (it closes stdin, and kills a child that does not stop in time).
"""

from __future__ import annotations

import json
import logging
import os
import signal
import sys
from collections.abc import Sequence

from blackboard.agent import AgentRunner
from blackboard.config import ZenohOptions
from blackboard.errors import AgentError, BlackboardError

__all__ = ["main"]

logger = logging.getLogger(__name__)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status (2: could not start)."""
    from blackboard.runtime import resolve_factory

    argv = list(sys.argv[1:] if argv is None else argv)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        spec = json.loads(argv[0])
        # the first line of stdin: this agent's join secret and the run's zenoh password
        private = json.loads(sys.stdin.buffer.readline().decode() or "{}")
        source = resolve_factory(spec["factory"])(spec["name"], **spec.get("options", {}))
        options = ZenohOptions(config_file=spec.get("zenoh_config"), password=private.get("password"))
        runner = AgentRunner(
            source,
            run_id=spec["run_id"],
            connect=list(spec["connect"]),
            zenoh_options=options,
            max_message_bytes=int(spec["max_message_bytes"]),
            secret=private.get("secret"),
        )
        runner.start()
    except (BlackboardError, ValueError, KeyError, IndexError, TypeError) as err:
        message = err.message if isinstance(err, AgentError) else str(err)  # the parent names the agent
        print(f"error: {message}", flush=True)
        return 2
    print("ready", flush=True)
    os.dup2(2, 1)  # the agent's own prints go to stderr: nobody reads the pipe any more
    try:
        sys.stdin.buffer.read()  # the watchdog: returns at EOF (parent closed the pipe or died)
    finally:
        runner.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
