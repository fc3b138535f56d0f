"""The unscented transform and the reference UKF: sigma-point weights (the paper's numbers, filterpy's), square
roots with their counted fallback, and the generic UKF against a Kalman filter and filterpy step by step."""

import numpy as np
import pytest
import torch
from reference_ukf import sigma_points, ukf_predict, ukf_update

from lightcurve_gp.filters.unscented import SqrtFallbackWarning, matrix_sqrt, unscented_weights

from helpers import DT

# ----------------------------------------------------------------------------------------------- weights

def test_lambda_zero_weights_are_the_papers_numbers():
    lam, wm, wc = unscented_weights(3, 1e-4, 2.0, 0.0, lam=0.0, dtype=DT)
    assert lam == 0.0
    assert wm[0].item() == 0.0
    assert wc[0].item() == pytest.approx(3.0 - 1e-8, abs=1e-15)
    assert torch.allclose(wm[1:], torch.full((6,), 1 / 6, dtype=DT), atol=1e-15)
    assert torch.equal(wm[1:], wc[1:])
    assert wm.sum().item() == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize("n, alpha, beta, kappa", [(3, 1e-4, 2.0, 0.0), (2, 0.3, 2.0, 1.0), (4, 1.0, 0.0, -1.0)])
def test_derived_lambda_matches_formula_and_filterpy(n, alpha, beta, kappa):
    from filterpy.kalman import MerweScaledSigmaPoints

    lam, wm, wc = unscented_weights(n, alpha, beta, kappa, dtype=DT)
    assert lam == pytest.approx(alpha ** 2 * (n + kappa) - n, rel=1e-15, abs=1e-15)
    pts = MerweScaledSigmaPoints(n, alpha, beta, kappa)
    np.testing.assert_allclose(wm.numpy(), pts.Wm, rtol=1e-12)
    np.testing.assert_allclose(wc.numpy(), pts.Wc, rtol=1e-12)


def test_nonpositive_spread_is_rejected():
    with pytest.raises(ValueError, match="n \\+ lambda"):
        unscented_weights(3, 1e-4, 2.0, 0.0, lam=-3.0)


# ----------------------------------------------------------------------------------------------- square roots

def test_sigma_points_reproduce_mean_and_covariance():
    g = torch.Generator().manual_seed(0)
    A = torch.randn(5, 3, 3, generator=g, dtype=DT)
    P = A @ A.transpose(-1, -2) + 0.1 * torch.eye(3, dtype=DT)
    x = torch.randn(5, 3, generator=g, dtype=DT)
    lam, wm, wc = unscented_weights(3, 0.5, 2.0, 0.0, dtype=DT)
    sig, fb = sigma_points(x, P, lam)
    assert sig.shape == (5, 7, 3) and fb.tolist() == [0] * 5
    mean = torch.einsum("s,bsn->bn", wm, sig)
    d = sig - mean[:, None]
    cov = torch.einsum("s,bsi,bsj->bij", wc, d, d)
    torch.testing.assert_close(mean, x, rtol=0, atol=1e-12)
    torch.testing.assert_close(cov, P, rtol=0, atol=1e-12)


def test_sqrt_fallback_is_per_filter_counted_and_warned():
    P = torch.stack([torch.eye(3, dtype=DT), torch.diag(torch.tensor([1.0, 0.5, -0.2], dtype=DT)),
                     2 * torch.eye(3, dtype=DT)])
    S, failed = matrix_sqrt(P)
    assert failed.tolist() == [False, True, False]
    torch.testing.assert_close(S[0], torch.eye(3, dtype=DT))  # untouched Cholesky factors
    torch.testing.assert_close(S[1] @ S[1].T, torch.diag(torch.tensor([1.0, 0.5, 0.0], dtype=DT)), rtol=0, atol=1e-14)
    with pytest.warns(SqrtFallbackWarning, match="1 of 3"):
        sig, fb = sigma_points(torch.zeros(3, 3, dtype=DT), P, 0.0)
    assert fb.tolist() == [0, 1, 0]
    assert torch.isfinite(sig).all()


# ----------------------------------------------------------------------------------------------- generic UKF

@pytest.mark.parametrize("alpha, beta, kappa, lam", [(1e-4, 2.0, 0.0, 0.0), (0.5, 2.0, 1.0, None),
                                                     (1.0, 0.0, 0.0, None), (1e-2, 2.0, 0.0, 1.0)])
def test_generic_ukf_equals_kalman_filter_on_a_linear_system(alpha, beta, kappa, lam):
    """Constant velocity, position measured: the UKF is exact for linear-Gaussian systems, whatever α, λ."""
    dt, B, steps = 0.5, 3, 50
    F = torch.tensor([[1.0, dt], [0.0, 1.0]], dtype=DT)
    H = torch.tensor([[1.0, 0.0]], dtype=DT)
    Q = 0.05 * torch.tensor([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]], dtype=DT)
    R = torch.tensor([[0.25]], dtype=DT)
    g = torch.Generator().manual_seed(1)
    x_kf = torch.randn(B, 2, generator=g, dtype=DT)
    P_kf = torch.diag(torch.tensor([2.0, 0.5], dtype=DT)).expand(B, 2, 2).clone()
    x_u, P_u = x_kf.clone(), P_kf.clone()
    w = unscented_weights(2, alpha, beta, kappa, lam, dtype=DT)
    for _ in range(steps):
        z = torch.randn(B, 1, generator=g, dtype=DT) * 3.0
        # hand-written Kalman filter
        x_kf = x_kf @ F.T
        P_kf = F @ P_kf @ F.T + Q
        S = H @ P_kf @ H.T + R
        K = P_kf @ H.T @ torch.linalg.inv(S)
        x_kf = x_kf + ((z - x_kf @ H.T).unsqueeze(-1) * K.transpose(-1, -2)).sum(-2)
        P_kf = (torch.eye(2, dtype=DT) - K @ H) @ P_kf
        # unscented
        pred = ukf_predict(x_u, P_u, lambda s: s @ F.T, Q, w)
        upd = ukf_update(pred.x, pred.P, z, lambda s: s @ H.T, R, w)
        x_u, P_u = upd.x, upd.P
        torch.testing.assert_close(x_u, x_kf, rtol=1e-10, atol=1e-10)
        torch.testing.assert_close(P_u, P_kf, rtol=1e-10, atol=1e-10)


def test_generic_ukf_matches_filterpy_step_by_step():
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    n, dt, alpha, beta, kappa = 2, 0.1, 0.3, 2.0, 1.0

    def fx_np(x, dt):
        return np.array([x[0] + dt * x[1], x[1] - dt * 2.0 * np.sin(x[0])])

    def hx_np(x):
        return np.array([np.sqrt(1.0 + x[0] ** 2), x[0] * x[1]])

    def fx_t(s):
        return torch.stack([s[..., 0] + dt * s[..., 1], s[..., 1] - dt * 2.0 * torch.sin(s[..., 0])], -1)

    def hx_t(s):
        return torch.stack([torch.sqrt(1.0 + s[..., 0] ** 2), s[..., 0] * s[..., 1]], -1)

    Q = np.array([[1e-4, 0.0], [0.0, 1e-3]])
    R = np.diag([0.01, 0.02])
    x0, P0 = np.array([0.8, -0.3]), np.diag([0.2, 0.1])
    ukf = UnscentedKalmanFilter(n, 2, dt, hx_np, fx_np, MerweScaledSigmaPoints(n, alpha, beta, kappa))
    ukf.x, ukf.P, ukf.Q, ukf.R = x0.copy(), P0.copy(), Q, R
    w = unscented_weights(n, alpha, beta, kappa, dtype=DT)
    x, P = torch.tensor(x0)[None], torch.tensor(P0)[None]
    rng = np.random.default_rng(2)
    truth = np.array([1.0, 0.0])
    for _ in range(40):
        truth = fx_np(truth, dt)
        z = hx_np(truth) + rng.normal(0, [0.1, 0.14])
        ukf.predict()
        pred = ukf_predict(x, P, fx_t, torch.tensor(Q), w)
        np.testing.assert_allclose(pred.x[0].numpy(), ukf.x, rtol=0, atol=1e-8)
        np.testing.assert_allclose(pred.P[0].numpy(), ukf.P, rtol=0, atol=1e-8)
        ukf.update(z)
        upd = ukf_update(pred.x, pred.P, torch.tensor(z)[None], hx_t, torch.tensor(R), w)
        np.testing.assert_allclose(upd.x[0].numpy(), ukf.x, rtol=0, atol=1e-8)
        np.testing.assert_allclose(upd.P[0].numpy(), ukf.P, rtol=0, atol=1e-8)
        x, P = upd.x, upd.P
