"""The run configuration: frozen sections built once from flat option names."""

from __future__ import annotations

import dataclasses
import json

import pytest
from ctrlunit.runtime.config import FLAT, ConfigError, RunConfig
from ctrlunit.runtime.config.sections import RENAMED, SECTIONS


def test_every_section_field_has_exactly_one_flat_name() -> None:
    fields = [(name, f.name) for name, cls in SECTIONS.items()
              for f in dataclasses.fields(cls)]
    assert sorted(FLAT.values()) == sorted(fields)
    assert len(set(FLAT)) == len(fields)
    for flat, field in RENAMED.items():
        assert FLAT[flat] == ("plant", field)


def test_a_configuration_and_its_sections_cannot_be_changed() -> None:
    rc = RunConfig.of(peripherals=2, plant_lag=1e-4)
    with pytest.raises(dataclasses.FrozenInstanceError):
        rc.schedule.peripherals = 3  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        rc.plant = rc.plant  # type: ignore[misc]


def test_options_land_in_their_sections() -> None:
    rc = RunConfig.of(peripherals=2, pipeline=2, law="pd", plant_lag=1e-4, timeout=0.5,
                      record="x.mcap", rt_priority=10)
    assert (rc.schedule.peripherals, rc.schedule.pipeline, rc.control.law, rc.plant.lag,
            rc.transport.timeout, rc.run.record, rc.schedule.rt_priority) \
        == (2, 2, "pd", 1e-4, 0.5, "x.mcap", 10)
    assert rc.option("plant_lag") == 1e-4
    assert rc.plant == dataclasses.replace(SECTIONS["plant"](), lag=1e-4)


def test_replace_gives_a_new_configuration_and_keeps_the_old() -> None:
    rc = RunConfig.of(period=2e-3, unit="ufixed")
    new = rc.replace(period=1e-3, record=None)
    assert (rc.schedule.period, new.schedule.period) == (2e-3, 1e-3)
    assert new.transport.unit == "ufixed"  # a generated default is carried, not drawn again
    assert new.control == rc.control and new.plant == rc.plant


def test_flat_dict_round_trip_is_exact() -> None:
    rc = RunConfig.of(peripherals=1, late={"law": "hold"}, listen=["tcp/127.0.0.1:7447"],
                      plant_friction=0.3, foxglove="8765", cycles=10)
    data = json.loads(json.dumps(rc.to_dict()))
    assert set(data) == set(FLAT)
    assert RunConfig.from_dict(data) == rc


def test_a_configuration_recorded_before_the_model_state_evaluates_it_at_the_sample() -> None:
    data = RunConfig.of(unit="uold").to_dict()
    assert data.pop("model_state") == "auto"  # the default of a run today
    assert RunConfig.from_dict(data).control.model_state == "sample"
    with pytest.raises(ConfigError, match=r"--model-state = 'later': allowed auto, acting, "
                                          r"sample, foreseen, foreseen2"):
        RunConfig.of(model_state="later").validate()


@pytest.mark.parametrize(("clock", "depth", "state"), [
    ("realtime", 2, "foreseen"), ("realtime", 1, "acting"), ("lockstep", 2, "acting")])
def test_a_recording_that_says_auto_replays_with_the_model_state_auto_meant_then(
        clock, depth, state):
    """Recordings now say what ``auto`` resolved to; one that says ``auto`` was made when
    ``auto`` meant ``foreseen`` in realtime at depth 2, and replays so."""
    old = RunConfig.of(clock=clock, pipeline=depth).to_dict()
    assert old["model_state"] == "auto"
    assert RunConfig.from_recording(old).control.model_state == state
    rc = RunConfig.of(clock=clock, pipeline=depth)
    new = rc.replace(model_state=rc.resolved_model_state).to_dict()  # as the recorder writes
    assert RunConfig.from_recording(new).resolved_model_state == rc.resolved_model_state


@pytest.mark.parametrize(("clock", "depth", "law", "state"), [
    ("realtime", 2, "resolved-acceleration", "foreseen2"),
    ("realtime", 1, "resolved-acceleration", "acting"),
    ("lockstep", 2, "resolved-acceleration", "acting"),
    ("freerun", 2, "resolved-acceleration", "acting"),
    ("realtime", 2, "computed-torque", "acting"),
])
def test_the_model_state_auto_is_foreseen2_in_realtime_at_depth_two(clock, depth, law, state):
    rc = RunConfig.of(clock=clock, pipeline=depth, law=law)
    assert rc.control.model_state == "auto" and rc.resolved_model_state == state
    assert RunConfig.of(clock=clock, pipeline=depth, model_state="sample"
                        ).resolved_model_state == "sample"
    # the gains: the foreseen model servoes the acting state, as acting does
    assert rc.replace(period=8e-3).bandwidth == (5.0 if law == "resolved-acceleration"
                                                 else 2.5)


@pytest.mark.parametrize(("period", "law", "state", "hz"), [
    (1e-3, "resolved-acceleration", "acting", 20.0),
    (2e-3, "resolved-acceleration", "acting", 20.0),
    (2.5e-3, "resolved-acceleration", "acting", 16.0),
    (4e-3, "resolved-acceleration", "acting", 10.0),
    (8e-3, "resolved-acceleration", "acting", 5.0),
    (1e-3, "resolved-acceleration", "sample", 20.0),
    (4e-3, "resolved-acceleration", "sample", 5.0),
    (4e-3, "computed-torque", "acting", 5.0),
])
def test_the_default_bandwidth_is_capped_by_the_delay_the_law_does_not_predict(
        period: float, law: str, state: str, hz: float) -> None:
    """20 Hz, at most 1 / (25 T) where the law servoes the state predicted for the
    period its command acts in (its margin at twice the period: a command a period late,
    or the halved rate), 1 / (50 T) where it servoes the sample's; ``--bandwidth`` is
    taken as given."""
    rc = RunConfig.of(period=period, law=law, model_state=state)
    assert rc.bandwidth == pytest.approx(hz)
    assert rc.replace(bandwidth_hz=33.0).bandwidth == 33.0


@pytest.mark.parametrize("name", ["nope", "plant.lag", "substeps"])
def test_an_unknown_option_is_named(name: str) -> None:
    with pytest.raises(ConfigError, match=f"unknown run option '{name}'"):
        RunConfig.of(**{name: 1})
    with pytest.raises(ConfigError, match=f"unknown run option '{name}'"):
        RunConfig.from_dict({name: 1})


def test_validation_names_the_flat_option() -> None:
    with pytest.raises(ConfigError, match=r"--plant-substeps = 0: allowed 1 to 1000"):
        RunConfig.of(plant_substeps=0).validate()
    with pytest.raises(ConfigError, match=r"--max-error = 2 m: allowed"):
        RunConfig.of(max_error=2.0).validate()


def test_eq_iv23_takes_the_traversal_where_the_clock_imposes_the_period():
    """Realtime at either depth: the traversal (the period is the clock's); freerun and
    lockstep: the traversal at depth 1, the mean period at depth 2."""
    from ctrlunit.runtime.observe.efficiency import parallel_time

    for clock, depth, want in (("realtime", 1, 2e-4), ("realtime", 2, 2e-4),
                               ("freerun", 1, 2e-4), ("freerun", 2, 9e-4),
                               ("lockstep", 2, 9e-4)):
        rc = RunConfig.of(clock=clock, pipeline=depth)
        t, what = parallel_time(rc, traversal_p50=2e-4, period_mean=9e-4)
        assert t == want, (clock, depth)
        assert ("imposes the period" in what) == (clock == "realtime")
