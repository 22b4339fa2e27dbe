"""The engine: running an interval's sample-free steps ahead changes no value."""

from __future__ import annotations

import pytest
from ctrlunit.kernels.kinematics import inverse_kinematics
from ctrlunit.kernels.laws import Gains
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.kernels.trajectory import pick_place_task
from ctrlunit.runtime.compute.controller import Controller, build_engine
from ctrlunit.topology.graph import LAWS


@pytest.mark.parametrize("law", LAWS)
def test_sample_free_steps_run_before_the_sample_give_the_same_command(law):
    task = pick_place_task()
    engine = build_engine(P, task, law=law, model="complete", gains=Gains.from_bandwidth(20.0),
                          period=1e-3, peripherals=3)
    assert engine.presample >= 1
    whole = Controller(engine, 1e-3, P.increment, tuple(task.start()))
    split = Controller(engine, 1e-3, P.increment, tuple(task.start()))
    for k in range(40):  # samples on the reference path, offset by a few increments
        q = inverse_kinematics(P, task.sample(k * 1e-3)[0])
        counts = [round(float(x) / P.increment) + 5 * (i + 1) for i, x in enumerate(q)]
        a = engine.run_local(whole.sources(k, counts))
        whole.handoff(a)
        ctx = split.context(k)
        engine.prefix(ctx)  # before the sample: only time and the previous estimate
        split.measure(ctx, k, counts)
        b = engine.run_local(ctx, skip_prefix=True)
        split.handoff(b)
        assert list(a["cmd"]) == list(b["cmd"]), f"cycle {k}"
