"""A stop signal while a run moves is held and raised where the central next waits
(runtime/roles/stopping.py, ``held_stops``), not where the signal finds the main thread:
raised inside a ``with`` block's exit it once left a lock taken, and the stop hung (a run
that raised SIGHUP at a random line of its main thread, one of 98 such runs)."""

from __future__ import annotations

import os
import signal
import threading

import pytest
from ctrlunit.runtime.roles.stopping import Terminated, held_stops, stop_signals
from ctrlunit.runtime.transport.node import Inbox


@pytest.fixture(autouse=True)
def stop_signals_as_from_a_terminal():
    """The three signals as a terminal's program has them, whatever this runner was
    started with (under ``nohup`` SIGHUP is ignored, and an ignored signal stays so:
    runtime/roles/stopping.py); put back afterwards."""
    saved = {s: signal.getsignal(s) for s in (signal.SIGHUP, signal.SIGTERM, signal.SIGINT)}
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    for s, h in saved.items():
        signal.signal(s, h)


class FakeInbox:
    """What :func:`held_stops` needs of an inbox: its checkpoint."""

    checkpoint = staticmethod(Inbox.checkpoint)


def test_a_stop_signal_is_held_until_the_checkpoint_and_a_second_one_is_raised_at_once():
    inbox = FakeInbox()
    lock = threading.Lock()
    reached: list[str] = []
    with stop_signals():
        with pytest.raises(Terminated) as exc, held_stops(inbox):
            with lock:  # where a raised stop once left a lock taken
                os.kill(os.getpid(), signal.SIGHUP)
                for _ in range(1000):  # the handler runs meanwhile, and raises nothing
                    pass
                reached.append("the end of the block")
            inbox.checkpoint()  # the central's next wait
            pytest.fail("the held stop was not raised at the checkpoint")
        assert reached == ["the end of the block"] and not lock.locked()
        assert exc.value.signum == signal.SIGHUP and inbox.checkpoint is Inbox.checkpoint
        with pytest.raises(Terminated), held_stops(inbox):
            os.kill(os.getpid(), signal.SIGTERM)
            os.kill(os.getpid(), signal.SIGTERM)  # a second: at once, the way out of a hang
            for _ in range(1000):
                pass
            pytest.fail("the second stop was not raised at once")


def test_a_stop_held_to_the_end_of_the_run_is_raised_there_and_ctrl_c_is_held_too():
    inbox = FakeInbox()
    with stop_signals():
        with pytest.raises(KeyboardInterrupt) as exc:
            with held_stops(inbox):
                os.kill(os.getpid(), signal.SIGINT)
                for _ in range(1000):
                    pass
        assert type(exc.value) is KeyboardInterrupt  # Ctrl-C: exit 130, not a Terminated
        with held_stops(inbox):  # nothing held: nothing raised
            inbox.checkpoint()
    with pytest.raises(KeyboardInterrupt):  # outside: Python's own Ctrl-C again
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(1000):
            pass
