"""How a run or a command ends on Ctrl-C, SIGTERM or SIGHUP.

Ctrl-C raises ``KeyboardInterrupt`` in Python's main thread; inside :func:`stop_signals`
SIGTERM (``kill``, ``timeout``, a service manager) and SIGHUP (the terminal closed) raise
:class:`Terminated`, a ``KeyboardInterrupt``, so one path ends the run for all three: the
central says stop, the plant holds and brakes, the report and the recording are written.
The exit code is 130 for Ctrl-C and 128 + the signal's number for the others (143, 129),
as a shell reports a process the signal ended.

A signal this process was started with ignored stays ignored (the convention every Unix
program keeps): ``nohup`` ignores SIGHUP, so closing the terminal does not stop a run
started under it; a background job of a non-interactive shell ignores SIGINT.

A command that runs the unit several times (``bench``, ``latency --unit``) calls
:func:`raise_if_stopped` after each run, so that a stop ends the command too, not only
the run it arrived in.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from ..config import EXIT_INTERRUPTED

STOP_SIGNALS = (signal.SIGTERM, signal.SIGHUP)
"""Signals that end a run as Ctrl-C does."""


def not_ignored(signals: tuple[int, ...]) -> tuple[int, ...]:
    """The signals of ``signals`` whose disposition here is not ``SIG_IGN`` (module notes)."""
    return tuple(s for s in signals if signal.getsignal(s) is not signal.SIG_IGN)


class Terminated(KeyboardInterrupt):
    """A signal of :data:`STOP_SIGNALS` arrived."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def stop_of(stop: BaseException | int | None) -> tuple[int, dict[str, Any]]:
    """The exit code and the report's ``fault`` of a run stopped by Ctrl-C (a plain
    ``KeyboardInterrupt``, ``SIGINT`` or ``None``) or by a signal (:class:`Terminated`,
    or the signal's number)."""
    signum = stop.signum if isinstance(stop, Terminated) else stop
    if not isinstance(signum, int) or signum == signal.SIGINT:
        return EXIT_INTERRUPTED, {"process": "user", "message": "interrupted",
                                  "code": EXIT_INTERRUPTED}
    code = 128 + signum
    return code, {"process": "user", "code": code,
                  "message": f"terminated ({signal.Signals(signum).name})"}


def stopped_by_user(report: dict[str, Any]) -> bool:
    """Whether the run of ``report`` was ended by Ctrl-C or a stop signal."""
    fault = report.get("fault")
    return isinstance(fault, dict) and fault.get("process") == "user"


def raise_if_stopped(code: int, report: dict[str, Any]) -> None:
    """Raise the stop again (``KeyboardInterrupt`` or :class:`Terminated`) if the run of
    ``report`` ended on one: the command that started the run ends as well."""
    if not stopped_by_user(report):
        return
    if code == EXIT_INTERRUPTED:
        raise KeyboardInterrupt
    raise Terminated(code - 128)


@contextmanager
def stop_signals() -> Iterator[None]:
    """While inside, SIGTERM and SIGHUP raise :class:`Terminated` in the main thread
    (elsewhere, or where Python cannot set handlers, nothing changes; a signal ignored
    when it is entered stays ignored)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def raise_terminated(signum: int, _frame: Any) -> None:
        raise Terminated(signum)

    old = {s: signal.signal(s, raise_terminated) for s in not_ignored(STOP_SIGNALS)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
