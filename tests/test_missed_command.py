"""``--missed-command``: what the plant applies in a period whose command is late.

The central sends, with each realtime command at the full rate, the command it expects
for the next sample (``next``, extrapolated from the last two); the plant applies it in a
period whose own command did not come in time (runtime/roles/plant_node.py,
``PlantServer.apply``), and holds the last command otherwise.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from types import SimpleNamespace
from typing import Any

import pytest
from ctrlunit.runtime.config import ConfigError, RunConfig
from ctrlunit.runtime.roles.plant_node import PlantServer
from ctrlunit.runtime.transport.codec import decode, encode

UNIT = "t-missed"


class FakePlant:
    def __init__(self) -> None:
        self.command = [0.0, 0.0, 0.0]

    def set_command(self, tau: list[float]) -> None:
        self.command = list(tau)


class FakeNode:
    def __init__(self) -> None:
        self.rejected: Counter[str] = Counter()
        self.last_heard_ns = time.monotonic_ns()
        self.keys = SimpleNamespace(sample="s", command="c")

    def publisher(self, _key: str) -> object:
        return object()

    def route(self, *_: object) -> None:
        pass

    def decode(self, data: bytes) -> dict | None:
        return decode(data, UNIT)

    def reject(self, reason: str) -> None:
        self.rejected[reason] += 1


def _server() -> PlantServer:
    server = PlantServer(FakeNode(), FakePlant(), depth=2, initial=[9.0, 9.0, 9.0],
                         period_s=1e-3)
    server.sample_no = 100  # every command below is for a sample already published
    return server


def _command(cycle: int, tau: list[float], nxt: object = None) -> bytes:
    extra = {} if nxt is None else {"next": nxt}
    return encode(UNIT, cycle, "command", tau=tau, **extra)


def test_a_late_command_is_replaced_by_the_one_extrapolated_with_the_command_before():
    server = _server()
    server.take_command(_command(5, [1.0, 2.0, 3.0], [1.5, 2.5, 3.5]))
    assert server.apply(5) and server.plant.command == [1.0, 2.0, 3.0]
    # 6 is late: the plant applies what 5 carried for it, and counts it as missed
    assert not server.apply(6)
    assert server.plant.command == [1.5, 2.5, 3.5] and server.spares_applied == 1
    # 6 comes late with its own extrapolation for 7; 7 is late too: 6's is applied, not
    # 6 itself (a period older than what is due)
    server.take_command(_command(6, [2.0, 3.0, 4.0], [2.5, 3.5, 4.5]))
    assert not server.apply(7)
    assert server.plant.command == [2.5, 3.5, 4.5] and server.spares_applied == 2
    assert server.applied_cycle == 6 and server.commands == {}
    # the one for 8 arrives in time: it is applied as it is
    server.take_command(_command(8, [3.0, 4.0, 5.0]))
    assert server.apply(8) and server.plant.command == [3.0, 4.0, 5.0]
    assert server.spares == {}


def test_without_an_extrapolated_command_a_late_one_holds_the_last_that_came():
    server = _server()
    server.take_command(_command(5, [1.0, 2.0, 3.0]))
    assert server.apply(5)
    assert not server.apply(6) and server.plant.command == [1.0, 2.0, 3.0]
    server.take_command(_command(6, [2.0, 3.0, 4.0]))  # late: applied at the next tick
    assert not server.apply(7) and server.plant.command == [2.0, 3.0, 4.0]
    assert server.spares_applied == 0
    # an extrapolation for a cycle whose own command came is not used
    server.take_command(_command(7, [5.0, 5.0, 5.0], [6.0, 6.0, 6.0]))
    server.take_command(_command(8, [7.0, 7.0, 7.0]))
    assert server.apply(8) and server.plant.command == [7.0, 7.0, 7.0]
    assert server.spares_applied == 0


@pytest.mark.parametrize("nxt", [[1.0, 2.0], [1.0, math.nan, 2.0], "x", [1, 2, True]])
def test_a_command_with_a_malformed_extrapolation_is_rejected_whole(nxt):
    server = _server()
    server.take_command(_command(5, [1.0, 2.0, 3.0], nxt))
    assert server.commands == {} and server.spares == {}
    assert server.node.rejected == Counter({"bad_value": 1})


def test_an_admission_trials_commands_are_checked_counted_and_never_applied():
    """The trial sends its commands flagged ``probe`` (the run's messaging load without
    motion): the plant checks each as a run's, counts it and keeps none, during the trial
    and after the start alike; during a trial a command of the run is dropped."""
    server = _server()
    probe = encode(UNIT, (1 << 41) + 3, "command", tau=[1.0, 2.0, 3.0], next=[1.0, 2.0, 3.0],
                   probe=True)
    server.take_command(probe, trial=True)
    server.take_command(probe)  # one that comes after the start
    assert server.trial_commands == 2 and server.commands_taken == 0
    assert server.commands == {} and server.spares == {} and not server.node.rejected
    server.take_command(_command(5, [1.0, 2.0, 3.0]), trial=True)
    assert server.commands == {} and server.commands_taken == 0
    bad = encode(UNIT, 7, "command", tau=[1.0, math.inf, 3.0], probe=True)
    server.take_command(bad, trial=True)
    assert server.trial_commands == 2 and server.node.rejected == Counter({"bad_value": 1})
    server.take_command(_command(5, [1.0, 2.0, 3.0]))  # the run's own still acts
    assert server.apply(5) and server.plant.command == [1.0, 2.0, 3.0]


def _ahead(clock: str = "realtime", missed: str = "extrapolate",
           halved_at: int | None = None) -> tuple[Any, Any]:
    """The central's rule for the command ahead (runtime/central/settings.py,
    ``CommandAhead``) as a run of ``clock`` and ``--missed-command missed`` sets it,
    with the control rate's grid (halved from ``halved_at``)."""
    from ctrlunit.runtime.central.settings import CommandAhead, LoopSettings
    from ctrlunit.runtime.compute.stride import StrideSchedule

    grid = StrideSchedule()
    if halved_at:
        grid.change(2, halved_at)
    rc = RunConfig.of(clock=clock, missed_command=missed)
    settings = LoopSettings.of(rc, peripherals=3, cycles=100, first_cycle=0, trial=False)
    return CommandAhead(settings.extrapolate), grid


def test_the_central_extrapolates_only_between_consecutive_commands_at_the_full_rate():
    def sent(rule, cycles):
        ahead, grid = rule
        return [ahead.after(c, [float(c), 2.0 * c, 1.0], grid=grid) for c in cycles]

    assert sent(_ahead(), [3, 4, 5, 7]) == [None, [5.0, 10.0, 1.0], [6.0, 12.0, 1.0], None]
    # halved from 6 on: 4's successor is 5, 5's would be 6 (on the new grid), then none
    assert sent(_ahead(halved_at=6), [4, 5, 6, 8]) == [None, [6.0, 12.0, 1.0], None, None]
    for rule in (_ahead("lockstep"), _ahead(missed="hold")):
        assert sent(rule, [3, 4, 5]) == [None, None, None]


def test_missed_command_accepts_extrapolate_or_hold_only():
    assert RunConfig.of().schedule.missed_command == "extrapolate"
    with pytest.raises(ConfigError, match="missed.command"):
        RunConfig.of(missed_command="guess").validate()


def test_a_burst_of_late_commands_costs_less_tracking_extrapolated_than_held():
    """The offline bench (bench/missed.py) with the plant's own rule: no late command,
    both the same (the extrapolations are never applied); four consecutive commands a
    period late in the task's fastest stretch, extrapolated tracks closer than held."""
    from ctrlunit.bench.missed import tracking_with_late

    period = 1.6e-3
    base = {m: tracking_with_late(period, {}, missed=m) for m in ("hold", "extrapolate")}
    assert base["hold"] == base["extrapolate"] < 1e-4
    worst = {m: max(tracking_with_late(period, {c: 1 for c in range(s, s + 4)}, missed=m)
                    for s in (60, 100, 140)) for m in ("hold", "extrapolate")}
    assert base["hold"] < worst["extrapolate"] < 0.75 * worst["hold"], worst


def test_every_command_a_period_late_keeps_the_loop_at_the_default_gains():
    """An overloaded host can make every command a period late for a while: each then
    acts a period later than the loop was designed for, and the plant applies the
    extrapolations. At 3.2 ms the bandwidth the default used to take (20 Hz, its margin
    at the designed delay alone) lost the robot that way (tracking past the 20 mm that
    stops it, the torques at their limits), as realtime runs loaded by a reader did; the
    default now keeps its margin at twice the period (1 / (25 T), 12.5 Hz here) and
    tracks within a few millimetres (docs/architecture.md, overload)."""
    from ctrlunit.bench.missed import tracking_with_late
    from ctrlunit.runtime.compute.setup import make_setup

    period = 3.2e-3
    rc = RunConfig.of(period=period, pipeline=2, peripherals=0, clock="lockstep")
    assert rc.bandwidth == pytest.approx(12.5)
    n = make_setup(rc.validate()).cycles
    late = {k: 1 for k in range(n // 10, n)}  # from a tenth of the task on
    default = tracking_with_late(period, late, missed="extrapolate")
    designed_only = tracking_with_late(period, late, missed="extrapolate", bandwidth_hz=20.0)
    assert default < 2e-3 < rc.control.max_error < designed_only, (default, designed_only)


def test_past_the_extrapolated_command_the_plant_holds_the_trend_of_the_last_ones():
    """A central silent for many periods: the plant follows the least-squares line through
    its last commands for a few periods, then holds it there; not the last command alone,
    whose interval-to-interval noise, held for tens of milliseconds, drove the slow pick &
    place 6.5-9.4 mm off (runtime/roles/plant_hold.py)."""
    from ctrlunit.runtime.roles.plant_hold import CommandHold

    server = _server()
    noise = [0.3, -0.3, -0.3, 0.3] * 4  # a ramp of slope 0.01 a period, with noise
    for k in range(16):
        tau = [1.0 + 0.01 * k + noise[k], 2.0, -1.0 - 0.01 * k]
        server.take_command(_command(10 + k, tau))
        assert server.apply(10 + k)
    assert server.plant.command[0] == pytest.approx(1.15 + 0.3)  # the last one, noisy
    ahead = CommandHold(1e-3).ahead
    for k in range(26, 40):  # nothing comes: the trend, followed `ahead` periods, then held
        assert not server.apply(k)
        at = min(k, 25 + ahead)
        got = server.plant.command
        assert got[0] == pytest.approx(1.0 + 0.01 * (at - 10)), (k, got)
        assert got[1] == pytest.approx(2.0) and got[2] == pytest.approx(-1.0 - 0.01 * (at - 10))
    assert server.misses == 0  # counting misses is the tick loop's, not apply's


@pytest.mark.parametrize(("period_s", "window", "ahead"), [(1e-3, 16, 4), (5e-4, 32, 8),
                                                           (2.5e-3, 6, 2), (0.02, 3, 1)])
def test_the_hold_spans_the_same_time_at_every_period(period_s, window, ahead):
    from ctrlunit.runtime.roles.plant_hold import CommandHold

    hold = CommandHold(period_s)
    assert (hold.recent.maxlen, hold.ahead) == (window, ahead)
    assert hold.held(0) is None
    hold.note(0, [1.0, 2.0, 3.0])
    hold.note(1, [3.0, 2.0, 1.0])
    assert hold.held(5) == [2.0, 2.0, 2.0]  # fewer than three: their mean
    with pytest.raises(ValueError, match="period_s must be > 0"):
        CommandHold(0.0)


def test_off_the_halved_grid_the_acting_command_holds_its_second_period():
    """At the halved control rate each command acts two periods (the central's model
    assumes so): off the grid the plant keeps it, not the trend of the last ones, which
    had the halved rate track 1.1 mm where it tracks 0.02
    (docs/measurements/2026-11-29-late-runs.md). A late command that comes off the grid
    is applied at once; a command missed on the grid still gets the trend."""
    server = _server()
    server.take_stride({"stride": 2, "start": 10})
    for k in range(10, 20, 2):  # a ramp: the trend at an odd cycle is not the last one
        tau = [1.0 + 0.1 * k, 2.0, 3.0 - 0.1 * k]
        server.take_command(_command(k, tau))
        assert server.apply(k) and server.plant.command == tau
        assert not server.apply(k + 1)
        assert server.plant.command == tau, k + 1
    assert server.spares_applied == 0
    assert not server.apply(20)  # missed on the grid: the trend of the last ones
    assert server.plant.command == pytest.approx([1.0 + 0.1 * 20, 2.0, 3.0 - 0.1 * 20])
    server.take_command(_command(20, [5.0, 5.0, 5.0]))  # late: it comes off the grid
    assert not server.apply(21) and server.plant.command == [5.0, 5.0, 5.0]
    assert server.misses == 0  # counting misses is the tick loop's, on the grid only
