"""The thesis's contact runs: identification holds 20 N; the hybrid part
alone misses the square wave (Fig 6.10)."""

import pytest

from drake_contact.runner import run
from drake_contact.scenario import load_scenario

IDENTIFY = [
    ("identify_styrofoam", []),
    ("identify_rubber", []),
    # A stiffness between the two, with the rubber gains.
    ("identify_rubber", ["environment.stiffness=20000"]),
]


@pytest.mark.parametrize("name,overrides", IDENTIFY)
def test_identification_runs_hold_20_n_with_small_position_errors(tmp_path, name, overrides):
    scenario = load_scenario(name, overrides)
    m = run(scenario, tmp_path, figures=False).metrics
    approach = scenario.controller.hybrid.approach
    assert approach.hold_time_s < m["contact_time_s"] < approach.hold_time_s + 5.0
    assert m["mode_switches"] == 1
    assert abs(m["force_mean_n"] - 20.0) < 0.5
    assert m["y_max_abs_error_m"] < 1e-3
    assert m["phi_max_abs_error_rad"] < 5e-3
    assert m["impact_peak_force_n"] <= 2 * 20.0


@pytest.mark.parametrize("name", ["hybrid_p_only_styrofoam", "hybrid_p_only_rubber"])
def test_hybrid_part_alone_misses_the_square_wave(tmp_path, name):
    scenario = load_scenario(name, duration=20.0)
    result = run(scenario, tmp_path)
    m = result.metrics
    assert m["force_mean_abs_error_n"] > 2.0
    assert m["impact_peak_force_n"] <= 2 * 20.0
    for figure in ("fig4_2_switch.png", "fig6_10_force_tracking.png"):
        assert (tmp_path / figure).is_file()
