"""Training attitudes: the paper's icosphere grid and uniform random / Sobol' attitudes on SO(3)."""

import math

import numpy as np
import pytest
import torch
from scipy.stats import kstest

from lightcurve_gp.attitude.rotations import attitude_matrix
from lightcurve_gp.attitude.sampling import grid_attitudes, icosphere_axes, random_attitudes, sobol_attitudes

F64 = torch.float64


def rotation_angle(q: torch.Tensor) -> np.ndarray:
    """Φ ∈ [0, π] of unit quaternions."""
    return (2.0 * torch.atan2(torch.linalg.vector_norm(q[:, :3], dim=-1), q[:, 3].abs())).numpy()


def angle_cdf(phi):
    """CDF of the rotation angle of a uniform rotation: (Φ − sin Φ)/π on [0, π]."""
    return (phi - np.sin(phi)) / np.pi


def test_icosphere_axes_are_the_papers_642_unit_vectors():
    axes = icosphere_axes(3, dtype=F64)
    assert axes.shape == (642, 3) and axes.dtype == F64
    torch.testing.assert_close(torch.linalg.vector_norm(axes, dim=-1), torch.ones(642, dtype=F64), rtol=0, atol=1e-15)
    assert torch.unique(axes.round(decimals=9), dim=0).shape[0] == 642  # distinct
    torch.testing.assert_close(axes.mean(0), torch.zeros(3, dtype=F64), rtol=0, atol=1e-12)  # symmetric
    assert icosphere_axes(0).shape == (12, 3)
    assert icosphere_axes(1, dtype=torch.float32).dtype == torch.float32


def test_grid_is_the_papers_3852_unit_quaternions_in_axis_major_order():
    axes = icosphere_axes(3, dtype=F64)
    q = grid_attitudes(axes, 60)
    assert q.shape == (3852, 4) and q.dtype == F64
    torch.testing.assert_close(torch.linalg.vector_norm(q, dim=-1), torch.ones(3852, dtype=F64), rtol=0, atol=1e-15)
    grid = q.reshape(642, 6, 4)
    # Φ = 0 entries are exactly the identity
    assert torch.equal(grid[:, 0], torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=F64).expand(642, 4))
    # row i·6 + j: axis i, Φ = 60 j degrees
    phi = torch.deg2rad(torch.arange(6, dtype=F64) * 60)
    torch.testing.assert_close(grid[:, :, 3], torch.cos(phi / 2).expand(642, 6), rtol=0, atol=1e-15)
    torch.testing.assert_close(grid[:, 1:, :3] / torch.sin(phi[1:] / 2)[:, None], axes[:, None].expand(642, 5, 3),
                               rtol=0, atol=1e-14)
    # only the Φ = 0 rows repeat
    assert torch.unique(q.round(decimals=9), dim=0).shape[0] == 642 * 5 + 1


@pytest.mark.parametrize("step, n_phi", [(60, 6), (60.0, 6), (45, 8), (90, 4), (70, 6), (360, 1), (0.5, 720)])
def test_grid_angle_count(step, n_phi):
    axes = icosphere_axes(0)
    assert grid_attitudes(axes, step).shape == (12 * n_phi, 4)


def test_grid_follows_the_axes_dtype_and_rejects_bad_steps():
    axes = icosphere_axes(1, dtype=torch.float32)
    assert grid_attitudes(axes, 60).dtype == torch.float32
    for bad in (0, -10, 400, math.nan):
        with pytest.raises(ValueError, match="phi_step_deg must be in"):
            grid_attitudes(axes, bad)
    with pytest.raises(ValueError, match=r"axes must be a \(M, 3\) tensor"):
        grid_attitudes(torch.zeros(5, 4), 60)


@pytest.mark.parametrize("sampler", [random_attitudes, sobol_attitudes])
def test_samplers_give_unit_quaternions_reproducibly(sampler):
    q = sampler(1000, seed=7, dtype=F64)
    assert q.shape == (1000, 4) and q.dtype == F64
    torch.testing.assert_close(torch.linalg.vector_norm(q, dim=-1), torch.ones(1000, dtype=F64), rtol=0, atol=1e-15)
    assert torch.equal(q, sampler(1000, seed=7, dtype=F64))
    assert not torch.allclose(q, sampler(1000, seed=8, dtype=F64))
    assert sampler(10, seed=7, dtype=torch.float32).dtype == torch.float32
    assert sampler(0, seed=7).shape == (0, 4)
    with pytest.raises(ValueError, match="n must be an integer >= 0"):
        sampler(-1, seed=7)


@pytest.mark.parametrize("sampler, n", [(random_attitudes, 40000), (sobol_attitudes, 2**14)])
def test_samplers_are_uniform_on_so3(sampler, n):
    q = sampler(n, seed=11, dtype=F64)
    tol = 4.0 / math.sqrt(n)
    # E[q_i²] = 1/4 and E[q] = 0 for the uniform (Haar) distribution on the unit 3-sphere
    torch.testing.assert_close((q * q).mean(0), torch.full((4,), 0.25, dtype=F64), rtol=0, atol=tol)
    torch.testing.assert_close(q.mean(0), torch.zeros(4, dtype=F64), rtol=0, atol=tol)
    # the rotated inertial x axis is uniform on the sphere: mean ≈ 0
    x_body = attitude_matrix(q)[:, :, 0]
    torch.testing.assert_close(x_body.mean(0), torch.zeros(3, dtype=F64), rtol=0, atol=tol)
    # the rotation angle follows the Haar CDF (Φ − sin Φ)/π
    result = kstest(rotation_angle(q), angle_cdf)
    if sampler is random_attitudes:
        assert result.pvalue > 0.01
    else:  # low-discrepancy: far closer than a random sample of this size would be
        assert result.statistic < 0.005


def test_ks_test_detects_a_non_uniform_sample():
    """The KS check has power: normalised Gaussian 4-vectors with one dominant component are not uniform."""
    g = torch.Generator().manual_seed(0)
    q = torch.randn(5000, 4, generator=g, dtype=F64) * torch.tensor([1.0, 1.0, 1.0, 1.5], dtype=F64)
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    assert kstest(rotation_angle(q), angle_cdf).pvalue < 1e-6
