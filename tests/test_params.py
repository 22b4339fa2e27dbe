"""Delta parameters: defaults, TOML loading, validation messages."""

from __future__ import annotations

import math
from importlib import resources

import pytest
from ctrlunit.kernels.params import DELTA_IA, ParameterError, load_params, params_from_mapping


def test_defaults_are_the_delta_ia_of_errata():
    p = DELTA_IA
    assert (p.l_a, p.l_b, p.r_a, p.r_b) == (0.260, 0.480, 0.194, 0.030)
    assert (p.m_a, p.m_b, p.m_c, p.j_a, p.j_b) == (0.200, 0.088, 0.092, 0.0131, 0.0017)
    assert p.tau_max == 20.0 and p.encoder_counts == 200_000
    assert math.isclose(math.degrees(p.q_min), -125.0) and math.isclose(math.degrees(p.q_max), 15.0)


def test_shipped_toml_equals_defaults():
    path = resources.files("ctrlunit.kernels") / "delta_ia.toml"
    assert load_params(str(path)) == DELTA_IA


def test_out_of_range_field_is_named_with_its_range(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_text("[delta]\nl_a = -1.0\n")
    with pytest.raises(ParameterError, match=r"l_a .*outside the allowed range \[0.01, 5.0\] m"):
        load_params(f)


def test_unknown_field_is_named():
    with pytest.raises(ParameterError, match="unknown field.*l_z"):
        params_from_mapping({"l_z": 1.0})


def test_wrong_type_is_named():
    with pytest.raises(ParameterError, match="m_c .*must be a number"):
        params_from_mapping({"m_c": "heavy"})


def test_inverted_joint_bounds_are_refused():
    with pytest.raises(ParameterError, match="q_min"):
        params_from_mapping({"q_min_deg": 20.0, "q_max_deg": 10.0})


def test_unparsable_file_names_the_file(tmp_path):
    f = tmp_path / "broken.toml"
    f.write_text("l_a = = 3")
    with pytest.raises(ParameterError, match="broken.toml"):
        load_params(f)
