"""Shared fixtures and strategies."""

from __future__ import annotations

import compileall
import importlib
import math
import os
import signal
import tempfile
from collections.abc import Iterator

import numpy as np
import pytest
from ctrlunit.kernels.forward import fk_closed_form
from ctrlunit.kernels.params import DELTA_IA, DeltaParams
from ctrlunit.kernels.workspace import check_point
from hypothesis import strategies as st

# The tests that send Ctrl-C (SIGINT) to a unit test what a terminal does. Run as a
# background job of a non-interactive shell, pytest starts with SIGINT ignored and every
# process it starts would inherit that (runtime/roles/stopping.py); a handler here is reset to
# the default in each child, as in a terminal.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_sessionstart(session: pytest.Session) -> None:
    """The package's bytecode, written once before the tests start their hundreds of
    processes: with ``PYTHONDONTWRITEBYTECODE`` set (as on the reference machine) an
    editable install is otherwise compiled again by every process that imports it,
    0.1-0.3 s each (53 s against 48 s for tests/test_late.py and tests/test_faults.py
    here). Only what changed since is compiled; a failure leaves imports as they were."""
    for name in ("runtime", "kernels", "topology", "plant", "bench"):
        for folder in importlib.import_module(f"ctrlunit.{name}").__path__:
            compileall.compile_dir(folder, quiet=2, workers=1)


@pytest.fixture(autouse=True, scope="session")
def _temporary_files_under_pytest(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Everything the tests and the units they start put in the temporary folder (the
    run directory a faulted run keeps for diagnosis, above all) goes under this session's
    pytest folder, which pytest prunes, not into /tmp for good (78 of them there after a
    few sessions)."""
    base = str(tmp_path_factory.mktemp("tmp"))
    before_env, before = os.environ.get("TMPDIR"), tempfile.tempdir
    os.environ["TMPDIR"], tempfile.tempdir = base, base
    yield
    tempfile.tempdir = before
    if before_env is None:
        os.environ.pop("TMPDIR", None)
    else:
        os.environ["TMPDIR"] = before_env


@pytest.fixture
def socket_endpoint() -> str:
    """A unix socket endpoint in a folder of its own (under the session's temporary
    folder: short, where a test's ``tmp_path`` may pass the 107 bytes a socket's path may
    have). Without keys the unit's roles reach the central over a unix socket alone
    (runtime/transport/security.py, ``socket_rule``)."""
    return f"unixsock-stream/{tempfile.mkdtemp(prefix='sock-')}/central.sock"


@pytest.fixture
def params() -> DeltaParams:
    return DELTA_IA


def usable_point_from_q(q: tuple[float, float, float]) -> np.ndarray | None:
    """The platform position for joint angles q if it is in the usable workspace."""
    try:
        p = fk_closed_form(DELTA_IA, np.array(q))
    except ValueError:
        return None
    return p if check_point(DELTA_IA, p).ok else None


joint_angles = st.tuples(
    *[st.floats(DELTA_IA.q_min, DELTA_IA.q_max, allow_nan=False) for _ in range(3)]
)
velocities = st.tuples(*[st.floats(-5.0, 5.0, allow_nan=False) for _ in range(3)])

INCREMENT = 2.0 * math.pi / 200_000
