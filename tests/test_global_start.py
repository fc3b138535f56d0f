"""The global-start bank: its attitudes cover SO(3); the bank's ranking, with and without pruning."""

from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.config.load import load_config
from lightcurve_gp.filters.bank import bank_attitudes, continue_filters, run_bank
from lightcurve_gp.filters.selection import innovation_log_likelihood
from lightcurve_gp.filters.setup import run_filter

from helpers import ToyModel, scenario


def nearest_angle_deg(q: torch.Tensor, bank: torch.Tensor) -> torch.Tensor:
    """Rotation angle from each attitude ``q (n, 4)`` to its nearest bank member (sign invariant)."""
    return torch.rad2deg(2 * torch.acos((q @ bank.T).abs().amax(1).clamp(max=1.0)))


def test_a_bank_of_1024_leaves_no_attitude_far_from_a_member():
    bank = bank_attitudes(1024)
    angles = nearest_angle_deg(random_attitudes(2000, seed=11, dtype=torch.float64), bank)
    # a uniform set of N points covers balls of angle r with (r - sin r)/pi = 1/N: r = 15.4 deg for N = 1024
    assert float(angles.quantile(0.95)) < 22.0
    assert float(angles.median()) < 15.4


def test_members_are_distinct_unit_quaternions():
    bank = bank_attitudes(1024)
    assert torch.allclose(bank.norm(dim=-1), torch.ones(1024, dtype=torch.float64), atol=1e-12)
    gram = (bank @ bank.T).abs() - torch.eye(1024, dtype=torch.float64)
    assert float(gram.max()) < 0.9999  # no two members within 1.6 deg of each other


# ---------------------------------------------------------------------------------------------- the bank and pruning

ROBUST = Path(__file__).resolve().parents[1] / "configs" / "boxwing_robust.yaml"


@pytest.fixture(scope="module")
def toy_light_curve():
    """The robust config (offset state) on the toy model: one noisy light curve of 40 steps, a bank of 32."""
    cfg = load_config(ROBUST)
    q_true, y, _, increments = scenario(B=1, T=40, seed=4, noise=0.05)
    return cfg, ToyModel(), y[0], increments[0], bank_attitudes(32)


def test_continuing_filters_reproduces_the_uninterrupted_run(toy_light_curve):
    cfg, model, y, increments, q0 = toy_light_curve
    R = torch.linspace(0.2, 0.6, y.shape[0], dtype=torch.float64)
    whole = run_filter(cfg, model, q_est0=q0, observations=y.expand(32, -1), increments=increments,
                       R=R.expand(32, -1))
    first = run_filter(cfg, model, q_est0=q0, observations=y[:16].expand(32, -1), increments=increments[:15],
                       R=R[:16].expand(32, -1))
    members = torch.tensor([3, 0, 17])
    rest = continue_filters(cfg, model, first, members, observations=y[15:].expand(3, -1),
                            increments=increments[15:], R=R[15:].expand(3, -1))
    torch.testing.assert_close(rest.q_est, whole.q_est[members, 15:], rtol=0, atol=1e-12)
    torch.testing.assert_close(rest.offset, whole.offset[members, 15:], rtol=0, atol=1e-12)
    torch.testing.assert_close(rest.P_full, whole.P_full[members, 15:], rtol=0, atol=1e-12)
    torch.testing.assert_close(rest.innovation[:, 1:], whole.innovation[members, 16:], rtol=0, atol=1e-12)


def test_without_pruning_the_bank_is_the_unpruned_batch(toy_light_curve):
    """prune_after=None and prune_after ≥ T both run every member over the whole curve, bit for bit."""
    cfg, model, y, increments, q0 = toy_light_curve
    direct = run_filter(cfg, model, q_est0=q0, observations=y.expand(32, -1), increments=increments,
                        variance="none")
    ll = innovation_log_likelihood(direct)
    for prune_after in (None, 40, 100):
        bank = run_bank(cfg, model, observations=y, increments=increments, q0=q0, keep=3, prune_after=prune_after,
                        prune_keep=4)
        assert torch.equal(bank.log_likelihood, ll) and torch.equal(bank.bank_history.q_est, direct.q_est)
        assert torch.equal(bank.order, torch.argsort(ll, descending=True))
        assert torch.equal(bank.weights, torch.softmax(ll, 0)) and bank.survivors is None


def test_pruning_keeping_everyone_gives_the_unpruned_ranking(toy_light_curve):
    cfg, model, y, increments, q0 = toy_light_curve
    full = run_bank(cfg, model, observations=y, increments=increments, q0=q0, keep=3)
    everyone = run_bank(cfg, model, observations=y, increments=increments, q0=q0, keep=3, prune_after=10,
                        prune_keep=32)
    torch.testing.assert_close(everyone.log_likelihood, full.log_likelihood, rtol=0, atol=1e-9)
    assert torch.equal(everyone.order, full.order)
    torch.testing.assert_close(everyone.kept.q_est, full.kept.q_est, rtol=0, atol=0)


def test_pruning_ranks_the_survivors_first_and_weights_only_them(toy_light_curve):
    cfg, model, y, increments, q0 = toy_light_curve
    bank = run_bank(cfg, model, observations=y, increments=increments, q0=q0, keep=3, prune_after=10, prune_keep=8)
    first = run_filter(cfg, model, q_est0=q0, observations=y[:11].expand(32, -1), increments=increments[:10],
                       variance="none")
    ll_first = innovation_log_likelihood(first)
    assert set(bank.survivors.tolist()) == set(torch.argsort(ll_first, descending=True)[:8].tolist())
    assert set(bank.order[:8].tolist()) == set(bank.survivors.tolist())
    assert bool((bank.log_likelihood[bank.order[:8]].diff() <= 0).all())
    pruned = bank.order[8:]
    assert torch.equal(bank.log_likelihood[pruned], ll_first[pruned])
    assert float(bank.weights[pruned].abs().max()) == 0.0
    torch.testing.assert_close(bank.weights.sum(), torch.ones((), dtype=torch.float64))
    assert bank.bank_history.q_est.shape == (32, 11, 4)
    with pytest.raises(ValueError, match="prune_keep"):
        run_bank(cfg, model, observations=y, increments=increments, q0=q0, keep=3, prune_after=10, prune_keep=2)


def test_pruning_refuses_adaptive_noise_before_running(toy_light_curve):
    _, model, y, increments, q0 = toy_light_curve
    cfg = load_config(ROBUST, ["filter.adaptive_noise=innovation"])
    calls = model.calls
    with pytest.raises(ValueError, match="^pruning: adaptive measurement noise"):
        run_bank(cfg, model, observations=y, increments=increments, q0=q0, keep=3, prune_after=10, prune_keep=8)
    assert model.calls == calls
