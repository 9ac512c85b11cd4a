"""A viewframe rendering worker process: ``python -m models.render_worker``, driven by
:func:`models.viewframes.render_viewframes_parallel` through its standard input and output.

The protocol is pickles on the two pipes. The parent sends ``(environment, camera,
skyline_step_deg)`` once, then ``(first, poses)`` per share of the route and ``None`` to end;
the worker answers each share with ``("ok", viewframes)`` (numbered from ``first``) or, when
it fails, ``("error", message)`` and exits. The worker's own standard output is sent to its
standard error before anything else runs, so a library that prints cannot corrupt the pipe.

A separate module started with ``-m`` rather than a ``multiprocessing`` pool: a spawned pool
worker imports the parent's ``__main__`` script again (so a script without a
``if __name__ == "__main__"`` guard would run twice and fail), and forking a process that may
hold an EGL context is unsafe.
"""

from __future__ import annotations

import os
import pickle
import sys
from typing import BinaryIO


def serve(inp: BinaryIO, out: BinaryIO) -> int:
    """Answer shares of the route read from ``inp`` on ``out`` until ``None``; the exit status."""
    from models.camera_emulator import CameraEmulator
    from models.viewframes import _render

    try:
        environment, camera, step = pickle.load(inp)
    except EOFError:
        return 0
    try:
        emulator = CameraEmulator(environment, camera)
    except Exception as exc:  # noqa: BLE001 - reported to the parent, which raises it
        pickle.dump(("error", f"{type(exc).__name__}: {exc}"), out)
        out.flush()
        return 1
    with emulator:
        while True:
            try:
                job = pickle.load(inp)
            except EOFError:
                return 0
            if job is None:
                return 0
            first, poses = job
            try:
                frames = _render(emulator, poses, first, skyline_step_deg=step)
            except Exception as exc:  # noqa: BLE001 - reported to the parent, which raises it
                pickle.dump(("error", f"{type(exc).__name__}: {exc}"), out)
                out.flush()
                return 1
            pickle.dump(("ok", frames), out, protocol=pickle.HIGHEST_PROTOCOL)
            out.flush()


def main() -> int:
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything printed goes to standard error, not into the pipe
    sys.stdout = sys.stderr
    with out:
        return serve(sys.stdin.buffer, out)


if __name__ == "__main__":
    sys.exit(main())
