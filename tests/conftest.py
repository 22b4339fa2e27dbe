"""Shared fixtures and strategies."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ctrlunit.kernels.forward import fk_closed_form
from ctrlunit.kernels.params import DELTA_IA, DeltaParams
from ctrlunit.kernels.workspace import check_point
from hypothesis import strategies as st


@pytest.fixture
def params() -> DeltaParams:
    return DELTA_IA


def usable_point_from_q(q: tuple[float, float, float]) -> np.ndarray | None:
    """The platform position for joint angles q if it is in the usable workspace."""
    try:
        p = fk_closed_form(DELTA_IA, np.array(q))
    except ValueError:
        return None
    return p if check_point(DELTA_IA, p).ok else None


joint_angles = st.tuples(
    *[st.floats(DELTA_IA.q_min, DELTA_IA.q_max, allow_nan=False) for _ in range(3)]
)
velocities = st.tuples(*[st.floats(-5.0, 5.0, allow_nan=False) for _ in range(3)])

INCREMENT = 2.0 * math.pi / 200_000
