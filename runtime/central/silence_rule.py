"""When a silent process becomes a fault (realtime): the silence rule's arithmetic, as
pure functions of the times the central keeps (docs/faults-and-errors.md, the silence
rule in three steps). :class:`~.silence.SilenceWatch` decides with them; the
scheduler's accounting (who was kept from a CPU) is its own.

All times are ``time.monotonic_ns()`` values; a gap ``(a, b)`` is a span in which
something did not happen: the central did not run (``own_gaps``: it woke more than a
period after it meant to), or the plant's samples did not come (``plant_gaps``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable


def overlap(gaps: Iterable[tuple[int, int]], since: int, now: int) -> int:
    """How much of ``[since, now]`` the gaps cover (each counted once; gaps do not
    overlap each other)."""
    return sum(max(0, min(b, now) - max(a, since)) for a, b in gaps)


def plant_shared(plant_gaps: Iterable[tuple[int, int]], last_sample_ns: int, since: int,
                 now: int, *, every_ns: int, own_ns: int, limit_ns: int) -> int:
    """The part of a silence since ``since`` that the plant's samples shared: each gap
    in them longer than two sample intervals (``every_ns``), the one still open since
    ``last_sample_ns`` included, counts less the interval a sample takes anyway; less
    ``own_ns`` (the central's own stalls in it, not counted twice), and at most one
    limit."""
    shared = 0
    for a, b in (*plant_gaps, (last_sample_ns, now)):
        if a and b - a > 2 * every_ns:
            shared += max(0, min(b, now) - max(a, since) - every_ns)
    return min(max(0, shared - own_ns), limit_ns)


def fault_at(since: int, now: int, limit_ns: int, *, own_ns: int,
             shared: Callable[[], int]) -> int:
    """When a process silent since ``since`` becomes a fault (realtime): ``since +
    limit_ns``, later by the central's own stalls in the silence (``own_ns``); once that
    has passed, later again by what the plant shared (``shared()``, :func:`plant_shared`,
    looked at only then)."""
    end = since + limit_ns + own_ns
    return end if end >= now else end + shared()


def renewal_holds(window_ns: int, denied_ns: int, ours_ns: int, waited_ns: int,
                  stolen_ns: int) -> bool:
    """Whether an excused silence gets one more limit: over the window since it was
    granted or last renewed, the machine kept the silent process (``denied_ns``), the
    central's Zenoh threads (``ours_ns``) or its own tasks (``waited_ns``, the CPU
    pressure) from a CPU, or the hypervisor took one of its CPUs (``stolen_ns``: what
    stood on it neither ran nor waited in the machine's own accounting), for at least
    half of it."""
    return 2 * max(denied_ns, ours_ns, waited_ns, stolen_ns) >= window_ns


def renewal_cap(since: int, limit_ns: int, limits: int, own_ns: int) -> int:
    """The latest a silence since ``since`` may be excused to: ``limits`` limits, plus
    the central's own stalls in it."""
    return since + limits * limit_ns + own_ns
