"""Fixtures of the blackboard tests: a fresh run id per test, and ``tests.blackboard.agents``
importable by name (processes mode spawns agents from ``"module:Class"`` strings)."""

from __future__ import annotations

import re
import sys
import uuid
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


@pytest.fixture
def run_id(request: pytest.FixtureRequest) -> str:
    """A run id unique to this test (its name, sanitised, plus random hex)."""
    stem = re.sub(r"[^A-Za-z0-9_-]", "-", request.node.name)[:60]
    return f"{stem}-{uuid.uuid4().hex[:8]}"
