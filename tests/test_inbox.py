"""A role's inbox: one FIFO under its prefix, read by the role's own thread."""

from __future__ import annotations

import queue
import time

import pytest
import zenoh
from ctrlunit.runtime.transport.node import Inbox
from ctrlunit.runtime.transport.zsession import make_config
from runner import unit_id

pytestmark = pytest.mark.zenoh


def test_pending_keeps_the_message_for_get_and_timeouts_still_hold():
    """pending() looks without losing anything (the central asks it before calling a
    peripheral silent: a reply it has not read yet is not silence)."""
    prefix = f"ctrlunit/{unit_id('inbox')}/central"
    unknown: list[str] = []
    with zenoh.open(make_config()) as session:
        inbox = Inbox(session, prefix, on_unknown=unknown.append)
        try:
            inbox.route(f"{prefix}/reply/1", "reply", 0)
            assert not inbox.pending()
            with pytest.raises(queue.Empty):
                inbox.get(timeout=0.05)
            pub = session.declare_publisher(f"{prefix}/reply/1")
            for payload in (b"a", b"b"):
                pub.put(payload)
            deadline = time.monotonic() + 5.0
            while not inbox.pending() and time.monotonic() < deadline:
                time.sleep(0.001)
            assert inbox.pending() and inbox.pending()  # asking twice takes nothing
            got = [inbox.get(timeout=1.0)[2], inbox.get(timeout=1.0)[2]]
            assert got == [b"a", b"b"]
            assert not inbox.pending()
            t0 = time.monotonic()
            with pytest.raises(queue.Empty):
                inbox.get(timeout=0.05)
            assert 0.04 < time.monotonic() - t0 < 1.0
            assert unknown == []
        finally:
            inbox.close()
