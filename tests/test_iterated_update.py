"""The iterated measurement update (iterated posterior linearisation): one iteration is the ordinary update, its
statistical linear regression over the prior reproduces the ordinary gain, a linear-Gaussian measurement gets the
exact posterior at every iteration, and a run with it stays finite and differs from the ordinary one."""

import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.rotations import euler321_to_quat, quat_mul, quat_normalize, quat_to_grp
from lightcurve_gp.config.load import ConfigError, load_config
from lightcurve_gp.filters.iterated import iterated_update, relinearised_gain
from lightcurve_gp.filters.setup import run_filter
from lightcurve_gp.filters.state import FilterState, StateLayout
from lightcurve_gp.filters.unscented import sqrt_psd_with_zero_rows
from lightcurve_gp.filters.update import Prior, kalman_gain, measurement_update, sigma_inputs, sigma_set
from lightcurve_gp.filters.usque import UsqueParams, run_constants
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario

DT = torch.float64
ROBUST = Path(__file__).resolve().parents[1] / "configs" / "boxwing_robust.yaml"


class LinearModel(torch.nn.Module):
    """``y = c · grp(q ⊗ q_ref⁻¹) + d``: linear in the GRP error about ``q_ref`` (the prior's centre below)."""

    def __init__(self, q_ref, c, d):
        super().__init__()
        self.q_ref, self.c, self.d = q_ref, c, d

    def forward(self, *, q, m_past, variance="none"):
        err = quat_to_grp(quat_mul(q, torch.cat([-self.q_ref[..., :3], self.q_ref[..., 3:]], -1).unsqueeze(1)), 1.0,
                          4.0)
        return (err * self.c.unsqueeze(1)).sum(-1) + self.d.unsqueeze(1), None


def _prior(P_m, q_m, scale, offset=False):
    root, failed = sqrt_psd_with_zero_rows(P_m)
    return Prior(q_m, None, None, P_m, sigma_set(None, math.sqrt(scale) * root.mT), failed)


def _setup(B=4, offset=False, model=None, q_m=None, R=1e-4):
    gen = torch.Generator().manual_seed(3)
    layout = StateLayout(offset=offset)
    n = layout.dim
    q_m = quat_normalize(torch.randn(B, 4, generator=gen, dtype=DT)) if q_m is None else q_m
    A = torch.randn(B, n, n, generator=gen, dtype=DT) * 0.05
    P_m = A @ A.mT + 1e-3 * torch.eye(n, dtype=DT)
    params = UsqueParams(Q=0.0, R=R, variance="none", lam=0.0, update_iterations=1)
    run, _ = run_constants(params, layout, model, B, 10, q_m)
    state = FilterState(q_m.clone(), torch.zeros(B, dtype=DT) if offset else None, P_m.clone(),
                        torch.zeros(B, dtype=DT))
    return run, state, _prior(P_m, q_m, run.scale), gen


def test_one_iteration_is_the_ordinary_update_and_the_regression_over_the_prior_reproduces_its_gain():
    cfg = load_config(ROBUST)
    scene = Scene.from_config(cfg).to(dtype=DT)
    model = Parametric(scene, 0.5)
    q_true = quat_normalize(torch.tensor([[0.1, -0.3, 0.2, 0.9], [0.5, 0.1, -0.4, 0.6]], dtype=DT))
    err = euler321_to_quat(torch.deg2rad(torch.tensor([[5.0, -3.0, 4.0], [-8.0, 2.0, 6.0]], dtype=DT)))
    q_m = quat_mul(err, q_true)
    run, state, prior, _ = _setup(B=2, model=model, q_m=q_m)
    y = model(q=q_true.unsqueeze(1), m_past=torch.zeros(2, 1, dtype=DT), variance="none")[0][:, 0]
    seen = torch.ones(2, dtype=torch.bool)
    ordinary, rec = measurement_update(run, state, prior, y_k=y, observed_k=seen)
    once, rec_once = iterated_update(run, state, prior, y_k=y, observed_k=seen, iterations=1)
    for a, b in zip((ordinary.q_hat, ordinary.P, rec.y_pred, rec.y_var), (once.q_hat, once.P, rec_once.y_pred,
                                                                          rec_once.y_var)):
        assert torch.equal(a, b)
    # the SLR step started from the prior itself (x_j = 0, P_j = P⁻, the same sigma points) is the ordinary gain
    sig = sigma_inputs(run, state, prior)
    y_sig, _ = model(q=sig.q, m_past=sig.m_past, variance="none")
    gain = kalman_gain(run, state, prior, y_sig, None, y_k=y, observed_k=seen)
    start = gain._replace(dx=torch.zeros_like(gain.dx), P=prior.P_m)
    again = relinearised_gain(run, state, prior, start, y_k=y, observed_k=seen)
    torch.testing.assert_close(again.dx, gain.dx, rtol=0, atol=1e-10)
    torch.testing.assert_close(again.P, gain.P, rtol=0, atol=1e-12)
    # a second real iteration moves the estimate (the renderer is not linear over a 5-10 deg prior)
    twice, _ = iterated_update(run, state, prior, y_k=y, observed_k=seen, iterations=2)
    assert float((twice.q_hat - once.q_hat).abs().max()) > 1e-6


@pytest.mark.parametrize("offset", [False, True])
@pytest.mark.parametrize("iterations", [1, 2, 4])
def test_a_linear_gaussian_measurement_gets_the_exact_posterior_at_every_iteration(offset, iterations):
    B = 5
    gen = torch.Generator().manual_seed(11)
    q_m = quat_normalize(torch.randn(B, 4, generator=gen, dtype=DT))
    c, d = torch.randn(B, 3, generator=gen, dtype=DT), torch.randn(B, generator=gen, dtype=DT)
    model = LinearModel(q_m, c, d)
    run, state, prior, _ = _setup(B=B, offset=offset, model=model, q_m=q_m, R=0.01)
    y = torch.randn(B, generator=gen, dtype=DT)
    seen = torch.tensor([True, True, False, True, True])
    out, rec = iterated_update(run, state, prior, y_k=y, observed_k=seen, iterations=iterations)
    H = torch.cat([c, torch.ones(B, 1, dtype=DT)], -1) if offset else c  # y = H x + d
    P = prior.P_m
    S = (H.unsqueeze(1) @ P @ H.unsqueeze(-1)).squeeze(-1).squeeze(-1) + 0.01
    K = (P @ H.unsqueeze(-1)).squeeze(-1) / S.unsqueeze(-1)
    x = K * (y - d).unsqueeze(-1)
    P_post = P - S.view(B, 1, 1) * K.unsqueeze(-1) * K.unsqueeze(-2)
    x = torch.where(seen.unsqueeze(-1), x, 0.0)
    P_post = torch.where(seen.view(B, 1, 1), P_post, P)
    torch.testing.assert_close(out.P, P_post, rtol=0, atol=1e-12)
    torch.testing.assert_close(quat_to_grp(quat_mul(out.q_hat, torch.cat([-q_m[:, :3], q_m[:, 3:]], -1)), 1.0, 4.0),
                               x[:, :3], rtol=0, atol=1e-10)
    if offset:
        torch.testing.assert_close(out.offset, x[:, 3], rtol=0, atol=1e-10)
    assert torch.equal(rec.updated, seen)


def test_a_run_with_the_iterated_update_is_finite_and_differs_from_the_ordinary_one():
    cfg = load_config(ROBUST, ["scenario.duration_s=60", "evaluation.rmse_window_s=[30, 60]",
                               "scenario.noise_var=0.01", "filter.measurement_noise=0.01"])
    sc = simulate_scenario(cfg, seeds=[0, 1])
    model = Parametric(Scene.from_config(cfg).to(dtype=DT), 0.5)
    runs = {}
    for j in (1, 3):
        c = load_config(ROBUST, ["scenario.duration_s=60", "evaluation.rmse_window_s=[30, 60]",
                                 "scenario.noise_var=0.01", "filter.measurement_noise=0.01",
                                 f"filter.update_iterations={j}"])
        runs[j] = run_filter(c, model, q_est0=sc.q_est0, observations=sc.observations, increments=sc.increments,
                             offset=False)
    assert torch.isfinite(runs[3].q_est).all() and torch.isfinite(runs[3].P).all()
    assert float((runs[3].q_est[:, -1] - runs[1].q_est[:, -1]).abs().max()) > 1e-6
    assert torch.equal(runs[1].y_pred[:, 1], runs[3].y_pred[:, 1])  # step 1 starts from the same prior


def test_the_iterated_update_is_refused_with_the_compiled_step():
    with pytest.raises(ConfigError, match="^filter.update_iterations: 2 is not supported with filter.compile true"):
        load_config(ROBUST, ["filter.update_iterations=2", "filter.compile=true"])
    with pytest.raises(ConfigError, match="^filter.update_iterations: 0 must be >= 1$"):
        load_config(ROBUST, ["filter.update_iterations=0"])
