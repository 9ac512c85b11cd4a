"""One BLAS thread during a mission (models/blas.py): in this process and for the processes it starts."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from models.blas import openblas_threads, single_blas_thread


def _child_threads() -> str:
    code = "from models.blas import openblas_threads; print(openblas_threads())"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()


def test_one_blas_thread_in_the_block_and_as_before_after(monkeypatch) -> None:
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)
    before = openblas_threads()
    if before is None:
        pytest.skip("numpy's BLAS here is not an OpenBLAS this process maps")
    with single_blas_thread():
        assert openblas_threads() == 1
        assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
        assert _child_threads() == "1"  # a process started meanwhile (an agent host) loads it so
    assert openblas_threads() == before and "OPENBLAS_NUM_THREADS" not in os.environ


def test_a_thread_count_the_user_set_is_left_alone(monkeypatch) -> None:
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    before = openblas_threads()
    with single_blas_thread():
        assert openblas_threads() == before and "OPENBLAS_NUM_THREADS" not in os.environ
