"""The commands of the in-process closed loop, pinned: their digests were recorded with
the code before the runtime's redesign (commit 46505a3) for every law, model, observer
and pipeline delay on both thesis tasks. tests/test_star.py shows the distributed unit
gives the reference's commands bit for bit, for n = 0..3 and depth 1 and 2; this test
shows the reference itself has not moved, so the two together keep lockstep commands
bit-identical across any rework of the runtime. The plant integrates with the 0.25 ms
sub-step the digests were recorded with (the default became 0.5 ms later: a choice of the
plant's, not of the controller's arithmetic these digests guard), and resolved acceleration
evaluates its model at the sample as it then did (``model_state="sample"``; the model at
the state where the command acts, the default since, is checked against its oracle in
tests/test_law_oracles.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from ctrlunit.kernels.laws import Gains
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.kernels.trajectory import circle_task, pick_place_task
from ctrlunit.plant.simulator import PlantConfig
from ctrlunit.runtime.compute.controller import simulate
from ctrlunit.runtime.observe.report import command_digest

PINNED = json.loads((Path(__file__).parent / "data" / "reference_commands.json").read_text())
TASKS = {"pick-place": pick_place_task, "circle": circle_task}


@pytest.mark.parametrize("key", sorted(PINNED))
def test_the_reference_commands_are_those_recorded_before_the_redesign(key):
    law, model, observer, delay, task = key.split("/")
    ref = simulate(P, TASKS[task](), law=law, model=model, observer=observer,
                   gains=Gains.from_bandwidth(20.0), cycles=150,
                   delay=int(delay.removeprefix("delay")),
                   plant_config=PlantConfig(substeps=4), model_state="sample")
    assert command_digest([x for c in ref.commands for x in c]) == PINNED[key]
