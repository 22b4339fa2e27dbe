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

While a run moves (:func:`held_stops`) a stop is not raised where the signal finds the
main thread but held, and raised where the central next waits for a message, between
two turns of its loop (runtime/transport/node.py, ``Inbox.checkpoint``): raised anywhere,
it once left a lock taken (inside a ``with`` block's exit) and the stop then hung. A
second signal while one is held is raised at once.
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


def _stop(signum: int) -> KeyboardInterrupt:
    """The exception a stop signal raises: ``KeyboardInterrupt`` for Ctrl-C, else
    :class:`Terminated`."""
    return KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)


_held: list[int] = []
"""The stop signal held while a run moves (:func:`held_stops`), at most one."""
_holding: list[bool] = []
"""Whether a :func:`held_stops` region is active (a stack: one entry per region)."""


def raise_held() -> None:
    """Raise the stop held by :func:`held_stops`, if any (the place where it is safe)."""
    if _held:
        raise _stop(_held.pop())


@contextmanager
def held_stops(inbox: Any) -> Iterator[None]:
    """While inside (in the main thread, within :func:`stop_signals`), a stop signal is
    held and raised at ``inbox``'s next wait (its ``checkpoint``), not where the signal
    finds the main thread (module notes); one still held at the end is raised there."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _holding.append(True)
    before = inbox.checkpoint
    inbox.checkpoint = raise_held
    try:
        yield
    finally:
        inbox.checkpoint = before
        _holding.pop()
    raise_held()


@contextmanager
def stop_signals() -> Iterator[None]:
    """While inside, SIGTERM and SIGHUP raise :class:`Terminated` and Ctrl-C
    ``KeyboardInterrupt`` in the main thread, or are held (:func:`held_stops`); elsewhere,
    or where Python cannot set handlers, nothing changes; a signal ignored when it is
    entered stays ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_stop(signum: int, _frame: Any) -> None:
        if _holding and not _held:
            _held.append(signum)
            return
        raise _stop(signum)

    catch = not_ignored((signal.SIGINT, *STOP_SIGNALS))
    old = {s: signal.signal(s, on_stop) for s in catch
           if s != signal.SIGINT or signal.getsignal(s) is signal.default_int_handler}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        _held.clear()
