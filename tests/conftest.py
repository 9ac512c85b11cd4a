"""Shared fixtures. Rendering is offscreen through EGL (Mesa)."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


@pytest.fixture(autouse=True, scope="session")
def _viewframe_cache(tmp_path_factory):
    """Tests never read or fill the user's viewframe cache: one fresh cache folder per session."""
    os.environ["MAPINTERP_CACHE"] = str(tmp_path_factory.mktemp("viewframe-cache"))
    yield
