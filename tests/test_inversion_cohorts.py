"""The continuation's cohorts: which arcs each rate is screened on, each cohort's quota, and a pruning that keeps
the best rows of every cohort so rows entering later never crowd out the rows carried."""

import math

import pytest
import torch

from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.inference.inversion import (
    TIE_CAP,
    InversionSettings,
    cohort_quotas,
    prune_rows,
    screened_at,
    tied_keep,
)
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup

F64 = torch.float64
IDENTITY = AmbiguityGroup(body=torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=F64),
                          inertial=torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=F64), labels=("identity",),
                          rate_known=False)


def test_each_rate_is_screened_on_its_entry_arc_and_the_arcs_before_it_asked_for():
    entry = torch.tensor([0, 1, 2, 3])
    got = screened_at(entry, stages=5, early_arcs=1)
    assert got.tolist() == [[True, True, False, False],
                            [False, True, True, False],
                            [False, False, True, True],
                            [False, False, False, True],
                            [False, False, False, False]]
    assert screened_at(entry, stages=5, early_arcs=0).long().argmax(0).tolist() == [0, 1, 2, 3]
    assert screened_at(entry, stages=5, early_arcs=0).sum(0).tolist() == [1, 1, 1, 1]


def test_the_largest_cohort_keeps_keep_and_the_others_their_share_rounded_up():
    assert cohort_quotas(300, [2000, 700, 0, 350]) == [300, math.ceil(300 * 700 / 2000), 0, math.ceil(300 * 350 / 2000)]
    assert cohort_quotas(50, [10, 40]) == [13, 50]
    assert cohort_quotas(50, []) == []


def _rows(n: int, seed: int):
    q = random_attitudes(n, seed=seed, dtype=F64)
    omega = torch.deg2rad(torch.linspace(0.5, 4.0, n, dtype=F64))[:, None] * torch.tensor([[0.0, 0.0, 1.0]], dtype=F64)
    return q, omega


def test_the_pruning_keeps_the_best_of_each_cohort_however_well_the_newcomers_fit():
    q, omega = _rows(30, seed=3)
    # cohort 0 (carried, 20 rows) fits worse than every row of cohort 1 (entering, 10 rows)
    cohort = torch.tensor([0] * 20 + [1] * 10)
    cost = torch.cat([100.0 + torch.arange(20, dtype=F64).flip(0), torch.arange(10, dtype=F64)])
    shared = prune_rows(IDENTITY, q, omega, cost, keep=8)
    assert sorted(shared.tolist()) == list(range(20, 28))  # all rows competing: the carried ones are all gone
    rows = prune_rows(IDENTITY, q, omega, cost, keep=8, cohort=cohort, quotas=cohort_quotas(8, [20, 10]))
    assert sorted(rows.tolist()) == list(range(12, 20)) + list(range(20, 24))  # 8 best carried, 4 best entering


def test_a_cohort_keeps_one_row_per_solution_modulo_the_group():
    q, omega = _rows(6, seed=5)
    q = torch.cat([q, q[:1]])  # row 6 is row 0 again, a little worse
    omega = torch.cat([omega, omega[:1]])
    cost = torch.tensor([1.0, 5.0, 6.0, 7.0, 8.0, 9.0, 1.5], dtype=F64)
    rows = prune_rows(IDENTITY, q, omega, cost, keep=3, cohort=torch.zeros(7, dtype=torch.long), quotas=[3])
    assert rows.tolist() == [0, 1, 2]


def test_rows_the_arc_cannot_tell_from_the_best_are_kept_beyond_the_quota():
    spaced = torch.arange(20, dtype=F64)  # one nat apart: 0..10 lie within 10 nats of the best
    assert tied_keep(spaced, keep=3, tie_nats=10.0) == 11
    assert tied_keep(spaced, keep=3, tie_nats=None) == 3
    assert tied_keep(30.0 * spaced, keep=3, tie_nats=10.0) == 3  # an arc that separates them: the quota
    assert tied_keep(spaced, keep=50, tie_nats=10.0) == 20  # never more than the rows
    assert tied_keep(spaced, keep=1, tie_nats=10.0) == 8  # at most TIE_CAP (8) times the quota
    assert tied_keep(spaced, keep=2, tie_nats=10.0, tie_cap=1.5) == 3
    assert tied_keep(spaced.new_zeros(0), keep=3, tie_nats=10.0) == 0
    q, omega = _rows(30, seed=7)
    cohort = torch.tensor([0] * 20 + [1] * 10)
    cost = torch.cat([torch.arange(20, dtype=F64), 100.0 * torch.arange(10, dtype=F64)])
    rows = prune_rows(IDENTITY, q, omega, cost, keep=4, cohort=cohort, quotas=[4, 2], tie_nats=10.0)
    assert sorted(rows.tolist()) == list(range(11)) + [20, 21]  # cohort 0's ties kept, cohort 1 its quota
    assert sorted(prune_rows(IDENTITY, q, omega, cost, keep=4, cohort=cohort, quotas=[4, 2]).tolist()) == [
        0, 1, 2, 3, 20, 21]


def test_the_defaults_screen_each_rate_early_once_and_prune_by_cohort():
    assert InversionSettings().early_arcs == 1 and InversionSettings().cohort_quotas
    assert InversionSettings().tie_nats == 10.0 and InversionSettings().tie_cap == TIE_CAP == 8.0
    with pytest.raises(ValueError, match=r"^early_arcs: -1 must be >= 0$"):
        InversionSettings(early_arcs=-1)


def test_rows_kept_are_a_share_of_the_starts():
    # the counts every 4000-start table used, and the same shares of the default 10^4
    assert InversionSettings(starts=4000).stage_keep() == (1000, 300, 100, 50)
    assert InversionSettings().stage_keep() == (2500, 750, 250, 125)
    assert InversionSettings(starts=10, keep_share=(0.01, 0.5, 0.25, 0.1)).stage_keep() == (1, 5, 2, 1)
    assert InversionSettings(keep=(7, 6, 5, 4)).stage_keep() == (7, 6, 5, 4)  # counts replace the shares
    with pytest.raises(ValueError, match=r"^keep: 2 values for 5 stages; need one per stage after the first$"):
        InversionSettings(keep=(7, 6))
    with pytest.raises(ValueError, match=r"^keep: \(7, 0, 5, 4\) must be >= 1 row per stage$"):
        InversionSettings(keep=(7, 0, 5, 4))
