"""The convex inversion's Cramér–Rao bound: the forward-mode Jacobian against central differences, the profiled
bound against the inverse of the full Fisher information, the circular probability against closed forms and a
direct quadrature."""

import math

import pytest
import torch
from scipy import integrate

from lightcurve_gp.inference.convex_bound import (
    MAG_PER_LN,
    circular_probability,
    circular_radius,
    convex_bound,
    magnitude_jacobian,
)
from lightcurve_gp.inference.convex_fit import convex_data, design
from lightcurve_gp.observations.observations import CurveInfo, Observations
from lightcurve_gp.photometry.convex import Scattering, body_vectors, brightness, fibonacci_normals, phase_angle

F64 = torch.float64
SPIN = dict(lam=2.1, beta=-0.6, period_s=5.3 * 3600.0)


def _problem(curves: int = 6, per_curve: int = 25):
    """24 normals, random areas (four of them 0), ``curves`` relative curves over two years."""
    g = torch.Generator().manual_seed(7)
    normals = fibonacci_normals(24)
    areas = torch.rand(24, generator=g, dtype=F64) + 0.2
    areas[[3, 9, 15, 20]] = 0.0
    t, sun, obs = [], [], []
    for c in range(curves):
        t.append(86400.0 * 120 * c + torch.linspace(0.0, 5 * 3600.0, per_curve, dtype=F64))
        s = torch.nn.functional.normalize(torch.randn(3, generator=g, dtype=F64), dim=0)
        o = torch.nn.functional.normalize(s + 0.3 * torch.randn(3, generator=g, dtype=F64), dim=0)
        sun.append(s.expand(per_curve, 3))
        obs.append(o.expand(per_curve, 3))
    t, sun, obs = torch.cat(t), torch.cat(sun), torch.cat(obs)
    full = {k: torch.tensor([v], dtype=F64) for k, v in SPIN.items()}
    full.update(phi0=torch.zeros(1, dtype=F64), t_s=t)
    L = brightness(areas[None], normals, body_vectors(sun, **full), body_vectors(obs, **full), phase_angle(sun, obs),
                   Scattering())[0]
    curve = torch.arange(curves).repeat_interleave(per_curve)
    o = Observations(t=t, mag=-2.5 * torch.log10(L), sigma=torch.full_like(t, 0.02), curve=curve,
                     curves=tuple(CurveInfo(f"c{c}", True) for c in range(curves)), sun=sun, observer=obs,
                     range_m=torch.ones_like(t), epoch="2000-01-01T00:00:00")
    return convex_data(o), normals, areas


def _magnitudes(data, normals, areas, lam, beta, period_s):
    G = design(data, normals, Scattering(), lam=torch.tensor([lam], dtype=F64), beta=torch.tensor([beta], dtype=F64),
               period_s=torch.tensor([period_s], dtype=F64))[0]
    return -2.5 * torch.log10(G @ areas)


def test_magnitude_jacobian_matches_central_differences():
    data, normals, areas = _problem()
    J_spin, J_area = magnitude_jacobian(data, normals, Scattering(), **SPIN, areas=areas)
    steps = (1e-6, 1e-6, 1e-4)                                           # rad, rad, s
    for j, h in enumerate(steps):
        up, down = dict(SPIN), dict(SPIN)
        key = ("lam", "beta", "period_s")[j]
        up[key] += h
        down[key] -= h
        fd = (_magnitudes(data, normals, areas, **up) - _magnitudes(data, normals, areas, **down)) / (2 * h)
        assert fd.abs().max().item() > 1e-3                               # the light curve moves with the spin
        assert (J_spin[:, j] - fd).abs().max().item() < 1e-6 * fd.abs().max().item()
    k, h = 5, 1e-6
    bumped = areas.clone()
    bumped[k] += h
    fd = (_magnitudes(data, normals, bumped, **SPIN) - _magnitudes(data, normals, areas, **SPIN)) / h
    assert torch.allclose(J_area[:, k], fd, atol=1e-6)
    assert MAG_PER_LN == pytest.approx(1.0857362, abs=1e-7)


def test_profiled_bound_is_the_spin_block_of_the_full_inverse():
    data, normals, areas = _problem()
    sigma = 0.02
    bound = convex_bound(data, normals, Scattering(), **SPIN, areas=areas, sigma_mag=sigma)
    assert bound.free_areas == 20 and bound.curves == 6
    # independently: the full Fisher information with the last curve's zero point held (the scale of the areas
    # and a common zero point are one direction), inverted whole
    J_spin, J_area = magnitude_jacobian(data, normals, Scattering(), **SPIN, areas=areas)
    free = areas > 0
    zero_points = torch.nn.functional.one_hot(data.curve, data.curves).to(F64)[:, :-1]
    J = torch.cat([J_spin, J_area[:, free], zero_points], -1) / sigma
    full = torch.linalg.inv(J.T @ J)[:3, :3]
    assert torch.allclose(bound.covariance, full, rtol=1e-6, atol=0.0)
    # the pole's tangent-plane covariance, its rms and its semi-axes
    D = torch.diag(torch.tensor([math.cos(SPIN["beta"]), 1.0], dtype=F64))
    pole = D @ full[:2, :2] @ D * (180 / math.pi) ** 2
    assert torch.allclose(bound.pole_covariance_deg2, pole, rtol=1e-6)
    assert bound.pole_sigma_deg == pytest.approx(math.sqrt(pole[0, 0] + pole[1, 1]), rel=1e-6)
    assert bound.pole_axes_deg[0] ** 2 + bound.pole_axes_deg[1] ** 2 == pytest.approx(bound.pole_sigma_deg ** 2)
    assert bound.period_sigma_s == pytest.approx(math.sqrt(full[2, 2]), rel=1e-6)
    # holding the zero areas free instead (a floor below them) can only widen the bound
    wider = convex_bound(data, normals, Scattering(), **SPIN, areas=areas + 1e-9 * (areas == 0), sigma_mag=sigma,
                         active_floor=1e-12)
    assert wider.free_areas == 24 and wider.pole_sigma_deg >= bound.pole_sigma_deg * (1 - 1e-9)
    # twice the noise, twice the bound
    twice = convex_bound(data, normals, Scattering(), **SPIN, areas=areas, sigma_mag=2 * sigma)
    assert twice.pole_sigma_deg == pytest.approx(2 * bound.pole_sigma_deg, rel=1e-9)


def test_circular_probability_closed_forms_and_quadrature():
    iso = torch.diag(torch.tensor([4.0, 4.0], dtype=F64))
    for r in (0.5, 2.0, 5.0):
        assert circular_probability(iso, r) == pytest.approx(1 - math.exp(-r * r / 8.0), abs=1e-12)
    assert circular_radius(iso, 0.95) == pytest.approx(2.0 * math.sqrt(-2 * math.log(0.05)), rel=1e-9)
    # a thin ellipse approaches the one-dimensional 2·Φ(r/σ) − 1
    thin = torch.diag(torch.tensor([9.0, 1e-4], dtype=F64))
    assert circular_probability(thin, 3.0, directions=20000) == pytest.approx(math.erf(1 / math.sqrt(2)), abs=3e-3)
    # a tilted ellipse against the density integrated over the disc
    cov = torch.tensor([[4.0, 1.5], [1.5, 1.0]], dtype=F64)
    inv, det = torch.linalg.inv(cov).numpy(), float(torch.linalg.det(cov))

    def density(rho, theta):
        x = rho * math.cos(theta), rho * math.sin(theta)
        q = inv[0, 0] * x[0] ** 2 + 2 * inv[0, 1] * x[0] * x[1] + inv[1, 1] * x[1] ** 2
        return rho * math.exp(-0.5 * q) / (2 * math.pi * math.sqrt(det))

    expected = integrate.dblquad(density, 0, 2 * math.pi, 0, 2.5, epsabs=1e-11)[0]
    assert circular_probability(cov, 2.5) == pytest.approx(expected, abs=1e-9)
    assert circular_probability(cov, circular_radius(cov, 0.95)) == pytest.approx(0.95, abs=1e-9)
