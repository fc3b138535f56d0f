"""Batched USQUE against the textbook recursion on a toy attitude observation model: convergence, offsets, batches,
missing and refused observations, square-root fallbacks, the model variance, configs, shapes and consistency."""

import math
from pathlib import Path

import pytest
import torch
from reference_ukf import sigma_points, unscented_mean_cov

from lightcurve_gp.attitude.rotations import (
    euler321_to_quat,
    grp_to_quat,
    quat_conj,
    quat_mul,
    quat_to_grp,
)
from lightcurve_gp.config.load import load_config
from lightcurve_gp.filters.unscented import SqrtFallbackWarning
from lightcurve_gp.filters.usque import UsqueParams, initial_covariance, run_usque

from helpers import DT, ToyModel, err_deg, increment, scenario

# ----------------------------------------------------------------------------------------------- USQUE

PARAMS = UsqueParams(Q=1e-8, R=1e-4, variance="none", t_span_past=20.0)


def test_usque_converges_from_ten_degrees_on_noise_free_observations():
    q_true, y, q_est0, inc = scenario(B=3, T=300)
    P0 = initial_covariance(10.0, dtype=DT)
    h = run_usque(model=ToyModel(), q_est0=q_est0, P0=P0, observations=y, m_past0=torch.zeros(3, dtype=DT),
                  increments=inc, params=PARAMS)
    e = err_deg(q_true, h.q_est)
    assert e[:, 0].min() > 14.0  # (-10, 5, -10)° is ~14.8° in total
    # a constant body rate observes the attitude weakly for some initial attitudes (filter 1 here is still
    # ~1.2° at 300 s, 0.34° at 600 s, consistent with its own σ ≈ 0.4°); the others reach < 0.05°
    assert (e[:, -20:] < 2.0).all(), e[:, -1]
    assert (e[:, -20:] < 0.1).sum(0).min() >= 2, e[:, -1]
    assert h.updated[:, 1:].all() and not h.updated[:, 0].any()
    assert h.fallbacks.tolist() == [0, 0, 0] and h.rejected.tolist() == [0, 0, 0]
    assert torch.isnan(h.y_pred[:, 0]).all() and torch.isfinite(h.y_pred[:, 1:]).all()
    # the posterior spread shrank with the error
    assert (torch.diagonal(h.P[:, -1], dim1=-2, dim2=-1) < torch.diagonal(h.P[:, 0], dim1=-2, dim2=-1)).all()


def textbook_usque(model, q_est0, P0, y, increments, params, b0=None):
    """USQUE as Crassidis & Markley (2003) write it, one filter at a time: every sigma quaternion is propagated
    and re-expressed as a GRP error about the propagated centre; reference UKF pieces for the moments. With ``b0``
    the state is ``[δp, b]`` and the measurement ``h(q) + b``."""
    n = 3 if b0 is None else 4
    lam, wm, wc = params.weights(n, dtype=DT)
    q_hat, P, out, offsets = q_est0, P0, [q_est0], [b0]
    Q = torch.zeros(n, n, dtype=DT)
    Q[:3, :3] = params.Q * torch.eye(3, dtype=DT)
    if b0 is not None:
        Q[3, 3] = params.offset_process_noise
    x_hat = torch.zeros(n, dtype=DT) if b0 is None else torch.cat([torch.zeros(3, dtype=DT), b0.reshape(1)])
    for k in range(1, y.shape[0]):
        chi, _ = sigma_points(x_hat[None], (P + Q)[None], lam)
        chi = chi[0]
        q_sig = quat_mul(increments[k - 1], quat_mul(grp_to_quat(chi[:, :3]), q_hat))
        q_sig = q_sig / q_sig.norm(dim=-1, keepdim=True)
        chi_m = torch.cat([quat_to_grp(quat_mul(q_sig, quat_conj(q_sig[0]))), chi[:, 3:]], -1)
        x_m, P_m = unscented_mean_cov(chi_m, wm, wc, Q)
        ys = model(q=q_sig, m_past=torch.zeros(2 * n + 1, dtype=DT), variance="none")[0]
        if b0 is not None:
            ys = ys + chi[:, 3]
        y_hat, P_yy = unscented_mean_cov(ys[:, None], wm, wc, torch.tensor([[params.R]], dtype=DT))
        P_xy = ((chi_m - x_m).T * wc) @ (ys[:, None] - y_hat)
        K = P_xy / P_yy
        x_p = x_m + (K * (y[k] - y_hat)).squeeze(-1)
        P = P_m - K @ P_yy @ K.T
        q_hat = quat_mul(grp_to_quat(x_p[:3]), q_sig[0])
        q_hat = q_hat / q_hat.norm()
        x_hat = torch.cat([torch.zeros(3, dtype=DT), x_p[3:]])
        out.append(q_hat)
        offsets.append(x_p[3] if b0 is not None else None)
    return torch.stack(out), P, (None if b0 is None else torch.stack(offsets))


def test_usque_equals_the_textbook_recursion_that_propagates_every_sigma_quaternion():
    """run_usque propagates the sigma points as the rotation A(δ) of their GRP errors: the same filter."""
    q_true, y, q_est0, inc = scenario(B=3, T=40, noise=0.02)
    g = torch.Generator().manual_seed(2)
    A = torch.randn(3, 3, 3, generator=g, dtype=DT) * 0.05
    P0 = A @ A.transpose(-1, -2) + initial_covariance(8.0, dtype=DT)
    params = UsqueParams(Q=1e-5, R=4e-4, variance="none")
    h = run_usque(model=ToyModel(), q_est0=q_est0, P0=P0, observations=y, m_past0=torch.zeros(3, dtype=DT),
                  increments=inc, params=params)
    assert h.offset is None and h.offset_var is None and torch.equal(h.P_full, h.P)
    for b in range(3):
        q_ref, P_ref, _ = textbook_usque(ToyModel(), q_est0[b], P0[b], y[b], inc[b], params)
        torch.testing.assert_close(h.q_est[b], q_ref, rtol=0, atol=1e-12)
        torch.testing.assert_close(h.P[b, -1], P_ref, rtol=0, atol=1e-14)


@pytest.mark.parametrize("lam", [0.0, 1.0])
def test_usque_with_an_offset_equals_the_textbook_recursion(lam):
    """The same loop with the offset block ``b`` (the state ``[δp, b]``, ``y = h(q) + b``, b a random walk)
    equals the textbook filter that propagates every sigma quaternion and carries b along."""
    _, y, q_est0, inc = scenario(B=3, T=40, noise=0.02)
    b_true = torch.tensor([0.3, -0.2, 0.0], dtype=DT)
    g = torch.Generator().manual_seed(7)
    A = torch.randn(3, 4, 4, generator=g, dtype=DT) * 0.05
    P0 = A @ A.transpose(-1, -2) + torch.diag(torch.tensor([1e-2, 1e-2, 1e-2, 0.25], dtype=DT))
    b0 = torch.tensor([0.1, 0.1, -0.1], dtype=DT)
    params = UsqueParams(Q=1e-5, R=4e-4, variance="none", lam=lam, offset_process_noise=1e-4)
    h = run_usque(model=ToyModel(), q_est0=q_est0, P0=P0, observations=y + b_true[:, None],
                  m_past0=torch.zeros(3, dtype=DT), increments=inc, params=params, offset0=b0)
    assert h.P_full.shape == (3, 41, 4, 4) and torch.equal(h.offset_var, h.P_full[..., 3, 3])
    for b in range(3):
        q_ref, P_ref, b_ref = textbook_usque(ToyModel(), q_est0[b], P0[b], y[b] + b_true[b], inc[b], params, b0[b])
        torch.testing.assert_close(h.q_est[b], q_ref, rtol=0, atol=1e-12)
        torch.testing.assert_close(h.offset[b], b_ref, rtol=0, atol=1e-12)
        torch.testing.assert_close(h.P_full[b, -1], P_ref, rtol=0, atol=1e-14)


def test_the_filter_passes_its_variance_choice_with_every_model_call():
    class Recording(ToyModel):
        def _predict(self, q, m_past, variance):
            self.asked.append(variance)
            return super()._predict(q, m_past, variance)

    _, y, q_est0, inc = scenario(B=2, T=4)
    for choice in ("none", "fast", "exact"):
        model = Recording(variance=0.05)
        model.asked = []
        h = run_usque(model=model, q_est0=q_est0, P0=initial_covariance(10.0, dtype=DT), observations=y,
                      m_past0=torch.zeros(2, dtype=DT), increments=inc, params=UsqueParams(variance=choice))
        assert model.asked == [choice] * 4
        assert bool(torch.isnan(h.model_var[:, 1:]).all()) == (choice == "none")


def test_usque_batch_equals_separate_runs():
    q_true, y, q_est0, inc = scenario(B=4, T=60, noise=0.01)
    g = torch.Generator().manual_seed(5)
    A = torch.randn(4, 3, 3, generator=g, dtype=DT) * 0.05
    P0 = A @ A.transpose(-1, -2) + initial_covariance(5.0, dtype=DT)
    m0 = torch.tensor([0.1, -0.2, 0.3, 0.0], dtype=DT)
    params = UsqueParams(Q=1e-6, R=torch.tensor([1e-4, 2e-4, 1e-3, 5e-4], dtype=DT), variance="fast",
                         t_span_past=10.0)
    model = ToyModel(variance=1e-4, m_past_gain=0.3)
    h = run_usque(model=model, q_est0=q_est0, P0=P0, observations=y, m_past0=m0, increments=inc, params=params)
    for b in range(4):
        pb = UsqueParams(Q=1e-6, R=float(params.R[b]), variance="fast", t_span_past=10.0)
        hb = run_usque(model=model, q_est0=q_est0[b:b + 1], P0=P0[b:b + 1], observations=y[b:b + 1],
                       m_past0=m0[b:b + 1], increments=inc[b:b + 1], params=pb)
        for name in ("q_est", "P", "y_pred", "y_var", "model_var", "innovation", "m_past"):
            torch.testing.assert_close(getattr(hb, name)[0], getattr(h, name)[b], rtol=0, atol=1e-12, equal_nan=True,
                                       msg=f"{name} of filter {b}")


def test_shared_increments_equal_per_filter_increments():
    q_true, y, q_est0, inc = scenario(B=1, T=30)
    q_est0, y = q_est0.expand(3, 4), y.expand(3, -1)
    P0 = initial_covariance(10.0, dtype=DT)
    h1 = run_usque(model=ToyModel(), q_est0=q_est0, P0=P0, observations=y, m_past0=torch.zeros(3, dtype=DT),
                   increments=inc[0], params=PARAMS)
    h2 = run_usque(model=ToyModel(), q_est0=q_est0, P0=P0, observations=y, m_past0=torch.zeros(3, dtype=DT),
                   increments=inc.expand(3, -1, -1), params=PARAMS)
    torch.testing.assert_close(h1.q_est, h2.q_est, rtol=0, atol=0)


def test_one_model_call_per_step():
    q_true, y, q_est0, inc = scenario(B=5, T=12)
    model = ToyModel()
    run_usque(model=model, q_est0=q_est0, P0=initial_covariance(10.0, dtype=DT), observations=y,
              m_past0=torch.zeros(5, dtype=DT), increments=inc, params=PARAMS)
    assert model.calls == 12


def test_nan_observation_skips_update_and_m_past_for_that_filter_only():
    q_true, y, q_est0, inc = scenario(B=3, T=40, noise=0.01)
    P0 = initial_covariance(10.0, dtype=DT)
    m0 = torch.tensor([1.0, 2.0, 3.0], dtype=DT)
    model = ToyModel(m_past_gain=0.1)
    ref = run_usque(model=model, q_est0=q_est0, P0=P0, observations=y, m_past0=m0, increments=inc, params=PARAMS)
    y_nan = y.clone()
    y_nan[1, 5:9] = math.nan
    h = run_usque(model=model, q_est0=q_est0, P0=P0, observations=y_nan, m_past0=m0, increments=inc, params=PARAMS)
    # the other filters are unaffected
    for name in ("q_est", "P", "y_pred", "m_past"):
        torch.testing.assert_close(getattr(h, name)[[0, 2]], getattr(ref, name)[[0, 2]], rtol=0, atol=0,
                                   equal_nan=True)  # y_pred is NaN at k = 0
    # filter 1 skipped exactly those steps and recorded it
    assert h.updated[1, 5:9].logical_not().all() and h.updated[1, 1:5].all() and h.updated[1, 9:].all()
    assert torch.isnan(h.innovation[1, 5:9]).all() and torch.isfinite(h.y_pred[1, 5:9]).all()
    assert h.rejected.tolist() == [0, 0, 0]
    # a skipped update leaves the prior covariance: it grows instead of shrinking
    assert torch.trace(h.P[1, 6]) > torch.trace(h.P[1, 5])
    # m_past: used before folding, frozen while observations are missing
    tsp = PARAMS.t_span_past
    m = m0[1].item()
    for k in range(1, 41):
        assert h.m_past[1, k].item() == pytest.approx(m, abs=1e-12)
        if not math.isnan(y_nan[1, k].item()):
            m = (tsp * m + y_nan[1, k].item()) / (tsp + 1)
    assert h.m_past_final[1].item() == pytest.approx(m, abs=1e-12)


def test_non_positive_definite_covariance_falls_back_with_a_count():
    q_true, y, q_est0, inc = scenario(B=3, T=20)
    P0 = initial_covariance(10.0, dtype=DT).expand(3, 3, 3).clone()
    P0[1, 2, 2] = -1e-3  # indefinite
    with pytest.warns(SqrtFallbackWarning, match="1 of 3"):
        h = run_usque(model=ToyModel(), q_est0=q_est0, P0=P0, observations=y, m_past0=torch.zeros(3, dtype=DT),
                      increments=inc, params=PARAMS)
    assert h.fallbacks[0] == 0 and h.fallbacks[2] == 0 and h.fallbacks[1] >= 1
    for name in ("q_est", "P", "y_pred", "y_var"):
        assert torch.isfinite(getattr(h, name)[:, 1:]).all(), name
    # the other filters are untouched by the fallback of filter 1
    ref = run_usque(model=ToyModel(), q_est0=q_est0[[0, 2]], P0=P0[[0, 2]], observations=y[[0, 2]],
                    m_past0=torch.zeros(2, dtype=DT), increments=inc[[0, 2]], params=PARAMS)
    torch.testing.assert_close(h.q_est[[0, 2]], ref.q_est, rtol=0, atol=1e-12)


def test_model_variance_is_added_to_the_innovation_variance():
    q_true, y, q_est0, inc = scenario(B=2, T=5)
    P0 = initial_covariance(10.0, dtype=DT)
    with_var = UsqueParams(Q=1e-8, R=1e-4, variance="fast")
    h = run_usque(model=ToyModel(variance=0.05), q_est0=q_est0, P0=P0, observations=y, m_past0=torch.zeros(2, dtype=DT),
                  increments=inc[:, :1].expand(2, 5, 4), params=with_var)
    h0 = run_usque(model=ToyModel(variance=0.05), q_est0=q_est0, P0=P0, observations=y,
                   m_past0=torch.zeros(2, dtype=DT), increments=inc[:, :1].expand(2, 5, 4),
                   params=UsqueParams(Q=1e-8, R=1e-4, variance="none"))
    torch.testing.assert_close(h.model_var[:, 1:], torch.full((2, 5), 0.05, dtype=DT))
    assert torch.isnan(h0.model_var).all()
    # first step: same prior, so Pyy differs by the model variance exactly
    torch.testing.assert_close(h.y_var[:, 1] - h0.y_var[:, 1], torch.full((2,), 0.05, dtype=DT))


def test_non_finite_prediction_is_refused_not_propagated():
    class Broken(ToyModel):
        def _predict(self, q, m_past, variance):
            mean, var = super()._predict(q, m_past, variance)
            mean = mean.clone()
            mean[1] = math.inf  # filter 1 always predicts an infinite magnitude (f_obs = 0)
            return mean, var

    q_true, y, q_est0, inc = scenario(B=2, T=6)
    h = run_usque(model=Broken(), q_est0=q_est0, P0=initial_covariance(10.0, dtype=DT), observations=y,
                  m_past0=torch.zeros(2, dtype=DT), increments=inc, params=PARAMS)
    assert h.rejected.tolist() == [0, 6]
    assert not h.updated[1].any() and h.updated[0, 1:].all()
    assert torch.isfinite(h.q_est).all() and torch.isfinite(h.P).all()


def test_params_from_config():
    """UsqueParams takes the filter section, t_span_past and the variance choice of a whole config."""
    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "boxwing.yaml",
                      ["filter.offset_process_noise=0.002", "model.variance=exact"])
    p = UsqueParams.from_config(cfg)
    assert (p.alpha, p.beta, p.kappa, p.lam, p.grp_a, p.grp_f, p.Q, p.R, p.t_span_past, p.offset_process_noise) == (
        1e-4, 2.0, 0.0, 0.0, 1.0, 4.0, 1e-4, 0.5, 20.0, 0.002)
    assert p.variance == "exact"
    no_var = load_config(Path(__file__).resolve().parents[1] / "configs" / "boxwing.yaml",
                         ["filter.add_model_variance=false", "model.variance=exact"])
    assert UsqueParams.from_config(no_var).variance == "none"
    with pytest.raises(ValueError, match="^variance must be one of none, fast, exact, got 'on'$"):
        UsqueParams(variance="on")
    P0 = initial_covariance(cfg.filter.p0_deg, dtype=DT)
    torch.testing.assert_close(P0, math.radians(10.0) ** 2 * torch.eye(3, dtype=DT))


def test_bad_shapes_are_reported():
    q_true, y, q_est0, inc = scenario(B=2, T=5)
    with pytest.raises(ValueError, match="increments"):
        run_usque(model=ToyModel(), q_est0=q_est0, P0=initial_covariance(10.0, dtype=DT), observations=y,
                  m_past0=torch.zeros(2, dtype=DT), increments=inc[:, :4], params=PARAMS)


def test_usque_is_consistent_nees_and_nis():
    """Initial errors drawn from P0 and matched noise: mean NEES ≈ 3 and mean NIS ≈ 1 (χ² bands)."""
    from lightcurve_gp.attitude.metrics import attitude_error_vector, chi2_band, nees
    from lightcurve_gp.attitude.rotations import rotvec_to_quat

    B, T, R = 300, 60, 1e-3
    g = torch.Generator().manual_seed(3)
    omega = torch.deg2rad(torch.tensor([4.5, -3.0, 7.5], dtype=DT))
    omega = omega * (1 + 0.2 * torch.rand(B, 1, generator=g, dtype=DT))
    delta = increment(omega, 1.0)
    q = euler321_to_quat(torch.deg2rad(torch.randn(B, 3, generator=g, dtype=DT) * 40))
    qs = [q]
    for _ in range(T):
        q = quat_mul(delta, q)
        qs.append(q)
    q_true = torch.stack(qs, 1)
    y = ToyModel()(q=q_true, m_past=torch.zeros(B, T + 1, dtype=DT))[0]
    y = y + math.sqrt(R) * torch.randn(B, T + 1, generator=g, dtype=DT)
    P0 = initial_covariance(3.0, dtype=DT)
    e0 = torch.randn(B, 3, generator=g, dtype=DT) @ torch.linalg.cholesky(P0).T
    q_est0 = quat_mul(quat_conj(rotvec_to_quat(e0)), q_true[:, 0])  # q_true ⊗ q_est0⁻¹ = q(e0)
    h = run_usque(model=ToyModel(), q_est0=q_est0, P0=P0, observations=y, m_past0=torch.zeros(B, dtype=DT),
                  increments=delta[:, None].expand(B, T, 4), params=UsqueParams(Q=1e-12, R=R, variance="none"))
    err = attitude_error_vector(q_true, h.q_est)
    torch.testing.assert_close(err[:, 0], e0, rtol=0, atol=1e-12)
    ne = nees(err, h.P)  # (B, T+1)
    lo, hi = chi2_band(3, B, 0.999)
    for k in (0, 10, 30, 60):
        assert lo < ne[:, k].mean().item() < hi, (k, ne[:, k].mean().item(), (lo, hi))
    assert 0.9 < h.nis()[:, 1:].mean().item() < 1.1


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_usque_on_cuda_matches_cpu():
    q_true, y, q_est0, inc = scenario(B=8, T=30, noise=0.01)
    P0 = initial_covariance(10.0, dtype=DT)
    cpu = run_usque(model=ToyModel(), q_est0=q_est0, P0=P0, observations=y, m_past0=torch.zeros(8, dtype=DT),
                    increments=inc, params=PARAMS)
    dev = torch.device("cuda")
    gpu = run_usque(model=ToyModel().to(dev), q_est0=q_est0.to(dev), P0=P0.to(dev), observations=y.to(dev),
                    m_past0=torch.zeros(8, dtype=DT, device=dev), increments=inc.to(dev), params=PARAMS)
    torch.testing.assert_close(gpu.q_est.cpu(), cpu.q_est, rtol=0, atol=1e-9)
    torch.testing.assert_close(gpu.P.cpu(), cpu.P, rtol=0, atol=1e-12)
