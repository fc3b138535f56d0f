"""The experiments' shared helpers: the one goal check, seed ranges and the spin cases' overrides."""

import pytest

from experiments.common import case_overrides, goal_check, seed_range
from lightcurve_gp.config.load import ConfigError


def test_goal_check_names_each_criterion_and_needs_every_axis():
    check = goal_check({"ratio": [1.1, 1.3, 0.9], "fraction": 0.9, "nees": 2.0, "median": [1.04, 0.951]},
                       {"ratio": ("<=", 1.25), "fraction": (">=", 0.9), "nees": ("in", (0.22, 9.35)),
                        "median": ("within", (1.0, 0.05))})
    assert check.flags == {"ratio_met": False, "fraction_met": True, "nees_met": True, "median_met": True}
    assert not check.met
    assert check.lines == ["ratio 1.1, 1.3, 0.9 <= 1.25: NOT met", "fraction 0.9 >= 0.9: met",
                           "nees 2 in [0.22, 9.35]: met", "median 1.04, 0.951 within 0.05 of 1: met"]
    assert goal_check({"nees": 9.36}, {"nees": ("in", (0.22, 9.35))}).flags == {"nees_met": False}
    assert goal_check({"x": 1.0}, {"x": ("<=", 1.0)}).met


def test_seed_range_reads_first_and_end():
    assert seed_range("2000:2300") == range(2000, 2300)
    with pytest.raises(ConfigError, match="seed block '5:5': END must exceed FIRST"):
        seed_range("5:5")
    with pytest.raises(ConfigError, match="expected FIRST:END"):
        seed_range("10")


def test_spin_case_overrides_score_the_last_200_s_and_start_one_sigma_off():
    assert case_overrides(600.0, None) == ["scenario.duration_s=600", "evaluation.rmse_window_s=[400, 600]"]
    assert case_overrides(1800.0, 0.03)[2:] == ["filter.estimate_omega=true", "filter.p0_omega_deg_s=0.03",
                                                "scenario.initial_omega_error_deg_s=[0.03, -0.03, 0.03]"]
