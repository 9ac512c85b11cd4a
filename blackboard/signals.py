"""Ctrl-C and SIGTERM for commands that run a blackboard: stop cleanly once, exit at once twice.

Within :func:`interrupt_on_signals`, the first SIGINT or SIGTERM raises :class:`Interrupted`
(a ``KeyboardInterrupt``) in the main thread, so the run in progress can write what it has
(results so far, the trace's ``run_end``) and stop its agents; a second one kills the child
processes of every open :class:`~blackboard.runtime.Runtime` and exits the process at once with
status ``128 + signal``, whatever the first one's clean-up was doing.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterator

__all__ = ["Interrupted", "interrupt_on_signals", "signal_name"]

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """Raised by the first SIGINT/SIGTERM; ``signum`` says which."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


def signal_name(err: BaseException) -> str:
    """``"SIGTERM"`` for an :class:`Interrupted` by SIGTERM, else ``"SIGINT"`` (a plain Ctrl-C)."""
    return signal.Signals(getattr(err, "signum", signal.SIGINT)).name


@contextlib.contextmanager
def interrupt_on_signals() -> Iterator[None]:
    """Install the handlers (main thread only; elsewhere a no-op) and restore the old ones."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    count = 0

    def handler(signum: int, frame: object) -> None:
        nonlocal count
        count += 1
        if count == 1:
            raise Interrupted(signum)
        from blackboard.runtime import Runtime

        Runtime.abort_all()
        try:
            sys.stderr.write(f"interrupted again by {signal.Signals(signum).name}: exiting at once\n")
            sys.stderr.flush()
        finally:
            os._exit(128 + signum)

    old = {s: signal.signal(s, handler) for s in _SIGNALS}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
