"""Endurance: many freerun intervals at n = 3, depth 2, no deadlock, bounded memory.

CI runs a bounded version (CTRLUNIT_SOAK_CYCLES, default 20 000); the full soak of the
issue is ``CTRLUNIT_SOAK_CYCLES=200000 python -m pytest -m slow tests/test_endurance.py``.
"""

from __future__ import annotations

import os

import pytest
from runner import start_json

pytestmark = pytest.mark.zenoh
LIMIT_KB = 5 * 1024


def soak(tmp_path, cycles: int) -> dict:
    code, rep, out = start_json(tmp_path, "--peripherals", "3", "--pipeline", "2", "--clock",
                                "freerun", "--cycles", str(cycles), tag="soak",
                                timeout=max(600, cycles / 300))
    assert code == 0, out
    assert rep["cycles"] == cycles
    mem = rep["memory_kb"]
    assert set(mem) == {"central", "peripheral-1", "peripheral-2", "peripheral-3"}
    for role, m in mem.items():
        growth = m["end"] - m["warm"]
        print(f"{role}: {m['warm']} kB after warm-up, {m['end']} kB after {cycles} intervals "
              f"(+{growth} kB)")
        assert m["warm"] > 0 and growth < LIMIT_KB, role
    return rep


def test_bounded_soak_has_no_deadlock_and_flat_memory(tmp_path):
    cycles = int(os.environ.get("CTRLUNIT_SOAK_CYCLES", "20000"))
    rep = soak(tmp_path, cycles)
    # The central keeps 12 bytes per interval (command time, traversal); the rest of its
    # resident memory moves in allocator-sized steps and levels off (seen: 55.3 MB after
    # warm-up, 57-58 MB from 30 000 to 100 000 intervals), so no linear extrapolation.
    print("central RSS series (interval, kB):", rep["memory_kb"]["central"]["series"])


@pytest.mark.slow
def test_full_soak_200k(tmp_path):
    soak(tmp_path, 200_000)
