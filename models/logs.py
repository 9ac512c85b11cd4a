"""Logging shared by the models: a warning said once per process.

The pre-run check and every agent of a run that reads the same map or camera image would each
say its warning again; :func:`warn_once` says each message once.
"""

from __future__ import annotations

import logging
import threading

__all__ = ["warn_once"]

_said: set[tuple[str, str]] = set()
_lock = threading.Lock()


def warn_once(logger: logging.Logger, msg: str, *args: object) -> None:
    """``logger.warning(msg, *args)`` the first time this process would say that text on that logger."""
    text = msg % args if args else msg
    with _lock:
        if (logger.name, text) in _said:
            return
        _said.add((logger.name, text))
    logger.warning("%s", text)
