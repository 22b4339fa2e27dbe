"""The whole unit in this process (tests/loopback.py): the central's real scheduling,
intake and pipeline give, in lockstep, the commands of the one-process reference for
every star size and depth, and a lost reply becomes the named fault."""

from __future__ import annotations

import pytest
from ctrlunit.kernels.laws import Gains
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.kernels.trajectory import pick_place_task
from ctrlunit.runtime.central import Fault
from ctrlunit.runtime.compute.controller import simulate
from ctrlunit.runtime.config import EXIT_PERIPHERAL
from ctrlunit.runtime.transport.codec import decode
from loopback import LoopbackUnit, lockstep_config
from runner import unit_id

CYCLES = 120


@pytest.mark.parametrize(("n", "depth"), [(0, 1), (1, 1), (3, 1), (1, 2), (2, 2), (3, 2)])
def test_lockstep_commands_equal_the_one_process_reference(n, depth):
    u = LoopbackUnit(lockstep_config(unit_id("lb"), peripherals=n, pipeline=depth,
                                     cycles=CYCLES, max_error=1.0))
    u.run()
    ref = simulate(P, pick_place_task(), gains=Gains.from_bandwidth(20.0), cycles=CYCLES,
                   delay=u.rc.delay_periods)
    assert u.commands() == [[float(x) for x in c] for c in ref.commands]
    assert u.central.done == CYCLES and not u.node.rejected


@pytest.mark.parametrize("law", ["computed-torque", "pd-feedforward", "pd-gravity", "pd"])
@pytest.mark.parametrize(("n", "depth"), [(1, 1), (2, 1), (1, 2), (2, 2)])
def test_every_law_gives_the_one_process_commands_with_the_axes_spread_unevenly(law, n, depth):
    """The other laws with one or two peripherals (a peripheral holding several axes);
    tests/test_star.py runs them through ``ctrlunit start`` at n = 0 and 3."""
    u = LoopbackUnit(lockstep_config(unit_id("lblaw"), peripherals=n, pipeline=depth,
                                     cycles=CYCLES, law=law, max_error=1.0))
    u.run()
    ref = simulate(P, pick_place_task(), law=law, gains=Gains.from_bandwidth(20.0),
                   cycles=CYCLES, delay=u.rc.delay_periods)
    assert u.commands() == [[float(x) for x in c] for c in ref.commands]
    assert u.central.done == CYCLES and not u.node.rejected


def test_a_lost_reply_is_the_peripherals_fault_after_the_timeout():
    """Under ``--peripheral-loss fault`` (the default takes the peripheral over:
    tests/test_takeover.py)."""
    u = LoopbackUnit(lockstep_config(unit_id("lblost"), peripherals=3, pipeline=1,
                                     cycles=CYCLES, timeout=0.2, peripheral_loss="fault"))
    unit = u.rc.transport.unit

    def lose(key: str, data: bytes) -> bool:
        if not key.endswith("/central/reply/2"):
            return False
        return any(p["cycle"] == 30 for p in decode(data, unit)["parts"])
    u.bus.drop = lose
    with pytest.raises(Fault) as exc:
        u.run()
    assert (exc.value.process, exc.value.code) == ("peripheral-2", EXIT_PERIPHERAL)
    assert str(exc.value).startswith("peripheral 2 did not answer round 0 of cycle 30: ")
    assert u.central.done == 30
