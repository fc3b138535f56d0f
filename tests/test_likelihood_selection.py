"""Selection among filter runs by innovation likelihood: the row picking, the criterion against an independent
log-density, and the surface-state filter under two λ rules."""

import math

import torch

from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation.registry import SELECTED_LAM_RULES, run_surface_filter_selected
from lightcurve_gp.filters.selection import (
    innovation_log_likelihood,
    innovation_log_terms,
    select_by_likelihood,
    select_rows,
)
from lightcurve_gp.filters.setup import run_surface_filter
from lightcurve_gp.filters.usque import UsqueParams, run_usque
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario

from helpers import ToyModel, scenario

DT = torch.float64


def toy_runs(R_values):
    """The same toy light curves filtered with several assumed noise variances."""
    q_true, y, q_est0, inc = scenario(B=5, T=80, seed=3, noise=0.05)
    return [run_usque(model=ToyModel(), q_est0=q_est0, P0=(math.radians(8.0) ** 2) * torch.eye(3, dtype=DT),
                      observations=y, m_past0=y[:, 0], increments=inc, params=UsqueParams(R=R, Q=1e-8))
            for R in R_values]


def test_rows_come_from_the_chosen_runs():
    runs = toy_runs([0.05 ** 2, 0.5])
    index = torch.tensor([1, 0, 0, 1, 1])
    picked = select_rows(runs, index)
    for b, k in enumerate(index.tolist()):
        assert torch.equal(picked.q_est[b], runs[k].q_est[b])
        assert torch.equal(picked.P_full[b], runs[k].P_full[b])
        torch.testing.assert_close(picked.innovation[b], runs[k].innovation[b], rtol=0, atol=0, equal_nan=True)
        assert picked.fallbacks[b] == runs[k].fallbacks[b]
    assert picked.offset is None and picked.theta is None


def test_the_true_noise_wins_and_the_criterion_is_the_gaussian_log_density():
    runs = toy_runs([0.05 ** 2, 0.5])  # the data's noise std is 0.05 mag
    kept, index = select_by_likelihood(runs)
    assert torch.equal(index, torch.zeros(5, dtype=index.dtype))
    assert torch.equal(kept.q_est, runs[0].q_est)
    h = runs[0]
    used = h.updated[:, 1:]
    normal = torch.distributions.Normal(torch.zeros_like(h.y_var[:, 1:]), h.y_var[:, 1:].sqrt())
    independent = torch.where(used, normal.log_prob(h.innovation[:, 1:]), 0.0).sum(-1)
    assert bool(used.all())
    assert torch.allclose(innovation_log_likelihood(h), independent, rtol=0, atol=1e-9)
    terms = innovation_log_terms(h)
    assert torch.equal(terms[:, 0], torch.zeros(5, dtype=DT))  # step 0 has no innovation
    assert torch.allclose(terms[:, 1:], normal.log_prob(h.innovation[:, 1:]), rtol=0, atol=1e-12)


def test_surface_filter_under_two_rules_keeps_one_of_them_per_seed():
    short = ["scenario.duration_s=30", "evaluation.rmse_window_s=[10, 30]"]
    cfg = load_config("configs/boxwing_robust.yaml", short)
    julier = load_config("configs/boxwing_robust.yaml", short + ["filter.lam_rule=julier"])
    scene = Scene.from_config(cfg)
    sc = simulate_scenario(cfg, seeds=[0, 1, 2])
    assert SELECTED_LAM_RULES == ("given", "julier")
    kept, index = run_surface_filter_selected(cfg, scene, observations=sc.observations, q_est0=sc.q_est0,
                                              increments=sc.increments, sigma0=sc.sigma0)
    alone = [run_surface_filter(c, scene, observations=sc.observations, q_est0=sc.q_est0, increments=sc.increments,
                                sigma0=sc.sigma0) for c in (cfg, julier)]
    ll = torch.stack([innovation_log_likelihood(h) for h in alone])
    assert torch.equal(index, ll.argmax(0))
    for b, k in enumerate(index.tolist()):
        assert torch.equal(kept.q_est[b], alone[k].q_est[b])
