"""The plant's admission-trial order is checked field by field before it ticks."""

from __future__ import annotations

import pytest
from ctrlunit.runtime.roles.plant_orders import TRIAL_MAX_S, trial_order
from ctrlunit.runtime.transport.node import Event


class FakeNode:
    def __init__(self, msg: dict) -> None:
        self.msg = msg
        self.rejected: list[str] = []

    def decode(self, _data: bytes) -> dict:
        return self.msg

    def reject(self, reason: str) -> None:
        self.rejected.append(reason)


def order(**fields) -> tuple[FakeNode, object]:
    node = FakeNode({"stage": "probe", "period": 1e-3, "ticks": 300, "base": 1 << 41}
                    | fields)
    return node, trial_order(node, Event("control", 0, b"", 0))


def test_a_well_formed_trial_order_is_taken():
    node, got = order()
    assert got == (1e-3, 300, 1 << 41) and node.rejected == []


@pytest.mark.parametrize("fields", [
    {"period": 5.0}, {"period": 1}, {"period": float("nan")}, {"ticks": 0},
    {"ticks": True}, {"ticks": 3.0}, {"base": -1}, {"base": "x"},
    {"period": 1.0, "ticks": int(TRIAL_MAX_S) + 1},  # longer than a trial may last
])
def test_a_malformed_or_endless_trial_order_is_counted_and_dropped(fields):
    node, got = order(**fields)
    assert got is None and node.rejected == ["bad_value"]


def test_other_orders_are_not_trials():
    node, got = order(stage="start")
    assert got is None and node.rejected == []
    assert trial_order(node, Event("command", 0, b"", 0)) is None
