"""The convex model's satellite law (Ashikhmin–Shirley bases): a sphere's closed forms, the box-wing's renderer
reproduced by its Gaussian image, the closed-form polish Jacobian, the areas of a box recovered by the non-negative
fit, the search normals with the equatorial ring, and the ``convex:`` keys that select it."""

import math

import numpy as np
import pytest
import torch
from scipy.integrate import quad

from lightcurve_gp.attitude.rotations import matrix_to_quat
from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.commands.invert_convex import settings_from_config
from lightcurve_gp.config.load import load_config
from lightcurve_gp.config.schema import ConfigError
from lightcurve_gp.inference.convex_fit import convex_data, design, fit_areas, relative_residuals
from lightcurve_gp.inference.convex_polish import PolishResidual
from lightcurve_gp.inference.convex_search import search_normals
from lightcurve_gp.inference.jacobian import jacobian
from lightcurve_gp.observations.observations import CurveInfo, Observations
from lightcurve_gp.photometry.convex import (
    SatelliteScattering,
    area_normals,
    body_vectors,
    brightness,
    facet_brightness,
    fibonacci_normals,
    phase_angle,
    pole_vector,
)
from lightcurve_gp.photometry.render import Scene

F64 = torch.float64
CONVEX = "configs/convex.yaml"


def _sphere(law: SatelliteScattering, alpha: float, k: int = 40_000) -> tuple[float, ...]:
    normals = fibonacci_normals(k)
    sun = torch.tensor([[[1.0, 0.0, 0.0]]], dtype=F64)
    obs = torch.tensor([[[math.cos(alpha), math.sin(alpha), 0.0]]], dtype=F64)
    G = facet_brightness(normals, sun, obs, phase_angle(sun[0], obs[0]), law)[0, 0]
    return tuple(float(part.sum()) * 4 * math.pi / k for part in G.reshape(law.bases, k))


def test_sphere_at_opposition_matches_closed_forms():
    """At α = 0 (μ = μ0 = ν) a unit sphere's diffuse basis is 2π·28/(23π) ∫ (1 − (1 − μ/2)^5)² μ² dμ and its lobe
    n basis (n + 1)/(8π) F0 · 2π ∫ μ^(n+1) dμ = F0 (n + 1)/(4 (n + 2))."""
    law = SatelliteScattering(f0=0.3, exponents=(10.0, 40.0))
    diffuse, lobe10, lobe40 = _sphere(law, 0.0)
    integral = quad(lambda m: (1 - (1 - m / 2) ** 5) ** 2 * m * m, 0.0, 1.0)[0]
    assert diffuse == pytest.approx(2 * 28 / 23 * integral, rel=1e-4)
    assert lobe10 == pytest.approx(0.3 * 11 / (4 * 12), rel=1e-3)
    assert lobe40 == pytest.approx(0.3 * 41 / (4 * 42), rel=1e-3)


@pytest.mark.parametrize("alpha_deg", [20.0, 70.0])
def test_sphere_lobe_at_a_phase_angle_matches_quadrature(alpha_deg):
    """A unit sphere's lobe basis at phase α: the integral over the lit and seen lune of
    (n + 1)/(8π) F(α)/cos(α/2) ν^n min(μ, μ0), by scipy's dblquad in the normal's spherical angles."""
    from scipy.integrate import dblquad
    a, n, f0 = math.radians(alpha_deg), 30.0, 0.5
    law = SatelliteScattering(f0=f0, exponents=(n,), diffuse=False)
    (lobe,) = _sphere(law, a)
    s = np.array([1.0, 0.0, 0.0])
    v = np.array([math.cos(a), math.sin(a), 0.0])
    h = (s + v) / np.linalg.norm(s + v)
    fresnel = f0 + (1 - f0) * (1 - math.cos(a / 2)) ** 5

    def integrand(theta, phi):
        nrm = np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])
        mu, mu0 = nrm @ v, nrm @ s
        if mu <= 0 or mu0 <= 0:
            return 0.0
        return (n + 1) / (8 * math.pi) * fresnel / math.cos(a / 2) * (nrm @ h) ** n * min(mu, mu0) * math.sin(theta)

    ref = dblquad(integrand, 0.0, 2 * math.pi, 0.0, math.pi, epsabs=1e-10)[0]
    assert lobe == pytest.approx(ref, rel=2e-3)


def test_box_wing_gaussian_image_reproduces_the_renderer():
    """The box-wing's merged facets (normal, area) as diffuse areas A ρ(1 − F0) and lobe-800 areas A give the
    renderer's f_obs (Ashikhmin–Shirley, n_u = n_v = 800, no shadowing) at random attitudes and near glints."""
    cfg = load_config("configs/boxwing.yaml")
    scene = Scene.from_config(cfg, rho=0.5)
    groups = scene.facets.grouped()[0]
    q = random_attitudes(40, seed=4, dtype=F64)
    h = scene.half / scene.half.norm()
    g = torch.Generator().manual_seed(1)
    glints = []
    for offset_deg in (0.0, 0.5, 1.0, 2.0, 3.0):                  # body +z (box top, wing tops) near h
        z = torch.nn.functional.normalize(h + math.radians(offset_deg) * torch.randn(3, generator=g, dtype=F64), dim=0)
        x = torch.nn.functional.normalize(torch.linalg.cross(torch.randn(3, generator=g, dtype=F64), z), dim=0)
        glints.append(matrix_to_quat(torch.stack([x, torch.linalg.cross(z, x), z])))
    q = torch.cat([q, torch.stack(glints)])
    diffuse, specular = scene.flux_parts(q)
    assert float((specular / (diffuse + specular)).max()) > 0.9    # the glints are there
    body = scene.body_vectors(q)                                   # rows: Sun, observer, half angle
    law = SatelliteScattering(f0=0.5, exponents=(800.0,))
    alpha = torch.full((q.shape[0],), math.radians(float(scene.phase_angle_deg)), dtype=F64)
    areas = torch.cat([groups.areas * 0.5 * (1 - 0.5), groups.areas])[None]
    L = brightness(areas, groups.normals, body[None, :, 0], body[None, :, 1], alpha, law)[0]
    assert torch.allclose(L, diffuse + specular, rtol=1e-10, atol=0.0)


def _satellite_problem(seed: int = 0, exponents=(20.0,), curves: int = 8):
    """A 2 × 3 × 5 box (diffuse areas and lobe areas on its faces) among 54 other normals, seen in ``curves``
    relative light curves of 60 samples under varied geometry, spinning with a 7-minute period."""
    g = torch.Generator().manual_seed(seed)
    axes = torch.cat([torch.eye(3, dtype=F64), -torch.eye(3, dtype=F64)])
    normals = torch.cat([axes, fibonacci_normals(54)])
    faces = torch.tensor([15.0, 10.0, 6.0, 15.0, 10.0, 6.0], dtype=F64)
    law = SatelliteScattering(f0=0.5, exponents=exponents)
    truth = torch.zeros(law.bases, 60, dtype=F64)
    truth[0, :6] = 0.2 * faces                                       # ρ(1 − F0) = 0.2
    truth[1, :6] = faces
    truth = truth.flatten()
    spin = dict(lam=torch.tensor([2.1], dtype=F64), beta=torch.tensor([0.6], dtype=F64),
                period_s=torch.tensor([420.0], dtype=F64), phi0=torch.zeros(1, dtype=F64))
    t, sun, obs = [], [], []
    for c in range(curves):
        t.append(86400.0 * c + torch.linspace(0.0, 1800.0, 60, dtype=F64))
        s = torch.nn.functional.normalize(torch.randn(3, generator=g, dtype=F64), dim=0)
        o = torch.nn.functional.normalize(s + 0.5 * torch.randn(3, generator=g, dtype=F64), dim=0)
        sun.append(s.expand(60, 3))
        obs.append(o.expand(60, 3))
    t, sun, obs = torch.cat(t), torch.cat(sun), torch.cat(obs)
    L = brightness(truth[None], normals, body_vectors(sun, **spin, t_s=t), body_vectors(obs, **spin, t_s=t),
                   phase_angle(sun, obs), law)[0]
    curve = torch.arange(curves).repeat_interleave(60)
    scale = torch.rand(curves, generator=g, dtype=F64) + 0.5
    o = Observations(t=t, mag=-2.5 * torch.log10(L * scale[curve]), sigma=torch.full_like(t, 0.01), curve=curve,
                     curves=tuple(CurveInfo(f"c{c}", True) for c in range(curves)), sun=sun, observer=obs,
                     range_m=torch.ones_like(t), epoch="2000-01-01T00:00:00")
    return convex_data(o), normals, truth, spin, law


def test_box_areas_recovered_under_the_satellite_law():
    data, normals, truth, spin, law = _satellite_problem(curves=16)
    spin.pop("phi0")
    G = design(data, normals, law, **spin)
    assert G.shape == (1, len(data), 2 * 60)
    fit = fit_areas(G, data, normals, iterations=60)
    areas = fit.areas[0] / fit.areas[0].sum()
    assert fit.rms.item() < 1e-6
    assert torch.allclose(areas, truth / truth.sum(), atol=5e-5)          # the solver's 1e-9 jitter
    r = relative_residuals(data, normals, law, **spin, areas=truth[None])
    assert r.abs().max().item() < 1e-12
    # the lobe is needed: the diffuse basis alone cannot fit these curves, nor a wrong period
    diffuse_only = fit_areas(G[..., :60], data, normals, iterations=60)
    wrong = fit_areas(design(data, normals, law, lam=spin["lam"], beta=spin["beta"],
                             period_s=spin["period_s"] * 1.003), data, normals, iterations=60)
    assert diffuse_only.rms.item() > 1e-2 and wrong.rms.item() > 1e-3


def test_satellite_polish_jacobian_matches_central_differences():
    data, normals, _, _, _ = _satellite_problem(2, exponents=(20.0, 200.0))
    law = SatelliteScattering(f0=0.5, exponents=(20.0, 200.0))
    res = PolishResidual(data, normals[:20], law, torch.tensor([400.0, 430.0], dtype=F64), 0.01, 0.1)
    assert res.normals.shape == (60, 3) and torch.equal(res.normals, area_normals(normals[:20], law))
    g = torch.Generator().manual_seed(3)
    x = torch.cat([torch.tensor([[4.0, -0.3, 0.2], [1.0, 0.5, -0.1]], dtype=F64),
                   0.3 * torch.randn(2, 60, generator=g, dtype=F64)], -1)
    rows = torch.arange(2)
    r1, J1 = res.linearize(x, rows)
    r2, J2 = jacobian(res, x, rows, method="central", step=1e-6)
    assert torch.allclose(r1, r2, atol=1e-12)
    assert (J1 - J2).abs().max().item() < 1e-5 * J2.abs().max().item()


def test_search_normals_with_the_ring_and_the_config_keys():
    n = search_normals(30, 12)
    assert n.shape == (44, 3) and torch.allclose(n.norm(dim=-1), torch.ones(44, dtype=F64))
    assert torch.allclose(n[30:42, 2], torch.zeros(12, dtype=F64))
    assert torch.allclose(n[30:42] @ pole_vector(torch.tensor(0.0, dtype=F64), torch.tensor(0.0, dtype=F64)),
                          torch.cos(torch.arange(12, dtype=F64) * math.pi / 6))
    assert n[42:].tolist() == [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]
    assert torch.equal(search_normals(30, 0), fibonacci_normals(30))
    cfg = load_config(CONVEX, ["convex.law=ashikhmin_shirley", "convex.lobe_exponents=[50, 800]",
                               "convex.fresnel_f0=0.4", "convex.ring_normals=90"])
    settings = settings_from_config(cfg, 10.0)
    assert settings.scattering == SatelliteScattering(f0=0.4, exponents=(50.0, 800.0))
    assert settings.ring == 90 and settings.scattering.basis_names() == ("diffuse", "lobe_50", "lobe_800")
    with pytest.raises(ConfigError, match=r"^convex.law: 'phong' is not one of lommel_seeliger, ashikhmin_shirley$"):
        load_config(CONVEX, ["convex.law=phong"])
    with pytest.raises(ConfigError, match=r"^convex.lobe: unknown key"):
        load_config(CONVEX, ["convex.lobe=3"])


def _scale_free_rss(a: np.ndarray, G: np.ndarray, y: np.ndarray, curve: np.ndarray) -> float:
    """Σ_c min_t |G_c a − t ỹ_c|² over the mean scale², written out from the data (the fit's normalised rss)."""
    L = G @ a
    scales, rss = [], 0.0
    for k in np.unique(curve):
        yc, Lc = y[curve == k], L[curve == k]
        t = (yc @ Lc) / (yc @ yc)
        scales.append(t)
        rss += ((Lc - t * yc) ** 2).sum()
    return rss / np.mean(scales) ** 2


def test_refine_descends_where_the_newton_iteration_stalls():
    """Ring normals 2° apart and two bases make the area program near-singular: the projected Newton iteration
    stalls; the accelerated projected-gradient refinement lowers the rss well below it, and both rss values are
    those of their areas (the scale-free objective written out from the data)."""
    data, _, _, spin, law = _satellite_problem(3, curves=6)
    spin.pop("phi0")
    normals = search_normals(20, 180)
    G = design(data, normals, law, **spin)
    plain = fit_areas(G, data, normals, iterations=12, closure=0.0)
    longer = fit_areas(G, data, normals, iterations=48, closure=0.0)
    refined = fit_areas(G, data, normals, iterations=12, closure=0.0, refine=200)
    g, y, curve = G[0].numpy(), data.y.numpy(), data.curve.numpy()
    assert _scale_free_rss(plain.areas[0].numpy(), g, y, curve) == pytest.approx(plain.rss.item(), rel=1e-9)
    assert _scale_free_rss(refined.areas[0].numpy(), g, y, curve) == pytest.approx(refined.rss.item(), rel=1e-9)
    assert bool((refined.areas >= 0).all())
    assert longer.rss.item() > 0.9 * plain.rss.item()               # more Newton iterations do not help
    assert refined.rss.item() < 0.5 * plain.rss.item()
