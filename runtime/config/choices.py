"""The closed sets of values some settings take (runtime/config/sections.py)."""

from __future__ import annotations

CLOCKS = ("lockstep", "realtime", "freerun")
REPLY_MODES = ("auto", "fused", "each")
LATE_POLICIES = ("wait", "compute", "hold", "fault")
"""``--late-policy``: what the central does with a round whose replies are late (its share
of the deadline passed, runtime/central/late.py): wait for them, compute the late
peripherals' blocks itself (the same arithmetic: the commands do not change), hold their
last values, or stop with a fault. A round takes the strictest of its blocks', in this
order."""
PERIPHERAL_LOSSES = ("takeover", "fault")
"""``--peripheral-loss``: what the central does when a peripheral is lost (its process
exited, or it stayed silent past the silence rule): ``takeover``, compute its rounds
itself from then on (the same arithmetic: the commands do not change;
runtime/central/takeover.py), or ``fault``: stop the robot safely (exit 3)."""
BALANCES = ("off", "live")
"""``--balance``: the placement stays as it started (``off``), or the central re-places
per-axis blocks while it runs where the model of ``ctrlunit balance`` predicts a faster
period (``live``: runtime/central/rebalance.py; not in realtime)."""
MISSED_COMMANDS = ("extrapolate", "hold")
"""``--missed-command``: what the plant applies in a period whose command is late: the
command the central extrapolated for it and sent with the one before (runtime/central/settings.py,
``CommandAhead``), or the last one that came (runtime/roles/plant_node.py)."""
OVERLOAD_ACTIONS = ("auto", "halve", "continue")
"""``--overload``: what a realtime run does when its commands keep missing their deadline
(runtime/central/overload.py, ``Overload.after_interval``): ``halve`` the control rate (every
second sample, each command held two periods, the plant still ticking at the period),
``continue`` as it is; ``auto``: halve when the admission is on (the main job) and the gains
keep their margin at twice the period (``RunConfig.halves_on_overload``), continue otherwise
(a run that measures the unit as it is)."""
COMPRESSIONS = ("none", "lz4", "zstd")
"""``--record-compression`` (runtime/recording/mcap_writer.py)."""
COMMAND_DELAYS = ("full", "short")
"""When the plant applies the command of sample k (docs/architecture.md, Clocks): ``full``
(causal): at depth d, to the period that begins at tick k + d, d periods after the sample;
``short``: d - 1 periods (the realtime plant integrates the period that *ends* at tick
k + d with the command due at that tick; kept for recordings made that way)."""
CPU_SPREADS = ("same", "split")
"""``--cpus``: every role on CPU 0 (``same``), or the central on 0 and the others on 1
(``split``)."""


__all__ = ["CLOCKS", "COMMAND_DELAYS", "COMPRESSIONS", "CPU_SPREADS", "LATE_POLICIES",
           "MISSED_COMMANDS", "OVERLOAD_ACTIONS", "REPLY_MODES"]
