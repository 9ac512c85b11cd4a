"""numpy's BLAS with one thread per call for a mission (models/blas.py): started so as
``knowledge_sources`` is imported, or set at run time for a mission, and for the processes it
starts; a count the user set is kept."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from models import blas
from models.blas import default_single_thread, openblas_threads, single_blas_thread


def _child_threads(first: str = "numpy") -> str:
    """The OpenBLAS thread count of a new Python process that imports ``first`` first."""
    code = f"import {first}; from models.blas import openblas_threads; print(openblas_threads())"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()


@pytest.fixture
def no_user_count(monkeypatch) -> None:
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", blas._OURS):
        monkeypatch.delenv(var, raising=False)


@pytest.fixture
def pool() -> object:
    """This process's OpenBLAS with a pool of two threads (as numpy loads it without the
    default), restored after; skipped when numpy's BLAS is not an OpenBLAS this process maps."""
    found = blas._openblas()
    if found is None:
        pytest.skip("numpy's BLAS here is not an OpenBLAS this process maps")
    setter, getter = found
    before = getter()
    setter(2)
    yield found
    setter(before)


def test_a_mission_sets_one_thread_at_run_time_and_as_before_after(no_user_count, pool) -> None:
    with single_blas_thread():
        assert openblas_threads() == 1
        assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
        assert _child_threads() == "1"  # a process started meanwhile (an agent host) loads it so
    assert openblas_threads() == 2 and "OPENBLAS_NUM_THREADS" not in os.environ


def test_a_thread_count_the_user_set_is_left_alone(monkeypatch, pool) -> None:
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    with single_blas_thread():
        assert openblas_threads() == 2 and "OPENBLAS_NUM_THREADS" not in os.environ
    default_single_thread()
    assert "OPENBLAS_NUM_THREADS" not in os.environ


def test_importing_knowledge_sources_first_starts_numpy_with_one_thread(no_user_count, monkeypatch) -> None:
    if blas._openblas() is None:
        pytest.skip("numpy's BLAS here is not an OpenBLAS this process maps")
    assert _child_threads("knowledge_sources") == "1"
    assert _child_threads("numpy") not in ("1", "None") or os.cpu_count() == 1  # without it: a pool
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")  # the user's count is kept
    assert _child_threads("knowledge_sources") == "2"
    default_single_thread()
    assert os.environ["OPENBLAS_NUM_THREADS"] == "2"
