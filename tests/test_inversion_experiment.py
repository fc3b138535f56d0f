"""The inversion experiment's tables: the calibration bins' chance spread, the NEES of the right top families and
the per-seed CSV, on hand-made rows; a kept row brought to today's ``p_right`` rule."""

import csv
import io
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.stats import binom

from experiments.inversion import (
    P_RIGHT_RULE,
    calibration,
    count_p_value,
    fast_right,
    main,
    mixed,
    nees_right,
    on_reported_ridge,
    per_seed_csv,
    read_per_seed_csv,
    reported_within_ratio,
    seed_problem,
    without_p_right,
)
from lightcurve_gp.attitude.rotations import quat_mul, rotvec_to_quat
from lightcurve_gp.config.load import load_config

ROOT = Path(__file__).resolve().parents[1]


def test_calibration_states_the_spread_an_honest_probability_allows():
    rows = [{"top1_p_right": 0.9, "top1": k < 8} for k in range(10)]
    text = calibration(rows)
    spread = 2.0 * math.sqrt(0.9 * 0.1 / 10)
    chance = 1.0 - binom.pmf(9, 10, 0.9)  # every count but the mean, 9, is at least 1 from it
    assert text == f"[0.8, 0.95]: w̄ 0.90 vs 0.80 (n 10, ±{spread:.2f}, p {chance:.2g})"


def test_the_count_p_value_is_the_binomials_for_equal_probabilities_and_exact_for_unequal_ones():
    assert count_p_value(np.full(20, 0.3), 10) == pytest.approx(
        sum(binom.pmf(j, 20, 0.3) for j in range(21) if abs(j - 6) >= 4), rel=1e-12)
    # two seeds at 0.5 and 1.0: counts 1 and 2 each 1/2; the mean is 1.5, both are 0.5 from it
    assert count_p_value(np.array([0.5, 1.0]), 2) == pytest.approx(1.0)
    assert count_p_value(np.array([0.1, 0.1, 0.1]), 3) == pytest.approx(0.001)


def test_fast_right_counts_apart_the_seeds_whose_truths_basin_is_right_and_the_best_found():
    rows = [{"rate_deg_s": 2.0, "top1": True, "basin_right": True, "best_minus_basin": 0.0},
            {"rate_deg_s": 2.0, "top1": False, "basin_right": False, "best_minus_basin": 0.0},   # the basin is off
            {"rate_deg_s": 2.0, "top1": False, "basin_right": True, "best_minus_basin": -0.5},   # a better basin
            {"rate_deg_s": 2.0, "top1": False, "basin_right": True, "best_minus_basin": 3.0},    # a search miss
            {"rate_deg_s": 0.5, "top1": False, "basin_right": True, "best_minus_basin": 0.0}]    # slow: not counted
    assert fast_right(rows) == "1/4 (1/2)"


def test_nees_of_the_right_top_families_only():
    rows = [{"top1": True, "top1_nees": v} for v in (2.0, 4.0, 6.0, 20.0)] + [{"top1": False, "top1_nees": 99.0}]
    assert nees_right(rows) == "5.0 [3.5, 9.5], > 16.8: 1/4"
    assert nees_right([{"top1": True}]) == "—"


def test_per_seed_csv_keeps_nested_values_in_one_column():
    rows = [{"seed": 1, "probe_rows": {"local": 21, "image": 0}, "stage_seconds": {"search": 1.0}}]
    table = list(csv.reader(io.StringIO(per_seed_csv(rows))))
    assert table == [["seed", "probe_rows"], ["1", "{'local': 21, 'image': 0}"]]


def test_the_per_seed_csv_reads_back_as_its_rows():
    row = {"seed": 1, "top1": True, "verdict": "unique", "rate_profile": None, "seconds": 2.5,
           "probe_rows": {"local": 21}, "families_state": {"q0": [[0.1, -0.2, 0.3, 0.9]], "weight": [1.0]}}
    assert read_per_seed_csv(per_seed_csv([{**row, "stage_seconds": {"search": 1.0}}])) == [row]


def test_kept_rows_of_another_config_are_refused_naming_the_file_and_line(tmp_path):
    kept = tmp_path / "per_seed.csv"
    kept.write_text(per_seed_csv([{"seed": 1, "config": "boxwing"}, {"seed": 2, "config": "geo_pass"}]))
    with pytest.raises(SystemExit) as exc:
        main(["--kept", str(kept), "--out", str(tmp_path / "out")])
    assert str(exc.value) == f"--kept {kept}, line 3: a row of config 'geo_pass', not --config's 'boxwing'"
    assert not (tmp_path / "out").exists()


def test_a_kept_no_fit_row_gets_the_answers_rule():
    row = {"verdict": "no_fit", "top1_p_right": 0.98, "p_right_sum": 0.99, "seed": 7,
           "families_state": {"p_right": [0.98, 0.01], "weight": [0.99, 0.01]}}
    new = without_p_right(row)
    assert new["top1_p_right"] == 0.0 and new["p_right_sum"] == 0.0
    assert new["families_state"] == {"p_right": [0.0, 0.0], "weight": [0.99, 0.01]} and new["seed"] == 7
    assert row["top1_p_right"] == 0.98  # the kept row itself is not changed in place


def test_the_truths_family_reported_counts_a_slow_tumblers_reported_ridge():
    base = {"basin_cost": 100.0, "best_cost": 99.0, "rate_lo_deg_s": 0.1, "rate_hi_deg_s": 0.3}
    rows = [{**base, "basin_rank": 1, "rate_deg_s": 2.0},
            {**base, "basin_rank": 0, "rate_deg_s": 0.2},    # slow, its rate inside the interval: on the ridge
            {**base, "basin_rank": 0, "rate_deg_s": 0.5},    # slow, outside the interval
            {**base, "basin_rank": 0, "rate_deg_s": 0.2, "basin_cost": 120.0}]  # basin beyond the ratio: not counted
    assert on_reported_ridge(rows[1]) and not on_reported_ridge(rows[2])
    assert not on_reported_ridge({**rows[1], "rate_deg_s": 0.7, "rate_hi_deg_s": 1.0})  # more than one turn
    assert reported_within_ratio(rows) == "1/3 (33 %; with the ridges 67 %)"


def test_a_kept_row_gets_the_mixture_rule_two_near_neighbours_share_their_tolerance():
    cfg = load_config(ROOT / "configs" / "boxwing.yaml",
                      ["scenario.duration_s=120", "evaluation.rmse_window_s=[0, 120]"])
    _, _, _, (q0, w0, rho) = seed_problem(cfg, 5, 0.05, "uniform")
    near = quat_mul(rotvec_to_quat(torch.tensor([0.0, 0.0, math.radians(3.0)], dtype=torch.float64)), q0)
    row = {"seed": 5, "sigma": 0.05, "rate_law": "uniform", "verdict": "ambiguous", "ridge": False,
           "rate_profile": None, "top1_p_right": 0.6, "p_right_sum": 1.0,
           "families_state": {"q0": [q0.tolist(), near.tolist()], "omega0_deg_s": [torch.rad2deg(w0).tolist()] * 2,
                              "log_rho": [math.log(rho)] * 2, "weight": [0.6, 0.4], "mass": [1.0, 1.0],
                              "p_right": [0.6, 0.4]}}
    new = mixed(cfg, row)
    # 3° apart, 1-4° wide (0.05 mag, 120 s, 3.2 °/s): most of each family's draws are right about the other's mode,
    # which adds most of the other's weight to the kept weight · mass
    p_right = new["families_state"]["p_right"]
    assert 0.6 + 0.3 < p_right[0] <= 1.0 and 0.4 + 0.5 < p_right[1] <= 1.0 and new["top1_p_right"] == p_right[0]
    assert new["verdict"] == "unique" and new["p_right_rule"] == P_RIGHT_RULE and row["verdict"] == "ambiguous"
    capped = mixed(cfg, {**row, "ridge": True, "rate_profile": {"share": 0.5, "resolved": False}})
    assert capped["top1_p_right"] == pytest.approx(0.3) and capped["verdict"] == "ambiguous"
    refused = mixed(cfg, {**row, "verdict": "no_fit"})
    assert refused["families_state"]["p_right"] == [0.0, 0.0] and refused["verdict"] == "no_fit"
