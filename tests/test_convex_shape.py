"""The convex inversion's shape: real spherical harmonics against closed forms and by quadrature, the polish of a
smooth Gaussian image (its Jacobian by central differences, its coefficients recovered from noiseless curves), the
magnitude rss against a direct computation, the Minkowski reconstruction of a box and of random areas, and the
refinement's rings of poles."""

import math

import numpy as np
import pytest
import torch

from lightcurve_gp.inference.convex_fit import convex_data, design, magnitude_rss
from lightcurve_gp.inference.convex_polish import PolishResidual, polish
from lightcurve_gp.inference.convex_search import ring_poles
from lightcurve_gp.inference.jacobian import jacobian
from lightcurve_gp.observations.observations import CurveInfo, Observations
from lightcurve_gp.photometry.convex import (
    Scattering,
    body_vectors,
    brightness,
    fibonacci_normals,
    phase_angle,
    pole_vector,
    real_harmonics,
)
from lightcurve_gp.photometry.minkowski import close_areas, minkowski_polytope, polytope

F64 = torch.float64


def test_real_harmonics_closed_forms_and_orthonormal():
    n = fibonacci_normals(5000)
    Y = real_harmonics(n, 6)
    assert Y.shape == (5000, 49)
    x, y, z = n.unbind(-1)
    c1 = math.sqrt(3 / (4 * math.pi))
    assert torch.allclose(Y[:, 0], torch.full_like(x, 0.5 / math.sqrt(math.pi)), atol=1e-12)
    # l = 1, m = −1, 0, 1 (Condon–Shortley phase): −c y, c z, −c x
    assert torch.allclose(Y[:, 1:4], torch.stack([-c1 * y, c1 * z, -c1 * x], -1), atol=1e-12)
    # l = 2, m = 0: √(5/16π) (3z² − 1)
    assert torch.allclose(Y[:, 6], math.sqrt(5 / (16 * math.pi)) * (3 * z * z - 1), atol=1e-12)
    gram = Y.T @ Y * (4 * math.pi / n.shape[0])                 # the Fibonacci points as equal-area quadrature
    assert (gram - torch.eye(49, dtype=F64)).abs().max().item() < 2e-3


def _smooth_problem():
    """A degree-2 smooth Gaussian image on 80 normals seen in 10 relative curves of 30 samples (noiseless)."""
    g = torch.Generator().manual_seed(4)
    normals = fibonacci_normals(80)
    basis = real_harmonics(normals, 2)
    coef = torch.tensor([0.0, 0.1, 0.4, -0.2, 0.3, -0.25, 0.2, 0.15, 0.35], dtype=F64)
    areas = torch.exp(basis @ coef)
    spin = dict(lam=torch.tensor([1.2], dtype=F64), beta=torch.tensor([0.5], dtype=F64),
                period_s=torch.tensor([6.1 * 3600.0], dtype=F64))
    t, sun, obs = [], [], []
    for c in range(10):
        t.append(86400.0 * 40 * c + torch.linspace(0.0, 5 * 3600.0, 30, dtype=F64))
        s = torch.nn.functional.normalize(torch.randn(3, generator=g, dtype=F64), dim=0)
        o = torch.nn.functional.normalize(s + 0.3 * torch.randn(3, generator=g, dtype=F64), dim=0)
        sun.append(s.expand(30, 3))
        obs.append(o.expand(30, 3))
    t, sun, obs = torch.cat(t), torch.cat(sun), torch.cat(obs)
    full = dict(**spin, phi0=torch.zeros(1, dtype=F64), t_s=t)
    L = brightness(areas[None], normals, body_vectors(sun, **full), body_vectors(obs, **full), phase_angle(sun, obs),
                   Scattering())[0]
    curve = torch.arange(10).repeat_interleave(30)
    o = Observations(t=t, mag=-2.5 * torch.log10(L) + 0.3 * curve, sigma=torch.full_like(t, 0.01), curve=curve,
                     curves=tuple(CurveInfo(f"c{c}", True) for c in range(10)), sun=sun, observer=obs,
                     range_m=torch.ones_like(t), epoch="2000-01-01T00:00:00")
    return convex_data(o), normals, basis, coef, areas, spin


def test_harmonic_polish_jacobian_matches_central_differences():
    data, normals, basis, coef, _, spin = _smooth_problem()
    res = PolishResidual(data, normals, Scattering(), spin["period_s"].repeat(2), 0.01, 0.1, smoothness=0.3,
                         basis=basis)
    x = torch.cat([torch.tensor([[1.0, 0.4, 0.1], [2.0, -0.3, -0.2]], dtype=F64), torch.stack([coef, -coef])], -1)
    rows = torch.arange(2)
    r1, J1 = res.linearize(x, rows)
    r2, J2 = jacobian(res, x, rows, method="central", step=1e-6)
    assert J1.shape == (2, r1.shape[1], 3 + 9)
    assert torch.allclose(r1, r2, atol=1e-12)
    assert (J1 - J2).abs().max().item() < 1e-6 * J2.abs().max().item()


def test_harmonic_polish_recovers_a_smooth_shape_and_spin():
    data, normals, basis, coef, areas, spin = _smooth_problem()
    start = dict(lam=spin["lam"] + 0.03, beta=spin["beta"] - 0.03, period_s=spin["period_s"] * (1 + 1e-6))
    p = polish(data, normals, Scattering(), **start, areas=torch.ones(1, 80, dtype=F64), iterations=60,
               closure=0.0, basis=basis, area_prior_std=100.0)
    assert p.rms.item() < 1e-6
    assert abs(p.lam.item() - spin["lam"].item()) < 1e-5 and abs(p.beta.item() - spin["beta"].item()) < 1e-5
    assert torch.allclose(p.areas[0], areas / areas.sum(), rtol=1e-4)


def test_magnitude_rss_profiles_each_curves_zero_point():
    data, normals, _, _, areas, spin = _smooth_problem()
    assert magnitude_rss(data, normals, Scattering(), **spin, areas=areas[None]).item() < 1e-20
    # doubled brightness is a zero point (no cost); a wrong period costs what a direct computation says
    assert magnitude_rss(data, normals, Scattering(), **spin, areas=2 * areas[None]).item() < 1e-20
    wrong = dict(spin, period_s=spin["period_s"] * 1.001)
    L = (design(data, normals, Scattering(), **wrong) * areas).sum(-1)[0].numpy()
    d = -2.5 * np.log10(data.y.numpy()) + 2.5 * np.log10(L)
    curve = data.curve.numpy()
    expected = sum(((d[curve == c] - d[curve == c].mean()) ** 2).sum() for c in range(10))
    got = magnitude_rss(data, normals, Scattering(), **wrong, areas=areas[None]).item()
    assert got > 1e-3 and got == pytest.approx(expected, rel=1e-10)


def test_minkowski_gives_back_a_box():
    axes = np.vstack([np.eye(3), -np.eye(3)])
    diagonals = np.array([[i, j, k] for i in (1, -1) for j in (1, -1) for k in (1, -1)]) / math.sqrt(3)
    normals = np.vstack([axes, diagonals])                      # eight more normals with zero area
    areas = np.concatenate([[15.0, 10.0, 6.0, 15.0, 10.0, 6.0], np.zeros(8)])   # a 2 × 3 × 5 box
    p = minkowski_polytope(normals, areas)
    dims = p.support[:3] + p.support[3:6]
    assert np.allclose(dims, [2.0, 3.0, 5.0], atol=1e-3)
    assert p.volume == pytest.approx(30.0, rel=1e-3)
    assert np.allclose(p.facet_areas, areas, atol=1e-3)
    assert np.allclose(p.vertices.mean(0), 0.0, atol=1e-9)     # centred


def test_minkowski_matches_random_closed_areas_and_refuses_bad_input():
    normals = fibonacci_normals(60).numpy()
    areas = np.random.default_rng(1).uniform(0.2, 1.0, 60)
    closed = close_areas(normals, areas)
    assert np.abs(closed @ normals).max() < 1e-2 * np.abs(areas @ normals).max()
    p = minkowski_polytope(normals, areas)
    assert np.abs(p.facet_areas - closed).max() < 1e-3 * closed.max()
    # the triangles are outward: the divergence theorem gives the volume back
    tri = p.vertices[p.triangles]
    assert np.einsum("ti,ti->t", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6 == pytest.approx(p.volume)
    with pytest.raises(ValueError, match="areas must be 60 non-negative numbers"):
        minkowski_polytope(normals, -areas)
    with pytest.raises(ValueError, match="every support distance must be > 0"):
        polytope(normals, np.zeros(60))


@pytest.mark.parametrize("beta_deg", [30.0, 90.0, -89.9])
def test_ring_poles_lie_at_the_radius_evenly(beta_deg):
    lam, beta = ring_poles(math.radians(200.0), math.radians(beta_deg), math.radians(7.0), 4)
    centre = pole_vector(torch.tensor(math.radians(200.0), dtype=F64), torch.tensor(math.radians(beta_deg), dtype=F64))
    v = pole_vector(lam, beta)
    assert torch.allclose(torch.rad2deg(torch.arccos((v @ centre).clamp(-1, 1))), torch.full((4,), 7.0, dtype=F64))
    # four evenly in azimuth: opposite ones 14° apart, neighbours at the spherical right-angle distance
    assert math.degrees(math.acos(float(v[0] @ v[2]))) == pytest.approx(14.0)
    neighbour = math.degrees(math.acos(math.cos(math.radians(7.0)) ** 2))
    assert math.degrees(math.acos(float(v[0] @ v[1]))) == pytest.approx(neighbour)
