"""How much of a memory mapping is resident in this process (Linux ``/proc/self/smaps``), for the
tests that check pages are given back (the viewframe cache, a stored index's ranking rows)."""

from __future__ import annotations

from pathlib import Path

import pytest

#: skip a test that needs /proc/self/smaps where there is none
needs_smaps = pytest.mark.skipif(not Path("/proc/self/smaps").exists(), reason="Linux /proc needed")


def resident_kb(address: int) -> int:
    """Resident KB of this process's mapping that holds ``address`` (/proc/self/smaps)."""
    inside = False
    for line in Path("/proc/self/smaps").read_text().splitlines():
        head = line.split()[0]
        if "-" in head and not head.endswith(":"):
            lo, hi = (int(v, 16) for v in head.split("-"))
            inside = lo <= address < hi
        elif inside and head == "Rss:":
            return int(line.split()[1])
    raise AssertionError(f"no mapping holds {address:#x}")
