"""The inversion experiment's tables: the calibration bins' chance spread, the NEES of the right top families and
the per-seed CSV, on hand-made rows."""

import csv
import io
import math

from experiments.inversion import (
    calibration,
    nees_right,
    on_reported_ridge,
    per_seed_csv,
    reported_within_ratio,
    without_p_right,
)


def test_calibration_states_the_spread_an_honest_probability_allows():
    rows = [{"top1_p_right": 0.9, "top1": k < 8} for k in range(10)]
    text = calibration(rows)
    spread = 2.0 * math.sqrt(0.9 * 0.1 / 10)
    assert text == f"[0.8, 0.95]: w̄ 0.90 vs 0.80 (n 10, ±{spread:.2f})"


def test_nees_of_the_right_top_families_only():
    rows = [{"top1": True, "top1_nees": v} for v in (2.0, 4.0, 6.0, 20.0)] + [{"top1": False, "top1_nees": 99.0}]
    assert nees_right(rows) == "5.0 [3.5, 9.5], > 16.8: 1/4"
    assert nees_right([{"top1": True}]) == "—"


def test_per_seed_csv_keeps_nested_values_in_one_column():
    rows = [{"seed": 1, "probe_rows": {"local": 21, "image": 0}, "stage_seconds": {"search": 1.0}}]
    table = list(csv.reader(io.StringIO(per_seed_csv(rows))))
    assert table == [["seed", "probe_rows"], ["1", "{'local': 21, 'image': 0}"]]


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
