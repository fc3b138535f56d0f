"""Convex inversion's parts: the scattering law against a sphere's closed forms, the rotation against RK4 and over
decades, the areas of a box recovered from its noiseless light curves, the closed-form Jacobian, the periodogram."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from lightcurve_gp.inference.convex_families import effective_samples
from lightcurve_gp.inference.convex_fit import ConvexData, convex_data, design, fit_areas, relative_residuals
from lightcurve_gp.inference.convex_periodogram import apparitions, multiterm_periodogram
from lightcurve_gp.inference.convex_polish import PolishResidual, polish
from lightcurve_gp.inference.convex_search import period_grid
from lightcurve_gp.inference.jacobian import jacobian
from lightcurve_gp.observations.observations import CurveInfo, Observations
from lightcurve_gp.photometry.convex import (
    Scattering,
    body_vectors,
    brightness,
    fibonacci_normals,
    folded_pole,
    phase_angle,
    pole_angles,
    pole_vector,
    spin_matrices,
)

F64 = torch.float64


def _ls_sphere(alpha: float) -> float:
    """Lommel–Seeliger brightness of the unit sphere: (π/2)(1 − sin(α/2) tan(α/2) ln cot(α/4))."""
    if alpha == 0:
        return math.pi / 2
    return math.pi / 2 * (1 - math.sin(alpha / 2) * math.tan(alpha / 2) * math.log(1 / math.tan(alpha / 4)))


def _lambert_sphere(alpha: float) -> float:
    """Lambert (μ μ0) brightness of the unit sphere: (2/3)(sin α + (π − α) cos α)."""
    return 2.0 / 3.0 * (math.sin(alpha) + (math.pi - alpha) * math.cos(alpha))


@pytest.mark.parametrize("alpha_deg", [0.0, 5.0, 30.0, 60.0, 120.0])
def test_sphere_phase_curve_matches_closed_forms(alpha_deg):
    k = 40_000
    normals = fibonacci_normals(k)
    areas = torch.full((1, k), 4 * math.pi / k, dtype=F64)
    a = math.radians(alpha_deg)
    sun = torch.tensor([[[1.0, 0.0, 0.0]]], dtype=F64)
    obs = torch.tensor([[[math.cos(a), math.sin(a), 0.0]]], dtype=F64)
    alpha = phase_angle(sun[0], obs[0])
    assert alpha.item() == pytest.approx(a, abs=1e-12)
    flat = dict(amplitude=0.0, slope=0.0)                                   # f(α) = 1
    ls = brightness(areas, normals, sun, obs, alpha, Scattering(lambert=0.0, **flat)).item()
    both = brightness(areas, normals, sun, obs, alpha, Scattering(lambert=0.3, **flat)).item()
    assert ls == pytest.approx(_ls_sphere(a), rel=2e-3)
    assert (both - ls) / 0.3 == pytest.approx(_lambert_sphere(a), rel=2e-3)
    # the phase function multiplies: convexinv's example at this α
    example = Scattering()
    f = 0.5 * math.exp(-a / 0.1) - 0.5 * a + 1.0
    assert brightness(areas, normals, sun, obs, alpha, example).item() == pytest.approx(
        f * (_ls_sphere(a) + 0.1 * _lambert_sphere(a)), rel=2e-3)


def test_law_is_zero_unless_lit_and_seen():
    law = Scattering(lambert=0.1).law
    mu = torch.tensor([0.5, -0.2, 0.5, 0.0, 0.3], dtype=F64)
    mu0 = torch.tensor([0.5, 0.5, -0.1, 0.4, 0.6], dtype=F64)
    expected = [0.25 / 1.0 + 0.025, 0.0, 0.0, 0.0, 0.18 / 0.9 + 0.018]
    assert law(mu, mu0).tolist() == pytest.approx(expected, abs=1e-15)


def _spin(lam_deg, beta_deg, period_h, phi0=0.0):
    t = lambda x: torch.tensor([x], dtype=F64)  # noqa: E731
    return dict(lam=t(math.radians(lam_deg)), beta=t(math.radians(beta_deg)), period_s=t(period_h * 3600.0),
                phi0=t(phi0))


def test_rotation_puts_the_pole_on_z_and_matches_rk4():
    spin = _spin(253.3, -16.9, 5.76198173, 0.3)
    pole = pole_vector(spin["lam"], spin["beta"])
    times = torch.linspace(0.0, 3 * 5.76198173 * 3600.0, 301, dtype=F64)
    R = spin_matrices(**spin, t_s=times)[0]                                 # (N, 3, 3)
    assert torch.allclose(R @ pole[0], torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand(301, 3), atol=1e-14)
    assert torch.allclose(R @ R.transpose(1, 2), torch.eye(3, dtype=F64).expand(301, 3, 3), atol=1e-14)
    v = torch.tensor([0.3, -0.5, 0.81], dtype=F64)
    closed = body_vectors(v.expand(301, 3), **spin, t_s=times)[0]
    assert torch.allclose(closed, R @ v, atol=1e-14)
    # RK4 of dv/dt = −ω × v in the body frame, ω = 2π/P along z (prograde spin about the pole)
    omega = torch.tensor([0.0, 0.0, 2 * math.pi / (5.76198173 * 3600.0)], dtype=F64)
    rate = lambda x: -torch.linalg.cross(omega, x)  # noqa: E731
    x, dt = closed[0].clone(), float(times[1] - times[0]) / 10        # ten RK4 steps between samples
    for n in range(1, 301):
        for _ in range(10):
            k1 = rate(x)
            k2 = rate(x + 0.5 * dt * k1)
            k3 = rate(x + 0.5 * dt * k2)
            k4 = rate(x + dt * k3)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        assert torch.allclose(x, closed[n], atol=1e-9)


def test_rotation_stays_exact_over_decades():
    period_h = 5.76198173
    spin = _spin(40.0, 60.0, period_h)
    rotations = 38_000                                                      # ~25 years
    times = torch.tensor([1234.5, 1234.5 + rotations * period_h * 3600.0], dtype=F64)
    v = torch.tensor([[0.6, 0.0, 0.8], [0.6, 0.0, 0.8]], dtype=F64)
    out = body_vectors(v, **spin, t_s=times)[0]
    assert torch.allclose(out[0], out[1], atol=1e-9)


def test_pole_angles_invert_pole_vector():
    lam = torch.tensor([0.1, 3.0, 6.0], dtype=F64)
    beta = torch.tensor([-1.2, 0.0, 0.7], dtype=F64)
    back = pole_angles(pole_vector(lam, beta))
    assert torch.allclose(back[0], lam) and torch.allclose(back[1], beta)


def _box_problem(seed: int = 0):
    """A 2 × 3 × 5 box on its own normals plus 54 others, seen in 8 relative light curves of 40 samples."""
    g = torch.Generator().manual_seed(seed)
    axes = torch.cat([torch.eye(3, dtype=F64), -torch.eye(3, dtype=F64)])
    normals = torch.cat([axes, fibonacci_normals(54)])
    truth = torch.zeros(60, dtype=F64)
    truth[:6] = torch.tensor([15.0, 10.0, 6.0, 15.0, 10.0, 6.0], dtype=F64)   # faces ±x: 3·5, ±y: 2·5, ±z: 2·3
    spin = _spin(120.0, 35.0, 7.3)
    curves, t, sun, obs = 8, [], [], []
    for c in range(curves):
        start = 86400.0 * 30 * c
        t.append(start + torch.linspace(0.0, 6 * 3600.0, 40, dtype=F64))
        s = torch.nn.functional.normalize(torch.randn(3, generator=g, dtype=F64), dim=0)
        o = torch.nn.functional.normalize(s + 0.4 * torch.randn(3, generator=g, dtype=F64), dim=0)
        sun.append(s.expand(40, 3))
        obs.append(o.expand(40, 3))
    t, sun, obs = torch.cat(t), torch.cat(sun), torch.cat(obs)
    body_sun = body_vectors(sun, **spin, t_s=t)
    body_obs = body_vectors(obs, **spin, t_s=t)
    L = brightness(truth[None], normals, body_sun, body_obs, phase_angle(sun, obs), Scattering())[0]
    curve = torch.arange(curves).repeat_interleave(40)
    scale = torch.rand(curves, generator=g, dtype=F64) + 0.5                 # unknown zero points
    o = Observations(t=t, mag=-2.5 * torch.log10(L * scale[curve]), sigma=torch.full_like(t, 0.01), curve=curve,
                     curves=tuple(CurveInfo(f"c{c}", True) for c in range(curves)), sun=sun, observer=obs,
                     range_m=torch.ones_like(t), epoch="2000-01-01T00:00:00")
    return convex_data(o), normals, truth, spin


def test_box_areas_recovered_from_noiseless_relative_curves():
    data, normals, truth, spin = _box_problem()
    G = design(data, normals, Scattering(), lam=spin["lam"], beta=spin["beta"], period_s=spin["period_s"])
    fit = fit_areas(G, data, normals, iterations=40)
    areas = fit.areas[0] / fit.areas[0].sum()
    assert fit.rms.item() < 1e-7
    assert torch.allclose(areas, truth / truth.sum(), atol=2e-5)          # the solver's 1e-9 jitter
    r = relative_residuals(data, normals, Scattering(), lam=spin["lam"], beta=spin["beta"],
                           period_s=spin["period_s"], areas=truth[None])
    assert r.abs().max().item() < 1e-12
    # at a wrong period the same fit is far worse
    wrong = fit_areas(design(data, normals, Scattering(), lam=spin["lam"], beta=spin["beta"],
                             period_s=spin["period_s"] * 1.01), data, normals, iterations=40)
    assert wrong.rms.item() > 1e-3


def test_weighted_area_fit_matches_scipy_nnls():
    """With the weights 1/ỹ the fit minimises Σ w_i² ((G a)_i − t_c ỹ_i)² over a ≥ 0 and the scales, the scale of
    ``a`` fixed by the mean of the scales' optima ``t_c = Σ_{i∈c} w_i² ỹ_i (G a)_i / Σ_{i∈c} w_i² ỹ_i²`` being 1:
    the same minimum as scipy's NNLS on the weighted rows, that mean held by a stiff extra row."""
    from scipy.optimize import nnls

    data, normals, _, spin = _box_problem(3)
    noise = 1 + 0.05 * torch.randn(len(data), generator=torch.Generator().manual_seed(6), dtype=F64)
    data = replace(data, y=data.y * noise).magnitude_weighted()
    G = design(data, normals, Scattering(), **{k: v for k, v in spin.items() if k != "phi0"})
    fit = fit_areas(G, data, normals, closure=0.0, iterations=60)
    w, y, curve = data.weight.numpy(), data.y.numpy(), data.curve.numpy()
    scales = np.zeros((len(data), data.curves))
    scales[np.arange(len(data)), curve] = -w * y
    Gw, yw = w[:, None] * G[0].numpy(), w * y
    mean_scale = np.mean([Gw[curve == k].T @ yw[curve == k] / (yw[curve == k] @ yw[curve == k])
                          for k in range(data.curves)], axis=0)
    stiff = 1e5
    rows = np.vstack([np.hstack([Gw, scales]), np.hstack([stiff * mean_scale, np.zeros(data.curves)])])
    x, _ = nnls(rows, np.concatenate([np.zeros(len(data)), [stiff]]), maxiter=5000)
    expected = float(((rows[:-1] @ x) ** 2).sum())
    assert expected > 1e-3                                                 # the noise is not fitted away
    assert fit.rss.item() == pytest.approx(expected, rel=1e-6)
    unweighted = fit_areas(G, replace(data, weight=None), normals, closure=0.0, iterations=60)
    assert abs(unweighted.rss.item() / expected - 1) > 1e-3               # the weights change the problem


def test_polish_returns_to_the_truth_from_a_nearby_start():
    data, normals, truth, spin = _box_problem(1)
    start = dict(lam=spin["lam"] + 0.02, beta=spin["beta"] - 0.02, period_s=spin["period_s"] * (1 + 2e-6))
    G = design(data, normals, Scattering(), **start)
    init = fit_areas(G, data, normals, iterations=20)
    p = polish(data, normals, Scattering(), **start, areas=init.areas, iterations=40, closure=0.0)
    assert init.rms.item() > 5e-3                                           # the start is visibly off
    # zero areas are approached in log space only (a weak prior holds them), so the fit is close, not exact
    assert p.rms.item() < 1e-3
    assert abs(p.lam.item() - spin["lam"].item()) < 1e-3 and abs(p.beta.item() - spin["beta"].item()) < 1e-3
    assert abs(p.period_s.item() / spin["period_s"].item() - 1) < 1e-7


def test_polish_state_past_the_ecliptic_pole_reproduces_its_rms():
    """A state past β = 90° is returned as it is: (λ + 180°, 180° − β) is the same axis in a body frame turned by
    180° about it, where the areas on these normals make another light curve."""
    data, normals, _, _ = _box_problem(4)
    spin = {k: v for k, v in _spin(120.0, 95.0, 7.3).items() if k != "phi0"}   # the axis (300°, 85°) past the pole
    areas = torch.rand(1, 60, generator=torch.Generator().manual_seed(5), dtype=F64) + 0.1   # no symmetry
    p = polish(data, normals, Scattering(), **spin, areas=areas, iterations=2, closure=0.0)
    assert p.beta.item() > math.pi / 2
    r = relative_residuals(data, normals, Scattering(), lam=p.lam, beta=p.beta, period_s=p.period_s, areas=p.areas)
    assert torch.sqrt((r * r).mean()).item() == pytest.approx(p.rms.item(), rel=1e-12)
    folded = relative_residuals(data, normals, Scattering(), lam=p.lam + math.pi, beta=math.pi - p.beta,
                                period_s=p.period_s, areas=p.areas)
    assert (folded - r).abs().max().item() > 1e-2                         # the folded state is another light curve


@pytest.mark.parametrize("weighted", [False, True])
def test_polish_jacobian_matches_central_differences(weighted):
    data, normals, _, _ = _box_problem(2)
    data = data.magnitude_weighted() if weighted else data
    res = PolishResidual(data, normals[:20], Scattering(), torch.tensor([7.0 * 3600, 5.5 * 3600], dtype=F64),
                         0.01, 0.1, smoothness=0.5)
    assert res.diff.shape[0] >= 60 and bool((res.diff.sum(-1) == 0).all())  # ≥ 20·6/2 neighbour differences
    g = torch.Generator().manual_seed(3)
    x = torch.cat([torch.tensor([[4.0, -0.3, 0.2], [1.0, 0.5, -0.1]], dtype=F64),
                   0.3 * torch.randn(2, 20, generator=g, dtype=F64)], -1)
    rows = torch.arange(2)
    r1, J1 = res.linearize(x, rows)
    r2, J2 = jacobian(res, x, rows, method="central", step=1e-6)
    assert torch.allclose(r1, r2, atol=1e-12)
    assert (J1 - J2).abs().max().item() < 1e-6 * J2.abs().max().item()


def test_periodogram_finds_a_double_peaked_period_across_apparitions():
    g = np.random.default_rng(0)
    period_h = 7.25
    t, curve = [], []
    for c, day in enumerate([0, 1, 3, 400, 402, 800]):
        t.append(day * 86400.0 + np.sort(g.uniform(0, 6 * 3600.0, 50)))
        curve.append(np.full(50, c))
    t, curve = np.concatenate(t), np.concatenate(curve)
    phase = 2 * math.pi * t / (period_h * 3600.0)
    y = 1 + 0.2 * np.cos(2 * phase + 0.3) + 0.03 * np.cos(phase) + 0.005 * g.standard_normal(t.size) + curve * 0.1
    tt, ct = torch.as_tensor(t), torch.as_tensor(curve)
    assert apparitions(tt, ct, 6).tolist() == [0, 0, 0, 1, 1, 2]
    pg = multiterm_periodogram(tt, torch.as_tensor(y), ct, 6, period_range_h=(2.0, 20.0), harmonics=2)
    assert pg.groups == 3
    assert abs(pg.minima_h[0] - period_h) < 0.5 * pg.peak_width_h


def test_period_grid_steps_and_effective_samples():
    grid = period_grid(6.0, 0.01, 1000 * 86400.0, 0.5)
    df = np.diff(1.0 / grid)
    assert np.allclose(df, 0.5 / (1000 * 24.0)) and grid.min() <= 5.99 and grid.max() >= 6.01
    curve = torch.zeros(1000, dtype=torch.int64)
    rho, n_eff = effective_samples(torch.ones(1000, dtype=F64), curve)           # ρ_k = 1 − k/N, summed to lag 50
    assert rho == pytest.approx(0.999) and n_eff == pytest.approx(1000 / (1 + 2 * sum(1 - k / 1000
                                                                                      for k in range(1, 51))))
    ar = torch.zeros(20000, dtype=F64)                                          # AR(1), ρ = 0.6: τ = 1.6/0.4
    noise = torch.randn(20000, generator=torch.Generator().manual_seed(0), dtype=F64)
    for i in range(1, 20000):
        ar[i] = 0.6 * ar[i - 1] + noise[i]
    rho, n_eff = effective_samples(ar, torch.zeros(20000, dtype=torch.int64))
    assert rho == pytest.approx(0.6, abs=0.02) and n_eff == pytest.approx(20000 / 4.0, rel=0.15)
    rho, n_eff = effective_samples(torch.tensor([1.0, -1.0] * 500, dtype=F64), curve)
    assert rho == 0.0 and n_eff == 1000
    assert isinstance(_box_problem()[0], ConvexData)


def test_a_pole_past_the_ecliptic_pole_folds_to_the_same_body_frame():
    rng = np.random.default_rng(7)
    lam, beta = rng.uniform(-30.0, 400.0, 64), rng.uniform(-260.0, 260.0, 64)
    lam_f, beta_f, phase = folded_pole(lam, beta)
    assert np.all(np.abs(beta_f) <= 90.0) and np.all((lam_f >= 0.0) & (lam_f < 360.0))
    assert set(np.unique(phase)) <= {0.0, 180.0} and np.any(phase == 180.0) and np.any(phase == 0.0)
    t = torch.linspace(0.0, 7200.0, 5, dtype=torch.float64)
    f64 = lambda v: torch.as_tensor(np.radians(v), dtype=torch.float64)  # noqa: E731
    period = torch.full((64,), 3600.0, dtype=torch.float64)
    before = spin_matrices(lam=f64(lam), beta=f64(beta), period_s=period, phi0=torch.zeros(64, dtype=torch.float64),
                           t_s=t)
    after = spin_matrices(lam=f64(lam_f), beta=f64(beta_f), period_s=period, phi0=f64(phase), t_s=t)
    torch.testing.assert_close(after, before, rtol=0.0, atol=1e-12)
    # the pole itself is unchanged
    torch.testing.assert_close(pole_vector(f64(lam_f), f64(beta_f)), pole_vector(f64(lam), f64(beta)), rtol=0.0,
                               atol=1e-12)
