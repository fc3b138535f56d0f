"""Per-sample measurement noise ``R (B, T+1)`` of :func:`lightcurve_gp.filters.usque.run_usque` (a file's
``mag_err²``)."""

import math

import pytest
import torch

from lightcurve_gp.filters.usque import UsqueParams, initial_covariance, run_usque

from helpers import DT, ToyModel, scenario


def run(y, q_est0, increments, R):
    return run_usque(model=ToyModel(), q_est0=q_est0, P0=initial_covariance(10.0, dtype=DT), observations=y,
                     m_past0=y[:, 0], increments=increments, params=UsqueParams(Q=1e-6, R=R, variance="none"))


def test_a_constant_per_sample_noise_equals_the_per_filter_noise_bitwise():
    _, y, q_est0, increments = scenario(B=3, T=60, noise=0.3)
    R = torch.tensor([0.09, 0.2, 0.5], dtype=DT)
    per_filter = run(y, q_est0, increments, R)
    per_sample = run(y, q_est0, increments, R[:, None].expand(3, 61).clone())
    assert torch.equal(per_filter.q_est, per_sample.q_est)
    assert torch.equal(per_filter.y_var[:, 1:], per_sample.y_var[:, 1:])  # column 0: NaN, no prediction


def test_step_k_uses_column_k():
    _, y, q_est0, increments = scenario(B=2, T=40, noise=0.3)
    R = torch.full((2, 41), 0.09, dtype=DT)
    R[:, 17] = 0.81
    hist = run(y, q_est0, increments, R)
    spread = hist.y_var - R  # Pyy - R: the sigma points' spread, which does not depend on R at this step
    assert float(spread[:, 17].min()) > 0 and float(spread[:, 17].max()) < 0.05
    assert torch.allclose(hist.y_var[:, 17] - spread[:, 17], torch.full((2,), 0.81, dtype=DT))


def test_a_huge_noise_at_a_step_is_a_missing_observation_there():
    _, y, q_est0, increments = scenario(B=2, T=50, noise=0.3)
    skipped = [5, 6, 30]
    R = torch.full((2, 51), 0.09, dtype=DT)
    R[:, skipped] = 1e30
    y_missing = y.clone()
    y_missing[:, skipped] = math.nan
    huge = run(y, q_est0, increments, R)
    missing = run(y_missing, q_est0, increments, torch.full((2, 51), 0.09, dtype=DT))
    # m_past differs (a real observation is folded in) but ToyModel does not use it
    assert torch.allclose(huge.q_est, missing.q_est, atol=1e-12)
    assert torch.allclose(huge.P, missing.P, rtol=1e-9, atol=1e-20)


def test_a_noise_of_the_wrong_shape_is_refused():
    _, y, q_est0, increments = scenario(B=2, T=10)
    with pytest.raises(ValueError, match=r"R must be a scalar, \(B=2,\) or \(B=2, T\+1=11\), got \(2, 10\)"):
        run(y, q_est0, increments, torch.ones(2, 10, dtype=DT))
