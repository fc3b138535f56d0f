"""Error metrics: Euler errors of hand-built rotations, RMSE windows, NEES/NIS and the chi-square band."""

import math

import pytest
import torch

from lightcurve_gp.attitude.metrics import (
    attitude_error_vector,
    attitude_errors_deg,
    chi2_band,
    lightcurve_rmse,
    model_error_on_trajectory,
    nees,
    nis,
    rmse_over_window,
    total_angle_deg,
)
from lightcurve_gp.attitude.rotations import euler321_to_quat, grp_to_quat, identity_quat, quat_mul, quat_normalize

from helpers import ToyModel

DT = torch.float64


def euler_deg(*angles):
    return euler321_to_quat(torch.deg2rad(torch.tensor(angles, dtype=DT)))


def random_quats(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    return quat_normalize(torch.randn(n, 4, generator=g, dtype=DT))


@pytest.mark.parametrize("angles", [(10.0, 0.0, 0.0), (0.0, -5.0, 0.0), (0.0, 0.0, 7.0), (-10.0, 5.0, -10.0)])
def test_euler_errors_of_hand_built_rotations(angles):
    expected = torch.tensor(angles, dtype=DT)
    # against the identity
    err = attitude_errors_deg(euler_deg(*angles), identity_quat(dtype=DT))
    assert torch.allclose(err, expected, atol=1e-10)
    # q_true = q(error) ⊗ q_est for arbitrary estimates gives the same error (q_err = q_true ⊗ q_est⁻¹)
    q_est = random_quats(16)
    q_true = quat_mul(euler_deg(*angles), q_est)
    err = attitude_errors_deg(q_true, q_est)
    assert torch.allclose(err, expected.expand(16, 3), atol=1e-10)


def test_pure_axis_rotations_are_the_right_euler_axes():
    # A(q) maps inertial to body: a yaw of φ is a rotation about z, so A = R_z(φ) with A12 = sin φ
    q = euler_deg(10.0, 0.0, 0.0)
    assert torch.allclose(q, torch.tensor([0, 0, math.sin(math.radians(5)), math.cos(math.radians(5))], dtype=DT))
    q = euler_deg(0.0, 0.0, 7.0)
    assert torch.allclose(q, torch.tensor([math.sin(math.radians(3.5)), 0, 0, math.cos(math.radians(3.5))], dtype=DT))


def test_identical_and_sign_flipped_attitudes_have_zero_error():
    q = random_quats(32, seed=1)
    assert torch.allclose(attitude_errors_deg(q, q), torch.zeros(32, 3, dtype=DT), atol=1e-10)
    assert torch.allclose(attitude_errors_deg(q, -q), torch.zeros(32, 3, dtype=DT), atol=1e-10)
    assert torch.allclose(attitude_errors_deg(-q, q), torch.zeros(32, 3, dtype=DT), atol=1e-10)
    assert torch.allclose(total_angle_deg(q, -q), torch.zeros(32, dtype=DT), atol=1e-6)


def test_total_angle():
    q_est = random_quats(8, seed=2)
    for angle in (0.5, 30.0, 179.0):
        axis = torch.tensor([1.0, 2.0, -2.0], dtype=DT) / 3.0
        half = math.radians(angle) / 2
        dq = torch.cat([axis * math.sin(half), torch.tensor([math.cos(half)], dtype=DT)])
        got = total_angle_deg(quat_mul(dq, q_est), q_est)
        assert torch.allclose(got, torch.full((8,), angle, dtype=DT), atol=1e-9)


def test_grp_error_is_the_filter_state_error():
    q_est = random_quats(10, seed=3)
    g = torch.Generator().manual_seed(4)
    p = 0.2 * torch.randn(10, 3, generator=g, dtype=DT)
    q_true = quat_mul(grp_to_quat(p), q_est)
    for qt in (q_true, -q_true):
        assert torch.allclose(attitude_error_vector(qt, q_est, "grp"), p, atol=1e-12)
    # the rotation vector agrees with the GRP (f = 2(a+1)) to first order
    small = 1e-4 * p
    q_true = quat_mul(grp_to_quat(small), q_est)
    assert torch.allclose(attitude_error_vector(q_true, q_est, "rotvec"), small, rtol=1e-6, atol=1e-15)


def test_rmse_over_inclusive_window_ignores_nan():
    times = torch.arange(11, dtype=DT)
    values = torch.stack([times, -2.0 * times])
    got = rmse_over_window(values, times, window=(2.0, 4.0))
    ref = math.sqrt((4 + 9 + 16) / 3)
    assert torch.allclose(got, torch.tensor([ref, 2 * ref], dtype=DT))
    values[0, 3] = float("nan")
    got = rmse_over_window(values, times, window=(2.0, 4.0))
    assert got[0].item() == pytest.approx(math.sqrt((4 + 16) / 2))
    # nothing finite in the window → NaN
    values[0, 2:5] = float("nan")
    assert torch.isnan(rmse_over_window(values, times, window=(2.0, 4.0))[0])
    with pytest.raises(ValueError):
        rmse_over_window(values, times[:-1])
    with pytest.raises(ValueError):
        rmse_over_window(values, times, window=(5.0, 1.0))


def test_lightcurve_and_euler_rmse():
    times = torch.arange(0.0, 601.0, dtype=DT)
    ref = torch.sin(times / 50)
    pred = ref + 0.3
    assert lightcurve_rmse(pred, ref, times).item() == pytest.approx(0.3)
    q_est = random_quats(601, seed=5)
    q_true = quat_mul(euler_deg(2.0, -1.0, 0.5), q_est)
    err = attitude_errors_deg(q_true, q_est)  # (T, 3)
    got = rmse_over_window(err.T, times, (400.0, 600.0))
    assert torch.allclose(got, torch.tensor([2.0, 1.0, 0.5], dtype=DT), atol=1e-9)


def test_nees_of_consistent_samples_averages_dof():
    g = torch.Generator().manual_seed(6)
    n_samples = 4000
    a = torch.randn(n_samples, 3, 3, generator=g, dtype=DT)
    P = a @ a.transpose(-1, -2) + 0.1 * torch.eye(3, dtype=DT)
    e = (torch.linalg.cholesky(P) @ torch.randn(n_samples, 3, 1, generator=g, dtype=DT)).squeeze(-1)
    mean = nees(e, P).mean().item()
    lo, hi = chi2_band(3, n_samples, 0.999)
    assert lo < mean < hi
    # an overconfident covariance is caught
    assert nees(e, 0.5 * P).mean().item() > hi


def test_nis_scalar_and_vector():
    nu = torch.tensor([1.0, -2.0], dtype=DT)
    S = torch.tensor([2.0, 4.0], dtype=DT)
    assert torch.allclose(nis(nu, S), torch.tensor([0.5, 1.0], dtype=DT))
    nu = torch.tensor([[1.0, 2.0]], dtype=DT)
    S = torch.tensor([[[2.0, 0.0], [0.0, 4.0]]], dtype=DT)
    assert torch.allclose(nis(nu, S), torch.tensor([1.5], dtype=DT))


def test_chi2_band():
    for dof in (1, 3):
        for n in (1, 10, 600):
            lo, hi = chi2_band(dof, n)
            assert lo < dof < hi
    lo1, hi1 = chi2_band(3, 10)
    lo2, hi2 = chi2_band(3, 1000)
    assert hi2 - lo2 < hi1 - lo1
    # one sample: the usual chi-square quantiles
    lo, hi = chi2_band(1, 1, 0.95)
    assert lo == pytest.approx(0.000982, rel=1e-3) and hi == pytest.approx(5.0239, rel=1e-4)
    with pytest.raises(ValueError):
        chi2_band(0, 10)


def test_model_error_on_trajectory_of_a_shifted_model():
    """A model that is the truth shifted by c has mean error c, no spread about it, RMS |c|; its std is √variance."""
    q = quat_normalize(random_quats(50, seed=4))
    model = ToyModel(variance=0.04)
    m_true = model(q=q, m_past=torch.zeros(50, dtype=torch.float64))[0] - 0.3
    err = model_error_on_trajectory(model, q=q, m_true=m_true, m_past=torch.zeros(50, dtype=torch.float64))
    assert err["mean_error"] == pytest.approx(0.3, abs=1e-12)
    assert err["rms_about_mean"] == pytest.approx(0.0, abs=1e-12)
    assert err["rms"] == pytest.approx(0.3, abs=1e-12)
    assert err["mean_predictive_std"] == pytest.approx(0.2, abs=1e-12)


def test_model_error_on_trajectory_spread_is_the_std_of_the_error():
    q = quat_normalize(random_quats(64, seed=5))
    model = ToyModel(variance=0.0)
    noise = torch.linspace(-1.0, 1.0, 64, dtype=torch.float64)
    m_true = model(q=q, m_past=torch.zeros(64, dtype=torch.float64))[0] + noise
    err = model_error_on_trajectory(model, q=q, m_true=m_true, m_past=torch.zeros(64, dtype=torch.float64))
    assert err["mean_error"] == pytest.approx(0.0, abs=1e-12)
    assert err["rms_about_mean"] == pytest.approx(float(noise.std(unbiased=False)), rel=1e-12)
    assert err["rms"] == pytest.approx(err["rms_about_mean"], rel=1e-12)
