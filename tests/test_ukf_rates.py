"""The rate-state USQUE (state [δp, ω, b?]): against the ω-known filter, dynamics.propagate, a textbook recursion
that propagates every sigma point on its own, and a Kalman filter on a linearised toy; the paper's variant."""

import math

import numpy as np
import pytest
import torch
from reference_ukf import sigma_points, unscented_mean_cov

from lightcurve_gp.attitude.dynamics import propagate, quaternion_increments, rk4_stepper
from lightcurve_gp.attitude.rotations import euler321_to_quat, grp_to_quat, quat_conj, quat_mul, quat_to_grp
from lightcurve_gp.filters.rates import rate_prior
from lightcurve_gp.filters.state import FilterState, StateLayout
from lightcurve_gp.filters.unscented import sqrt_psd_with_zero_rows
from lightcurve_gp.filters.usque import UsqueParams, initial_covariance, run_constants, run_usque

from helpers import DT, ToyModel, err_deg

J = (55.0, 40.0, 65.0)
OMEGA0 = torch.deg2rad(torch.tensor([1.5, -1.0, 2.5], dtype=DT))


def tumbling_truth(B=3, T=60, seed=0, noise=0.0):
    """Torque-free truth from random attitudes at OMEGA0, toy observations, estimates 10° off."""
    g = torch.Generator().manual_seed(seed)
    q0 = torch.nn.functional.normalize(torch.randn(B, 4, generator=g, dtype=DT), dim=-1)
    q_true, omega_true = propagate(q0, OMEGA0, torch.tensor(J, dtype=DT), 1.0, T)
    y = ToyModel()(q=q_true, m_past=torch.zeros(B, T + 1, dtype=DT))[0]
    y = y + noise * torch.randn(y.shape, generator=g, dtype=DT)
    q_est0 = quat_mul(euler321_to_quat(torch.deg2rad(torch.tensor([-10.0, 5.0, -10.0], dtype=DT))), q0)
    return q_true, omega_true, y, q_est0


def block_diag_P0(P_att, omega_var, offset_var=None):
    n = 6 + (offset_var is not None)
    P0 = torch.zeros(n, n, dtype=DT)
    P0[:3, :3] = P_att
    P0[3:6, 3:6] = omega_var * torch.eye(3, dtype=DT)
    if offset_var is not None:
        P0[6, 6] = offset_var
    return P0


# ----------------------------------------------------------------------------------------------- ω known exactly

@pytest.mark.parametrize("redraw, placement", [(False, "both"), (True, "after")])
@pytest.mark.parametrize("with_offset", [False, True])
def test_zero_rate_uncertainty_equals_the_omega_known_filter(redraw, placement, with_offset):
    """P0_ω = 0 and no ω noise: the rate filter is the ω-known filter (same n + λ, so the same sigma spread; the
    three extra sigma points pairs sit on the centre and carry its weight)."""
    B, T = 3, 150
    q_true, omega_true, y, q_est0 = tumbling_truth(B, T, noise=0.01)
    b_true = torch.tensor([0.2, -0.1, 0.0], dtype=DT)
    y = y + b_true[:, None] if with_offset else y
    offset0 = torch.zeros(B, dtype=DT) if with_offset else None
    P_att = initial_covariance(10.0, dtype=DT)
    n_known = 3 + with_offset
    P_known = P_att if not with_offset else torch.block_diag(P_att, torch.tensor([[0.25]], dtype=DT))
    common = dict(Q=1e-6, R=1e-4, variance="none", sigma_redraw=redraw, q_placement=placement,
                  offset_process_noise=1e-6)
    known = run_usque(model=ToyModel(), q_est0=q_est0, P0=P_known, observations=y, m_past0=torch.zeros(B, dtype=DT),
                      increments=quaternion_increments(OMEGA0, torch.tensor(J, dtype=DT), 1.0, T),
                      params=UsqueParams(lam=0.0, **common), offset0=offset0)
    rates = run_usque(model=ToyModel(), q_est0=q_est0, P0=block_diag_P0(P_att, 0.0, 0.25 if with_offset else None),
                      observations=y, m_past0=torch.zeros(B, dtype=DT), omega0=OMEGA0,
                      params=UsqueParams(lam=float(n_known - (n_known + 3)), **common), offset0=offset0)
    assert rates.P_full.shape == (B, T + 1, n_known + 3, n_known + 3)
    assert rates.fallbacks.tolist() == [0] * B and known.fallbacks.tolist() == [0] * B
    torch.testing.assert_close(rates.q_est, known.q_est, rtol=0, atol=1e-10)
    torch.testing.assert_close(rates.P, known.P, rtol=0, atol=1e-10)
    torch.testing.assert_close(rates.omega, omega_true.expand(B, -1, -1), rtol=0, atol=1e-10)
    assert rates.P_full[..., 3:6, :].abs().max().item() == 0.0  # ω stays known
    if with_offset:
        torch.testing.assert_close(rates.offset, known.offset, rtol=0, atol=1e-10)
    # and the updates did something: every filter ends closer to the truth than its ~15° start
    e = err_deg(q_true, rates.q_est)
    assert (e[:, 0] > 14.0).all() and (e[:, -1] < e[:, 0]).all(), e[:, -1]


def test_square_root_leaves_out_zero_variance_components():
    g = torch.Generator().manual_seed(3)
    A = torch.randn(4, 4, generator=g, dtype=DT)
    P = torch.zeros(6, 6, dtype=DT)
    keep = [0, 2, 3, 5]
    P[np.ix_(keep, keep)] = A @ A.T + 0.1 * torch.eye(4, dtype=DT)
    S, failed = sqrt_psd_with_zero_rows(P)
    assert not failed.item()
    torch.testing.assert_close(S @ S.T, P, rtol=0, atol=1e-13)
    assert S[:, [1, 4]].abs().max().item() == 0.0
    torch.testing.assert_close(S[np.ix_(keep, keep)], torch.linalg.cholesky(P[np.ix_(keep, keep)]), rtol=0,
                               atol=1e-15)


# ----------------------------------------------------------------------------------------------- propagation

def test_every_sigma_point_moves_as_dynamics_propagate_moves_it():
    """The rate prior's one batched RK4 call equals dynamics.propagate of each sigma point on its own."""
    B = 2
    g = torch.Generator().manual_seed(5)
    q_hat = torch.nn.functional.normalize(torch.randn(B, 4, generator=g, dtype=DT), dim=-1)
    omega_hat = OMEGA0 * (1 + 0.3 * torch.rand(B, 1, generator=g, dtype=DT))
    P = block_diag_P0(initial_covariance(5.0, dtype=DT), math.radians(0.5) ** 2)
    params = UsqueParams(Q=0.0, variance="none", dt=2.0)
    run, _ = run_constants(params, StateLayout(omega=True), ToyModel(), B, 1, q_hat)
    state = FilterState(q_hat, None, P.expand(B, 6, 6), torch.zeros(B, dtype=DT), omega=omega_hat)
    prior = rate_prior(run, state)
    # the sigma points before propagation, as the prior draws them
    chi = sigma_points(torch.zeros(B, 6, dtype=DT), P.expand(B, 6, 6), run.scale - 6, warn=False)[0]
    for b in range(B):
        for i in range(13):
            q_i = quat_mul(grp_to_quat(chi[b, i, :3]), q_hat[b])
            q_hist, w_hist = propagate(q_i, omega_hat[b] + chi[b, i, 3:], torch.tensor(J, dtype=DT), 2.0, 1)
            if i == 0:
                torch.testing.assert_close(prior.q_m[b], q_hist[-1], rtol=0, atol=1e-15)
                torch.testing.assert_close(prior.omega_m[b], w_hist[-1], rtol=0, atol=1e-15)
            # the prior's χ_i⁻ (no redraw) re-expresses exactly that attitude and rate about the centre
            dq = quat_mul(q_hist[-1], quat_conj(prior.q_m[b]))
            torch.testing.assert_close(prior.chi[b, i, :3], quat_to_grp(dq), rtol=0, atol=1e-14)
            torch.testing.assert_close(prior.chi[b, i, 3:], w_hist[-1] - prior.omega_m[b], rtol=0, atol=1e-15)


def test_the_stepper_validates_once_and_equals_rk4_step():
    from lightcurve_gp.attitude.dynamics import rk4_step

    g = torch.Generator().manual_seed(1)
    q = torch.nn.functional.normalize(torch.randn(4, 5, 4, generator=g, dtype=DT), dim=-1)
    w = 0.05 * torch.randn(4, 5, 3, generator=g, dtype=DT)
    step = rk4_stepper(J, 0.5, like=w)
    for got, want in zip(step(q, w), rk4_step(q, w, J, 0.5)):
        torch.testing.assert_close(got, want, rtol=0, atol=0)
    with pytest.raises(ValueError, match="dt must be"):
        rk4_stepper(J, -1.0, like=w)


# ----------------------------------------------------------------------------------------------- textbook

def textbook_rate_usque(q_est0, omega0, P0, y, params, *, redraw, q_both):
    """USQUE with ω in the state as Crassidis & Markley write it, one filter and one sigma point at a time:
    each sigma point propagated by dynamics.propagate, re-expressed about the propagated centre; the paper's
    variant redraws the update's sigma points from (x̂⁻, P⁻) and adds Q once."""
    n = 6
    lam, wm, wc = params.weights(n, dtype=DT)
    Q = torch.block_diag(params.Q * torch.eye(3, dtype=DT), params.omega_process_noise * torch.eye(3, dtype=DT))
    q_hat, w_hat, P, out, rates = q_est0, omega0, P0, [q_est0], [omega0]
    for k in range(1, y.shape[0]):
        chi, _ = sigma_points(torch.zeros(1, n, dtype=DT), (P + Q if q_both else P)[None], lam)
        chi = chi[0]
        moved = [propagate(quat_mul(grp_to_quat(c[:3]), q_hat), w_hat + c[3:], torch.tensor(J, dtype=DT), 1.0, 1)
                 for c in chi]
        q_sig = torch.stack([m[0][-1] for m in moved])
        w_sig = torch.stack([m[1][-1] for m in moved])
        chi_m = torch.cat([quat_to_grp(quat_mul(q_sig, quat_conj(q_sig[0]))), w_sig - w_sig[0]], -1)
        x_m, P_m = unscented_mean_cov(chi_m, wm, wc, Q)
        if redraw:
            chi_m = sigma_points(x_m[None], P_m[None], lam)[0][0]
        q_upd = quat_mul(grp_to_quat(chi_m[:, :3]), q_sig[0])
        ys = ToyModel()(q=q_upd, m_past=torch.zeros(2 * n + 1, dtype=DT), variance="none")[0]
        y_hat, P_yy = unscented_mean_cov(ys[:, None], wm, wc, torch.tensor([[params.R]], dtype=DT))
        P_xy = ((chi_m - x_m).T * wc) @ (ys[:, None] - y_hat)
        K = P_xy / P_yy
        x_p = x_m + (K * (y[k] - y_hat)).squeeze(-1)
        P = P_m - K @ P_yy @ K.T
        q_hat = quat_mul(grp_to_quat(x_p[:3]), q_sig[0])
        q_hat = q_hat / q_hat.norm()
        w_hat = w_sig[0] + x_p[3:]
        out.append(q_hat)
        rates.append(w_hat)
    return torch.stack(out), torch.stack(rates), P


@pytest.mark.parametrize("redraw, placement", [(False, "both"), (True, "after"), (True, "both"), (False, "after")])
def test_rate_filter_equals_the_textbook_recursion(redraw, placement):
    B, T = 2, 30
    q_true, omega_true, y, q_est0 = tumbling_truth(B, T, seed=4, noise=0.02)
    omega0 = OMEGA0 + torch.deg2rad(torch.tensor([0.05, -0.05, 0.05], dtype=DT))
    g = torch.Generator().manual_seed(9)
    A = torch.randn(6, 6, generator=g, dtype=DT) * 1e-3
    P0 = block_diag_P0(initial_covariance(8.0, dtype=DT), math.radians(0.1) ** 2) + A @ A.T
    params = UsqueParams(Q=1e-6, R=4e-4, variance="none", omega_process_noise=1e-10, sigma_redraw=redraw,
                         q_placement=placement)
    h = run_usque(model=ToyModel(), q_est0=q_est0, P0=P0, observations=y, m_past0=torch.zeros(B, dtype=DT),
                  omega0=omega0, params=params)
    for b in range(B):
        q_ref, w_ref, P_ref = textbook_rate_usque(q_est0[b], omega0, P0, y[b], params, redraw=redraw,
                                                  q_both=placement == "both")
        torch.testing.assert_close(h.q_est[b], q_ref, rtol=0, atol=1e-12)
        torch.testing.assert_close(h.omega[b], w_ref, rtol=0, atol=1e-13)
        torch.testing.assert_close(h.P_full[b, -1], P_ref, rtol=0, atol=1e-14)


def textbook_known_usque_variant(q_est0, P0, y, increments, params):
    """The ω-known USQUE with the paper's variant, one sigma quaternion at a time: sigma points of P⁺ (Q after the
    propagation only), propagated, mean and covariance + Q, sigma points drawn again from (x̂⁻, P⁻)."""
    lam, wm, wc = params.weights(3, dtype=DT)
    Q = params.Q * torch.eye(3, dtype=DT)
    q_hat, P, out = q_est0, P0, [q_est0]
    for k in range(1, y.shape[0]):
        chi = sigma_points(torch.zeros(1, 3, dtype=DT), P[None], lam)[0][0]
        q_sig = quat_mul(increments[k - 1], quat_mul(grp_to_quat(chi), q_hat))
        q_sig = q_sig / q_sig.norm(dim=-1, keepdim=True)
        x_m, P_m = unscented_mean_cov(quat_to_grp(quat_mul(q_sig, quat_conj(q_sig[0]))), wm, wc, Q)
        chi_m = sigma_points(x_m[None], P_m[None], lam)[0][0]
        ys = ToyModel()(q=quat_mul(grp_to_quat(chi_m), q_sig[0]), m_past=torch.zeros(7, dtype=DT),
                        variance="none")[0]
        y_hat, P_yy = unscented_mean_cov(ys[:, None], wm, wc, torch.tensor([[params.R]], dtype=DT))
        K = ((chi_m - x_m).T * wc) @ (ys[:, None] - y_hat) / P_yy
        x_p = x_m + (K * (y[k] - y_hat)).squeeze(-1)
        P = P_m - K @ P_yy @ K.T
        q_hat = quat_mul(grp_to_quat(x_p), q_sig[0])
        out.append(q_hat / q_hat.norm())
    return torch.stack(out), P


def test_the_papers_variant_with_omega_known_equals_its_textbook_recursion():
    B, T = 2, 40
    q_true, _, y, q_est0 = tumbling_truth(B, T, seed=6, noise=0.02)
    inc = quaternion_increments(OMEGA0, torch.tensor(J, dtype=DT), 1.0, T)
    P0 = initial_covariance(8.0, dtype=DT)
    params = UsqueParams(Q=1e-5, R=4e-4, variance="none", sigma_redraw=True, q_placement="after")
    h = run_usque(model=ToyModel(), q_est0=q_est0, P0=P0, observations=y, m_past0=torch.zeros(B, dtype=DT),
                  increments=inc, params=params)
    default = run_usque(model=ToyModel(), q_est0=q_est0, P0=P0, observations=y, m_past0=torch.zeros(B, dtype=DT),
                        increments=inc, params=UsqueParams(Q=1e-5, R=4e-4, variance="none"))
    assert (h.q_est - default.q_est).abs().max() > 1e-6  # the variant is another filter
    for b in range(B):
        q_ref, P_ref = textbook_known_usque_variant(q_est0[b], P0, y[b], inc, params)
        torch.testing.assert_close(h.q_est[b], q_ref, rtol=0, atol=1e-12)
        torch.testing.assert_close(h.P[b, -1], P_ref, rtol=0, atol=1e-14)


# ----------------------------------------------------------------------------------------------- linearised toy

def test_rate_filter_on_a_linearised_toy_equals_the_kalman_filter():
    """An isotropic body at rest (ω̂ = 0, J = I: ω constant) with tiny errors: θ_{k+1} = θ_k + dt ω_k and
    y = H θ + noise with H the toy model's gradient. The rate filter's posterior (and the rate it infers from the
    attitude drift) is the Kalman filter's of x = [θ, ω], F = [[I, dt I], [0, I]]."""
    T, dt = 40, 1.0
    q0 = torch.nn.functional.normalize(torch.tensor([[0.3, -0.2, 0.5, 0.8]], dtype=DT), dim=-1)
    theta_true0 = torch.tensor([2e-5, -1e-5, 1.5e-5], dtype=DT)
    omega_true = torch.tensor([3e-7, 2e-7, -4e-7], dtype=DT)
    # the toy observation's gradient with respect to the GRP error (≈ rotation vector) about q0
    base = lambda th: ToyModel()(q=quat_mul(grp_to_quat(th), q0[0]), m_past=torch.zeros((), dtype=DT))[0]  # noqa: E731
    eps = 1e-6 * torch.eye(3, dtype=DT)
    H = torch.stack([(base(e) - base(-e)) / 2e-6 for e in eps]).reshape(1, 3)  # central differences
    g = torch.Generator().manual_seed(0)
    R = 1e-12
    thetas = torch.stack([theta_true0 + k * dt * omega_true for k in range(T + 1)])
    y_lin = (thetas @ H.T).squeeze(-1) + math.sqrt(R) * torch.randn(T + 1, generator=g, dtype=DT)
    y = y_lin + base(torch.zeros(3, dtype=DT))
    P0 = block_diag_P0((5e-5) ** 2 * torch.eye(3, dtype=DT), (1e-6) ** 2)
    params = UsqueParams(Q=0.0, R=R, variance="none", inertia=(1.0, 1.0, 1.0), dt=dt)
    h = run_usque(model=ToyModel(), q_est0=q0, P0=P0, observations=y[None], m_past0=torch.zeros(1, dtype=DT),
                  omega0=torch.zeros(3, dtype=DT), params=params)
    F = torch.eye(6, dtype=DT)
    F[:3, 3:] = dt * torch.eye(3, dtype=DT)
    Hx = torch.cat([H, torch.zeros(1, 3, dtype=DT)], -1)
    x, P = torch.zeros(6, dtype=DT), P0.clone()
    for k in range(1, T + 1):
        x, P = F @ x, F @ P @ F.T
        S = Hx @ P @ Hx.T + R
        K = P @ Hx.T / S
        x = x + (K * (y_lin[k] - Hx @ x)).squeeze(-1)
        P = P - K @ S @ K.T
    # estimated error state = truth − estimate: the filter's attitude estimate is q0 rotated by the KF's θ
    theta_ukf = quat_to_grp(quat_mul(h.q_est[0, -1], quat_conj(q0[0])))
    np.testing.assert_allclose(theta_ukf.numpy(), x[:3].numpy(), rtol=0, atol=1e-3 * thetas.abs().max().item())
    np.testing.assert_allclose(h.omega[0, -1].numpy(), x[3:].numpy(), rtol=0, atol=1e-3 * omega_true.abs().max().item())
    np.testing.assert_allclose(h.P_full[0, -1].numpy(), P.numpy(), rtol=1e-3, atol=1e-3 * P.diagonal().min().item())
    # the rate was learned: its posterior std shrank well below the prior's
    assert (h.P_full[0, -1].diagonal()[3:] < 0.5 * P0.diagonal()[3:]).any()


# ----------------------------------------------------------------------------------------------- inputs

def test_rate_inputs_are_checked():
    _, _, y, q_est0 = tumbling_truth(2, 5)
    P0 = block_diag_P0(initial_covariance(5.0, dtype=DT), 1e-6)
    kw = dict(model=ToyModel(), q_est0=q_est0, observations=y, m_past0=torch.zeros(2, dtype=DT))
    with pytest.raises(ValueError, match="not both or neither"):
        run_usque(P0=P0, **kw)
    with pytest.raises(ValueError, match=r"P0 must have shape \(6, 6\).*\[dp, omega\]"):
        run_usque(P0=initial_covariance(5.0, dtype=DT), omega0=OMEGA0, **kw)
    with pytest.raises(ValueError, match="omega0 must have shape"):
        run_usque(P0=P0, omega0=OMEGA0[:2], **kw)
    with pytest.raises(ValueError, match="q_placement must be one of both, after"):
        UsqueParams(q_placement="before")
    with pytest.raises(ValueError, match="omega_process_noise must be >= 0"):
        UsqueParams(omega_process_noise=-1.0)
