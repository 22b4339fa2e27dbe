"""``replay`` (runtime/recording/replay.py) in this process, on recordings the loopback unit
(tests/loopback.py) makes with the real recorder: verification finds every kind of
tampering and names where, a held round is checked and used as the central used it, the
CSV holds the recorded signals, and republishing keeps the recorded pace, order, topics
and window (on a clock the test moves)."""

from __future__ import annotations

import csv
import json
from collections import namedtuple
from pathlib import Path
from typing import Any

import msgpack
import pytest
from ctrlunit.runtime.recording import reader, replay, republish
from ctrlunit.runtime.recording.replay import Divergence
from loopback import record_lockstep
from runner import unit_id

CYCLES = 520  # past 500: the progress callback's second call


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> tuple[Path, Any]:
    path = tmp_path_factory.mktemp("replay") / "run.mcap"
    # the circle: the three axes differ (on pick & place, in the x-z plane, two are equal)
    unit = record_lockstep(str(path), unit_id("replay"), peripherals=3, pipeline=2,
                           cycles=CYCLES, max_error=1.0, task="circle")
    return path, unit


@pytest.fixture
def rec(made) -> reader.Recording:
    return reader.read(made[0])  # a fresh copy: tests tamper with it


def messages(rec: reader.Recording, topic: str) -> list[dict]:
    return [msgpack.unpackb(d) for _, d in rec.topics[topic]]


def rewrite(rec: reader.Recording, topic: str, edit: Any) -> None:
    """Apply ``edit(msg) -> msg | None`` (None: drop it) to every message of ``topic``."""
    out = []
    for t, data in rec.topics[topic]:
        m = edit(msgpack.unpackb(data))
        if m is not None:
            out.append((t, msgpack.packb(m, use_single_float=False)))
    rec.topics[topic] = out


def parts_edit(cycle: int, stage: int, edit: Any) -> Any:
    """An edit of the part (cycle, stage) of a fused message; ``edit(part) -> part|None``."""
    def go(m: dict) -> dict:
        parts = []
        for part in m["parts"]:
            if (part["cycle"], part["stage"]) == (cycle, stage):
                part = edit(part)
            if part is not None:
                parts.append(part)
        m["parts"] = parts
        return m
    return go


def reply_part(rec: reader.Recording, peripheral: int, cycle: int, stage: int) -> dict:
    for m in messages(rec, f"/central/reply/{peripheral + 1}"):
        for part in m["parts"]:
            if (part["cycle"], part["stage"]) == (cycle, stage):
                return part
    raise AssertionError("no such reply")


# -- verify ---------------------------------------------------------------------------------


def test_the_loopback_recording_verifies_every_interval(rec, made):
    done, div = replay.verify(rec)
    assert (done, div) == (CYCLES, None)
    assert made[1].central.done == CYCLES


def test_progress_is_reported_every_500_intervals(rec):
    calls = []
    replay.verify(rec, progress=lambda i, n: calls.append((i, n)))
    assert calls == [(0, CYCLES), (500, CYCLES)]


@pytest.mark.parametrize("block", ["reference", "predict", "ik_obs0", "jinv_obs0",
                                   "residual0", "observer0", "velocity", "law", "ik", "jinv",
                                   "jdot", "accel", "dyn_axis", "dyn_central", "output"])
def test_a_perturbed_block_is_named_with_its_cycle(rec, block):
    done, div = replay.verify(rec, alter=(block, 137))
    assert div is not None and done == 137
    assert (div.cycle, div.block) == (137, block)
    assert div.expected != div.got
    per_axis = block in {b.name for b in replay._setup(rec).plan.graph.axis_blocks}
    assert (div.axis is not None) == per_axis


def test_a_perturbed_block_outside_the_compared_cycles_is_not_reported_there(rec):
    done, div = replay.verify(rec, cycles=(200, 260), alter=("ik", 300))
    assert (done, div) == (60, None)
    done, div = replay.verify(rec, cycles=(200, 260), alter=("ik", 259))
    assert (done, div.cycle, div.block) == (59, 259, "ik")


def test_a_tampered_reply_value_names_its_block_axis_and_both_values(rec):
    part = reply_part(rec, 1, 40, 1)
    name = next(n for n in part["vals"] if n.startswith("tauq"))
    wrong = part["vals"][name][0] + 1e-9

    def edit(p: dict) -> dict:
        p["vals"][name][0] = wrong
        return p
    rewrite(rec, "/central/reply/2", parts_edit(40, 1, edit))
    done, div = replay.verify(rec)
    assert done == 40
    assert div == Divergence(40, "dyn_axis", 1, name, wrong, part["vals"][name][0])


def test_a_tampered_trace_value_names_the_block_that_makes_it(rec):
    part = reply_part(rec, 2, 41, 1)
    name = next(iter(part["trace"]))

    def edit(p: dict) -> dict:
        p["trace"][name][0] = -12345.0
        return p
    rewrite(rec, "/central/reply/3", parts_edit(41, 1, edit))
    done, div = replay.verify(rec)
    producer = {o: b.name for b in replay._setup(rec).plan.graph.blocks for o in b.outputs}
    assert (done, div.cycle, div.block, div.axis, div.value, div.expected) == (
        41, 41, producer[name], 2, name, -12345.0)


def test_a_tampered_central_trace_value_names_the_central_block(rec):
    def edit(m: dict) -> dict:
        if m["cycle"] == 42:
            m["vals"]["pc"] = [0.0, 0.0, 0.0]
        return m
    want = next(m["vals"]["pc"] for m in messages(rec, "/trace/central") if m["cycle"] == 42)
    rewrite(rec, "/trace/central", edit)
    done, div = replay.verify(rec)
    assert (done, div.cycle, div.block, div.axis, div.value, div.expected) == (
        42, 42, "reference", None, "pc", [0.0, 0.0, 0.0])
    assert div.got == want


def test_an_interval_without_central_trace_is_a_divergence(rec):
    """A whole recording that traces the central but lacks one interval's trace has lost
    what verify compares the central's blocks with: the interval diverges, naming it
    (a salvaged file's last intervals may lack theirs: the cut falls between chunks)."""
    rewrite(rec, "/trace/central", lambda m: None if m["cycle"] == 48 else m)
    done, div = replay.verify(rec)
    assert (done, div.cycle, div.block, div.value) == (48, 48, "(central trace)", "missing")


def test_a_tampered_request_names_the_block_of_the_value(rec):
    def edit(p: dict) -> dict:
        p["vals"]["pd"] = [1.0, 2.0, 3.0]
        return p
    rewrite(rec, "/peripheral/request", parts_edit(43, 1, edit))
    done, div = replay.verify(rec)
    assert (done, div.cycle, div.block, div.axis, div.value, div.expected) == (
        43, 43, "velocity", None, "pd", [1.0, 2.0, 3.0])


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_tampered_per_axis_request_value_names_its_axis(rec, axis):
    def edit(p: dict) -> dict:
        p["vals"]["qmeas_i"][axis] = 0.5
        return p
    rewrite(rec, "/peripheral/request", parts_edit(44, 0, edit))
    done, div = replay.verify(rec)
    assert (done, div.cycle, div.axis, div.value, div.expected) == (44, 44, axis, "qmeas_i",
                                                                     0.5)


def test_a_missing_request_or_reply_is_a_divergence(rec):
    rewrite(rec, "/peripheral/request", parts_edit(45, 1, lambda p: None))
    assert replay.verify(rec) == (45, Divergence(45, "(request)", None, "missing", None, None))
    rec = reader.read(rec.path)
    rewrite(rec, "/central/reply/1", parts_edit(46, 0, lambda p: None))
    assert replay.verify(rec) == (46, Divergence(46, "(reply)", None, "missing", None, None))


def test_a_tampered_command_is_a_divergence_of_the_output(rec):
    def edit(m: dict) -> dict:
        if m["cycle"] == 47:
            m["tau"][1] += 1e-12
        return m
    rewrite(rec, "/plant/command", edit)
    done, div = replay.verify(rec)
    assert (done, div.cycle, div.block, div.value) == (47, 47, "output", "cmd")
    assert div.expected[1] != div.got[1] and div.expected[0] == div.got[0]


def test_a_divergence_reads_as_where_what_and_both_values():
    assert str(Divergence(3, "ik", 1, "q_i", 1.5, 2.5)) == (
        "first divergence at cycle 3, block ik (axis 1), value q_i: recorded 1.5, "
        "recomputed 2.5")
    assert str(Divergence(4, "law", None, "cmd", [1], [2])) == (
        "first divergence at cycle 4, block law (central), value cmd: recorded [1], "
        "recomputed [2]")


# -- held rounds --------------------------------------------------------------------------


def hold(rec: reader.Recording, peripheral: int, cycle: int, stage: int,
         vals: dict) -> None:
    data = msgpack.packb({"cycle": cycle, "stage": stage, "peripheral": peripheral,
                          "vals": vals}, use_single_float=False)
    rec.topics.setdefault("/faults/held", []).append((0, data))


def test_a_held_round_is_checked_against_the_last_accepted_values_and_used(rec):
    # the central held peripheral 2's round 1 of cycle 60 with its values of cycle 59;
    # those equal cycle 60's here, so the run went on as recorded
    now = reply_part(rec, 1, 60, 1)["vals"]

    def same(p: dict) -> dict:
        p["vals"] = json.loads(json.dumps(now))
        return p
    rewrite(rec, "/central/reply/2", parts_edit(59, 1, same))
    hold(rec, 1, 60, 1, now)

    def garbage(p: dict) -> dict:  # what arrived too late is not what the central used
        p["vals"] = {n: [9.0 if not isinstance(v[0], list) else [9.0] * len(v[0])]
                     for n, v in p["vals"].items()}
        p["trace"] = {n: [9.0] for n in p.get("trace", {})}
        return p
    rewrite(rec, "/central/reply/2", parts_edit(60, 1, garbage))
    assert replay.verify(rec, cycles=(60, CYCLES)) == (CYCLES - 60, None)
    # the other peripherals' replies of that round are still compared
    rewrite(rec, "/central/reply/3", parts_edit(60, 1, garbage))
    done, div = replay.verify(rec, cycles=(60, CYCLES))
    assert (done, div.cycle, div.axis) == (0, 60, 2)


def test_held_values_other_than_the_last_accepted_ones_are_a_divergence(rec):
    before = reply_part(rec, 1, 59, 1)["vals"]
    now = reply_part(rec, 1, 60, 1)["vals"]
    hold(rec, 1, 60, 1, now)  # the central claims it held these: they are not cycle 59's
    done, div = replay.verify(rec)
    name = next(iter(now))
    assert (done, div.cycle, div.block, div.axis) == (60, 60, "(hold)", 1)
    assert div.value == name
    assert div.expected == now[name][0] and div.got == before[name][0]


def test_held_values_replace_the_recomputed_ones(rec):
    # held with the last accepted values (cycle 59's, which differ from cycle 60's): the
    # central computed on with them, the recording did not, so what follows diverges
    before = reply_part(rec, 1, 59, 1)["vals"]
    hold(rec, 1, 60, 1, before)
    done, div = replay.verify(rec)
    assert div is not None and div.block != "(hold)" and div.cycle == 60 and done == 60


def test_a_held_peripherals_values_go_to_its_axes_only():
    from ctrlunit.runtime.recording.replay import _apply_held
    from ctrlunit.topology.placement import default_placement

    plan = type("P", (), {"placement": default_placement(3)})()
    last = {"x_i": [1.0, 2.0, 3.0]}
    ctx = {"x_i": [10.0, 20.0, 30.0]}
    held = {(2, 5, 0): {"x_i": [3.0]}}
    replies = {(0, 5, 0): {"vals": {"x_i": [11.0]}}, (1, 5, 0): {"vals": {"x_i": [21.0]}}}
    assert _apply_held(plan, 0, ctx, 5, held, replies, last) is None
    assert ctx == {"x_i": [10.0, 20.0, 3.0]}
    assert last == {"x_i": [11.0, 21.0, 3.0]}  # the accepted replies are the last ones
    ctx = {"x_i": [0.0, 0.0, 0.0]}
    held = {(2, 6, 0): {"x_i": [4.0]}}
    d = _apply_held(plan, 0, ctx, 6, held, {}, last)
    assert d == Divergence(6, "(hold)", 2, "x_i", 4.0, 3.0)
    assert ctx == {"x_i": [0.0, 0.0, 4.0]}
    assert last == {"x_i": [11.0, 21.0, 3.0]}  # a missing reply changes nothing
    d = _apply_held(plan, 0, {}, 7, {(0, 7, 0): {"y_i": [1.0]}}, {}, last)
    assert d == Divergence(7, "(hold)", 0, "y_i", 1.0, None)  # nothing accepted before


# -- reading the recording ---------------------------------------------------------------


def test_intervals_come_in_command_order_with_their_samples(rec):
    seq = replay.cycles_in_order(rec)
    assert [k for k, _ in seq] == list(range(CYCLES))
    samples = {m["cycle"]: m["counts"] for m in messages(rec, "/central/sample")}
    assert all(counts == samples[k] for k, counts in seq)
    rewrite(rec, "/central/sample", lambda m: None if m["cycle"] == 10 else m)
    assert [k for k, _ in replay.cycles_in_order(rec)] == [k for k in range(CYCLES) if k != 10]


def test_the_recorded_inputs_are_those_the_central_measured(rec, made):
    central = made[1].central
    got = replay.recorded_inputs(rec, replay._setup(rec))
    assert len(got) == CYCLES
    want = central.snapshot().t1_inputs
    assert len(want) > 10
    for g, w in zip(got, want, strict=False):
        assert g[0] == w[0] and list(g[2]) == list(w[2]) and list(g[3]) == list(w[3])
        assert replay._plain(g[1]) == replay._plain(w[1])


def test_plain_turns_nested_tuples_into_lists():
    P = namedtuple("P", "a b")
    assert replay._plain((1, (2, 3), [P(4, 5)])) == [1, [2, 3], [[4, 5]]]
    assert replay._plain(2.5) == 2.5


def test_nudge_changes_the_first_float_only_and_keeps_the_type():
    P = namedtuple("P", "a b")
    assert replay._nudge(1.0) != 1.0 and replay._nudge(1.0) - 1.0 < 1e-11
    assert replay._nudge(0.0) > 0.0
    assert replay._nudge(-2.0) != -2.0 and replay._nudge(-2.0) > -2.0
    assert replay._nudge("x") == "x" and replay._nudge(3) == 3
    v = replay._nudge(P(1.0, 2.0))
    assert type(v) is P and v.a != 1.0 and v.a == pytest.approx(1.0) and v.b == 2.0
    v = replay._nudge([1.0, 2.0])
    assert type(v) is list and v[0] != 1.0 and v[1] == 2.0
    v = replay._nudge((1.0, 2.0))
    assert type(v) is tuple and v[0] != 1.0 and v[1] == 2.0


def test_diff_names_the_first_differing_value_and_its_producer():
    prod = {"a_i": "blk", "b": "cen"}
    assert replay._diff({"a_i": [1, 2, 3]}, {"a_i": [1, 2, 3]}, (0, 1, 2), prod, 4) is None
    assert replay._diff({"a_i": [1, 5, 3]}, {"a_i": [1, 2, 3]}, (0, 1, 2), prod, 4) == \
        Divergence(4, "blk", 1, "a_i", 2, 5)
    assert replay._diff({}, {"a_i": [1, 2, 3]}, (0, 1, 2), prod, 4) == \
        Divergence(4, "blk", 0, "a_i", 1, None)
    assert replay._diff({"b": (1, 2)}, {"b": [1, 2]}, (0, 1, 2), prod, 4) is None
    assert replay._diff({"b": (1, 3)}, {"b": [1, 2]}, (0, 1, 2), prod, 4) == \
        Divergence(4, "cen", None, "b", [1, 2], [1, 3])
    assert replay._diff({"c": 1}, {"c": 2}, (0, 1, 2), prod, 4).block == "?"
    assert replay._diff({}, {"z_i": [1, 2, 3]}, (0, 1, 2), prod, 4).block == "?"


# -- export --------------------------------------------------------------------------------


def test_csv_holds_every_recorded_signal_row_and_the_window_asked(rec, tmp_path):
    out = tmp_path / "a" / "b"  # made with its parents
    [path] = republish.export_csv(rec, out)
    assert path == out / "signals.csv"
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["cycle", "t", "p_x", "p_y", "p_z", "ref_x", "ref_y", "ref_z", "q1",
                       "q2", "q3", "tau1", "tau2", "tau3", "tracking_error", "period",
                       "traversal"]
    states = [json.loads(d) for _, d in rec.topics["/signals/state"]]
    assert len(rows) - 1 == len(states) == CYCLES
    for row, s in zip(rows[1:], states, strict=True):
        p, r = s["p"], s["reference"]
        want = [s["cycle"], s["t"], p["x"], p["y"], p["z"], r["x"], r["y"], r["z"], *s["q"],
                *s["torque"], s["tracking_error"], s["period"], s["traversal"]]
        assert row == ["" if v is None else str(v) for v in want]
    assert len({row[3] for row in rows[1:]}) > 100  # y moves on the circle
    del rec.topics["/signals/state"]  # nothing to export: the header alone
    [path] = republish.export_csv(rec, tmp_path / "none")
    assert path.read_text().splitlines() == [",".join(rows[0])]
    rec = reader.read(rec.path)
    [path] = republish.export_csv(rec, out, cycles=(100, 150))  # into the same folder again
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["cycle"]) for r in rows] == list(range(100, 150))


# -- republish, on the test's clock --------------------------------------------------------


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0
        self.sleeps: list[float] = []

    def monotonic(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.sleeps.append(s)
        self.now += s


class FakePublisher:
    def __init__(self, session: FakeSession, key: str) -> None:
        self.session, self.key = session, key
        self.matching_status = type("M", (), {"matching": session.matched})()

    def put(self, data: bytes) -> None:
        self.session.puts.append((self.session.clock.now, self.key, data))


class FakeSession:
    def __init__(self, clock: FakeClock, matched: bool = True) -> None:
        self.clock, self.matched = clock, matched
        self.conf: Any = None
        self.puts: list[tuple[float, str, bytes]] = []

    def __enter__(self) -> FakeSession:
        return self

    def __exit__(self, *a: Any) -> None:
        pass

    def declare_publisher(self, key: str) -> FakePublisher:
        return FakePublisher(self, key)


@pytest.fixture
def fake(monkeypatch) -> tuple[FakeClock, FakeSession]:
    import zenoh

    clock = FakeClock()
    session = FakeSession(clock)
    monkeypatch.setattr(republish, "time", clock)
    def open_(conf: Any) -> FakeSession:
        session.conf = conf
        return session
    monkeypatch.setattr(zenoh, "open", open_)
    return clock, session


def small(rec: reader.Recording) -> reader.Recording:
    """Three topics, each message ``(t, data)`` with its cycle; times in ns."""
    r = reader.Recording(rec.path)
    r.topics = {
        "/plant/command": [(1_000_000_000 + k * 10_000_000, msgpack.packb({"cycle": k}))
                           for k in range(5)],
        "/central/sample": [(995_000_000 + k * 10_000_000, msgpack.packb({"cycle": k}))
                            for k in range(5)],
        "/signals/state": [(1_001_000_000 + k * 10_000_000, json.dumps({"cycle": k}).encode())
                           for k in range(5)],
    }
    return r


def test_republish_keeps_the_recorded_order_and_pace_scaled_by_rate(rec, fake):
    clock, session = fake
    r = small(rec)
    conf = object()
    n = republish.republish(r, unit="u1", rate=2.0, conf=conf)
    assert session.conf is conf
    assert n == 15 == len(session.puts)
    assert all(s > 0 for s in clock.sleeps)  # no sleep for a message already due
    t0 = session.puts[0][0]
    want = sorted((t, topic) for topic, items in r.topics.items() for t, _ in items)
    for (at, key, _), (t, topic) in zip(session.puts, want, strict=True):
        assert key == f"ctrlunit/u1{topic}"
        assert at - t0 == pytest.approx((t - want[0][0]) / 1e9 / 2.0, abs=1e-12)


def test_republish_starts_at_the_offset_and_keeps_topics_and_cycles_asked(rec, fake):
    _clock, session = fake
    r = small(rec)
    n = republish.republish(r, unit="u2", start_offset=0.003, conf=object())
    assert n == 14  # the first sample (5 ms before the first command) is left out
    session.puts.clear()
    n = republish.republish(r, unit="u2", topics=["/signals/state", "/central/sample"],
                         conf=object())
    assert n == 10 and {k for _, k, _ in session.puts} == {"ctrlunit/u2/signals/state",
                                                         "ctrlunit/u2/central/sample"}
    session.puts.clear()
    n = republish.republish(r, unit="u2", cycles=(1, 3), conf=object())
    got = sorted((k, msgpack.unpackb(d)["cycle"] if not d.startswith(b"{")
                  else json.loads(d)["cycle"]) for _, k, d in session.puts)
    states = [json.loads(d)["cycle"] for _, d in r.topics["/signals/state"]]
    # every channel that names its interval, the JSON states too (they were all dropped)
    assert got == sorted([("ctrlunit/u2/central/sample", 1), ("ctrlunit/u2/central/sample", 2),
                          ("ctrlunit/u2/plant/command", 1), ("ctrlunit/u2/plant/command", 2),
                          *(("ctrlunit/u2/signals/state", c) for c in states if 1 <= c < 3)])
    assert n == len(got) and any(k.endswith("signals/state") for k, _ in got)
    assert republish.republish(r, unit="u2", topics=["/none"], conf=object()) == 0


def test_republish_loops_until_its_time_is_up(rec, fake):
    _clock, session = fake
    r = small(rec)
    span = (r.topics["/signals/state"][-1][0] - r.topics["/central/sample"][0][0]) / 1e9
    n = republish.republish(r, unit="u3", loop=True, max_seconds=3.5 * span, conf=object())
    assert 45 <= n <= 60  # more than three passes of 15, each in the recorded order
    seq = [msgpack.unpackb(d)["cycle"] if not d.startswith(b"{") else json.loads(d)["cycle"]
           for _, _, d in session.puts]
    assert seq[:15] == seq[15:30]
    once = republish.republish(r, unit="u3", loop=False, max_seconds=3.5 * span, conf=object())
    assert once == 15


def test_republish_waits_for_subscribers_only_as_long_as_asked(rec, fake):
    clock, session = fake
    session.matched = False
    t = clock.now
    republish.republish(small(rec), unit="u4", wait_subscribers=0.25, conf=object())
    waited = session.puts[0][0] - t
    assert 0.25 <= waited <= 0.25 + 0.006
    assert all(s == 0.005 for s in clock.sleeps[:10])


def test_waiting_for_subscribers_ends_as_soon_as_all_match():
    clock = FakeClock()
    pubs = [type("P", (), {"matching_status": type("M", (), {"matching": True})()})()
            for _ in range(3)]
    orig = republish.time
    republish.time = clock
    try:
        assert republish.wait_for_subscribers(pubs, 5.0) is True
        assert clock.sleeps == []
        pubs[1].matching_status.matching = False
        assert republish.wait_for_subscribers(pubs, 0.02) is False
        assert 0.02 <= sum(clock.sleeps) <= 0.025
        clock.sleeps.clear()
        assert republish.wait_for_subscribers(pubs, -1.0) is False and clock.sleeps == []
    finally:
        republish.time = orig


def test_republish_keeps_the_recorded_order_of_messages_logged_at_the_same_time(rec, fake):
    _clock, session = fake
    r = reader.Recording(rec.path)
    r.topics = {"/z/first": [(5, msgpack.packb({"cycle": 1}))],
                "/a/second": [(5, msgpack.packb({"cycle": 2}))]}
    republish.republish(r, unit="u6", conf=object())
    assert [k for _, k, _ in session.puts] == ["ctrlunit/u6/z/first", "ctrlunit/u6/a/second"]


def test_a_start_offset_keeps_a_message_logged_exactly_at_it(rec, fake):
    _clock, session = fake
    r = reader.Recording(rec.path)
    r.topics = {"/x": [(0, msgpack.packb({"cycle": 0})),
                       (10_000_000_000, msgpack.packb({"cycle": 1}))]}
    assert republish.republish(r, unit="u7", start_offset=10.0, conf=object()) == 1
    assert [msgpack.unpackb(d)["cycle"] for _, _, d in session.puts] == [1]


def copy_with(src: Path, dst: Path, topic: str, edit: Any) -> None:
    """Copy an MCAP file message by message, ``edit(msg) -> msg`` applied to ``topic``."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as fin, open(dst, "wb") as fout:
        reader = make_reader(fin)
        writer = Writer(fout)
        writer.start()
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, msg in reader.iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding,
                                                            schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding,
                    schemas.get(channel.schema_id, 0), channel.metadata)
            data = msg.data
            if channel.topic == topic:
                data = msgpack.packb(edit(msgpack.unpackb(data)), use_single_float=False)
            writer.add_message(channels[channel.id], msg.log_time, data, msg.publish_time)
        for m in reader.iter_metadata():
            writer.add_metadata(m.name, dict(m.metadata))
        writer.finish()


def test_the_cli_says_where_a_recording_diverges_on_stderr_and_exits_1(made, tmp_path):
    """``ctrlunit replay --verify`` on a recording one reply value of which was changed
    after the run: exit 1, one ``ctrlunit: error:`` line on stderr naming the cycle, the
    block, the axis and both values (the exit-1 contract of every command); an untouched
    copy made the same way verifies."""
    from runner import ctrlunit

    src = made[0]
    same, bad = tmp_path / "same.mcap", tmp_path / "bad.mcap"
    copy_with(src, same, "/central/reply/2", lambda m: m)
    part = reply_part(reader.read(src), 1, 40, 1)
    name = next(n for n in part["vals"] if n.startswith("tauq"))

    def spoil(p: dict) -> dict:
        p["vals"][name][0] += 1e-9
        return p
    copy_with(src, bad, "/central/reply/2", parts_edit(40, 1, spoil))
    ok = ctrlunit("replay", str(same), "--verify", timeout=120)
    assert ok.returncode == 0 and "verified" in ok.stdout, ok.stderr
    res = ctrlunit("replay", str(bad), "--verify", timeout=120)
    assert res.returncode == 1
    err = res.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("ctrlunit: error: "), res.stderr
    assert "after 40 identical intervals" in err[0]
    assert f"cycle 40, block dyn_axis (axis 1), value {name}" in err[0]



def test_only_stride_orders_with_integer_fields_change_the_replayed_rate():
    """``/plant/control`` also carries the other orders (``start``, ``stop``, ...); only a
    ``stride`` order with an integer start and stride is a change of the control rate."""
    import msgpack
    from ctrlunit.runtime.recording.reader import Recording

    orders = [{"stage": "start", "start": 3}, {"stage": "stride", "stride": 2, "start": 40},
              {"stage": "stride", "stride": "1", "start": 90},
              {"stage": "stride", "stride": 1, "start": 90.0},
              {"stage": "stride", "stride": 1, "start": 120}, {"stage": "stop", "start": 7},
              {"stage": "probe", "stride": 3, "start": 5}]  # fields alike, another order
    rec = Recording("orders.mcap", topics={
        "/plant/control": [(t, msgpack.packb(m)) for t, m in enumerate(orders)]})
    assert replay.stride_changes(rec) == [(40, 2), (120, 1)]


@pytest.mark.parametrize(("topic", "edit"), [
    ("/central/reply/2", lambda m: m | {"parts": "x"} if m.get("cycle") == 30 else m),
    ("/central/reply/2", lambda m: m | {"parts": [{"cycle": "30", "stage": 1}]}
     if m.get("cycle") == 30 else m),
    ("/trace/central", lambda m: {k: v for k, v in m.items() if k != "vals"}),
    ("/peripheral/request", lambda m: m | {"parts": [1, 2]} if m.get("cycle") == 30 else m)])
def test_a_recording_edited_to_messages_of_another_shape_fails_verify_in_one_line(
        made, tmp_path, topic, edit):
    """An attacker's review (2026-11-29): a reply's ``parts`` made a string, or the
    central's trace without ``vals``, rewritten with fresh CRCs, made ``replay --verify``
    end in a traceback. Such a message is now one the reader skips, as the live roles
    would refuse it: verify names what is missing, in one line, exit 1."""
    from runner import ctrlunit

    bad = tmp_path / "shape.mcap"
    copy_with(made[0], bad, topic, edit)
    res = ctrlunit("replay", str(bad), "--verify", timeout=120)
    err = res.stderr.strip().splitlines()
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr[-800:]
    assert len(err) == 1 and err[0].startswith("ctrlunit: error: replay --verify"), err
