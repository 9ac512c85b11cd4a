"""One BLAS thread per call in a process whose agents share it.

A mission runs its agents (about 25 at 10,000 viewframes: 20 indexer shards, the skyline ranker,
the detectors, ...) as threads of one process. numpy's OpenBLAS splits each product over a pool
of worker threads of its own, one per core, and its workers spin while they wait for the next
call: with many agent threads calling BLAS at once on a machine of few cores, the pool competes
with the agents for the cores and every call waits for it. On the 2-core test machine the
coarse stage's product of one indexer shard took 3.6 ms of CPU with the pool and 0.5 ms without
(``bench/coarse.py``), and a 10,000-viewframe drive localized 1.2-2.1 frames/s with it and
3.1-3.3 without (``bench/scale.py``; BENCHMARKS.md, "Associative coarse stage").

Best is OpenBLAS started with one thread (``OPENBLAS_NUM_THREADS=1`` before numpy is first
imported): then each agent's call runs in its own thread, several at once. Set later, at run
time, its calls take one thread but one call at a time: 20 threads each making small products
took 9.5 s of wall with the pool, 2.4 s set at run time and 1.4 s started with one thread
(``bench`` script in BENCHMARKS.md). So :func:`default_single_thread` (called as
:mod:`knowledge_sources` is imported, before numpy is: the command line, agent hosts) sets
``OPENBLAS_NUM_THREADS=1`` unless the user set it or ``OMP_NUM_THREADS``; and
:func:`single_blas_thread` (a mission: :func:`knowledge_sources.mission.run_mission`), when numpy
was loaded with a pool all the same, sets OpenBLAS's count to one at run time for the mission
(through the library numpy loaded, found among the process's mapped libraries: Linux; elsewhere
nothing) and ``OPENBLAS_NUM_THREADS=1`` for the processes it starts (agents in processes mode).
A count the user set is always left alone.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
from collections.abc import Iterator
from pathlib import Path

__all__ = ["default_single_thread", "single_blas_thread", "openblas_threads"]

log = logging.getLogger(__name__)

_USER_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")
#: OPENBLAS_NUM_THREADS was set by :func:`default_single_thread`, not by the user
_OURS = "_MAPINTERP_BLAS_DEFAULT"


def _user_set() -> bool:
    """The user chose a BLAS thread count (not :func:`default_single_thread`)."""
    if os.environ.get("OMP_NUM_THREADS"):
        return True
    return bool(os.environ.get("OPENBLAS_NUM_THREADS")) and os.environ.get(_OURS) != "1"


def default_single_thread() -> None:
    """``OPENBLAS_NUM_THREADS=1`` in this process's environment, for numpy's first import and the
    processes started from here, unless the user set a count (module docstring)."""
    if not _user_set() and not os.environ.get("OPENBLAS_NUM_THREADS"):
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
        os.environ[_OURS] = "1"


_SETTERS = ("openblas_set_num_threads", "scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads")
_GETTERS = ("openblas_get_num_threads", "scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads")


def _openblas() -> tuple[ctypes._CFuncPtr, ctypes._CFuncPtr] | None:  # type: ignore[name-defined]
    """(set, get) of the OpenBLAS mapped into this process (numpy's), or None."""
    import numpy  # noqa: F401  # loads its BLAS

    maps = Path("/proc/self/maps")
    if not maps.is_file():
        return None
    paths = []
    for line in maps.read_text().splitlines():
        path = line.split(maxsplit=5)[-1] if line.count(" ") >= 5 else ""
        if "openblas" in Path(path).name.lower() and ".so" in path and path not in paths:
            paths.append(path)
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        setter = next((getattr(lib, n) for n in _SETTERS if hasattr(lib, n)), None)
        getter = next((getattr(lib, n) for n in _GETTERS if hasattr(lib, n)), None)
        if setter is not None and getter is not None:
            setter.argtypes, setter.restype = [ctypes.c_int], None
            getter.argtypes, getter.restype = [], ctypes.c_int
            return setter, getter
    return None


def openblas_threads() -> int | None:
    """The OpenBLAS thread count of this process, or None when no OpenBLAS is found."""
    found = _openblas()
    return None if found is None else int(found[1]())


@contextlib.contextmanager
def single_blas_thread() -> Iterator[None]:
    """One OpenBLAS thread in this process and ``OPENBLAS_NUM_THREADS=1`` for the processes it
    starts, until the block ends (then as before); nothing when the user set the thread count
    (``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``) or no OpenBLAS is found (module docstring)."""
    if _user_set():
        yield
        return
    found = _openblas()
    before = None if found is None else int(found[1]())
    if found is not None and before != 1:
        found[0](1)
    env_before = os.environ.get("OPENBLAS_NUM_THREADS")
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    log.debug("BLAS: one thread (was %s)", before)
    try:
        yield
    finally:
        if env_before is None:
            os.environ.pop("OPENBLAS_NUM_THREADS", None)
        if found is not None and before is not None and before != 1:
            found[0](before)
