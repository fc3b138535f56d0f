"""The Cramér–Rao bound of a light curve: finite differences, closed forms, scaling, the issue's numbers."""

import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.metrics import attitude_errors_deg
from lightcurve_gp.attitude.rotations import quat_mul, rotvec_to_quat
from lightcurve_gp.config.load import load_config
from lightcurve_gp.filters.state import StateLayout
from lightcurve_gp.inference.crb import (
    CramerRaoBound,
    bound_for_truths,
    cramer_rao_bound,
    filter_prior,
    state_layout,
    surface_state,
)
from lightcurve_gp.observation.surface_state import surface_from_state
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.photometry.shapes import facets_from_config
from lightcurve_gp.simulation.truths import draw_truths, paper_case_draw

DT = torch.float64
CONFIGS = Path(__file__).resolve().parents[1] / "configs"
INERTIA = (55.0, 40.0, 65.0)
ALL = ("attitude", "omega", "offset", "surface")


@pytest.fixture(scope="module")
def cfg():
    return load_config(CONFIGS / "boxwing.yaml")


@pytest.fixture(scope="module")
def scene(cfg):
    return Scene.from_config(cfg)


@pytest.fixture(scope="module")
def truths():
    draw = draw_truths([1000, 1001])
    return draw.q0, draw.omega0 * 5.0, draw.surface  # faster spins: a short arc sees more of the object


def _magnitudes(scene, x, *, q0, omega0, surface, n_steps, sample_index=None):
    """Noise-free magnitudes ``(S, T+1)`` of the perturbed initial states ``x (S, 11)`` = [e, δω, b, δθ], by
    propagating and rendering directly (independent of the module's derivatives)."""
    q_start = quat_mul(rotvec_to_quat(x[:, :3]), q0)
    q = propagate(q_start, omega0 + x[:, 3:6], torch.tensor(INERTIA, dtype=DT), 1.0, n_steps)[0]
    if sample_index is not None:
        q = q[:, sample_index]
    theta = surface_state(surface) + x[:, 7:]
    return scene.magnitude(q, surface=surface_from_state(theta)) + x[:, 6:7]


def test_the_fisher_matrix_equals_central_finite_differences_of_the_light_curve(scene, truths):
    q0, omega0, surface = truths
    R = torch.linspace(0.01, 0.04, 41, dtype=DT)  # per-sample noise
    bound = cramer_rao_bound(scene, q0=q0, omega0=omega0, inertia=INERTIA, dt=1.0, noise_var=R, n_steps=40,
                             surface=surface, unknowns=ALL)
    steps = torch.tensor([1e-6] * 3 + [1e-8] * 3 + [1e-6] * 5, dtype=DT)
    columns = []
    for j in range(11):
        dx = torch.zeros(2, 11, dtype=DT)
        dx[:, j] = steps[j]
        plus = _magnitudes(scene, dx, q0=q0, omega0=omega0, surface=surface, n_steps=40)
        minus = _magnitudes(scene, -dx, q0=q0, omega0=omega0, surface=surface, n_steps=40)
        columns.append((plus - minus) / (2 * steps[j]))
    J = torch.stack(columns, -1)
    J[:, 0] = 0.0  # ỹ_0 is left out
    F = torch.einsum("stn,t,stm->snm", J, 1.0 / R, J)
    assert torch.allclose(bound.jacobian, J, rtol=1e-6, atol=1e-6 * float(J.abs().max()))
    assert torch.allclose(bound.fisher, F, rtol=1e-6, atol=1e-9 * float(F.abs().max()))


def test_along_a_pass_with_gaps_each_sample_takes_its_own_geometry(cfg, truths):
    q0, omega0, surface = truths
    index = torch.tensor([0, 1, 2, 5, 6, 9, 13, 14, 20])
    angle = 0.02 * index.to(DT)
    sun = torch.stack([torch.cos(angle), torch.sin(angle), 0.3 * torch.ones_like(angle)], -1)
    observer = torch.tensor([1.0, -0.4, 0.2], dtype=DT).expand(len(index), 3)
    scene = Scene(facets_from_config(cfg), sun, observer, torch.full((len(index),), 3.6e7, dtype=DT))
    observed = torch.ones(len(index), dtype=torch.bool)
    observed[4] = False
    bound = cramer_rao_bound(scene, q0=q0, omega0=omega0, inertia=INERTIA, dt=1.0, noise_var=0.02,
                             sample_index=index, surface=surface, unknowns=("attitude", "omega"), observed=observed)
    columns = []
    for j in range(6):
        dx = torch.zeros(2, 11, dtype=DT)
        dx[:, j] = 1e-6 if j < 3 else 1e-8
        pm = [_magnitudes(scene, s * dx, q0=q0, omega0=omega0, surface=surface, n_steps=20, sample_index=index)
              for s in (1, -1)]
        columns.append((pm[0] - pm[1]) / (2 * float(dx[0, j])))
    J = torch.stack(columns, -1)
    J[:, [0, 4]] = 0.0
    assert bound.times.tolist() == index.tolist()
    assert bound.weights[:, 4].eq(0).all() and bound.weights[:, 5].eq(50.0).all()
    assert torch.allclose(bound.jacobian, J, rtol=1e-6, atol=1e-6 * float(J.abs().max()))


def test_the_sensitivity_turns_a_small_initial_error_into_the_euler_errors_at_each_sample(scene, truths):
    q0, omega0, surface = truths
    bound = cramer_rao_bound(scene, q0=q0, omega0=omega0, inertia=INERTIA, dt=1.0, noise_var=0.01, n_steps=300,
                             surface=surface, unknowns=("attitude", "omega"))
    x = torch.tensor([[2e-6, -1e-6, 3e-6, 1e-9, -2e-9, 1.5e-9]], dtype=DT).expand(2, 6)
    inertia = torch.tensor(INERTIA, dtype=DT)
    q_true = propagate(q0, omega0, inertia, 1.0, 300)[0]
    q_est = propagate(quat_mul(rotvec_to_quat(x[:, :3]), q0), omega0 + x[:, 3:], inertia, 1.0, 300)[0]
    euler = attitude_errors_deg(q_true, q_est)  # (S, T+1, 3) of q_true ⊗ q_est⁻¹ = −(the error)
    linear = torch.rad2deg(bound.sensitivity[..., [2, 1, 0], :] @ x.unsqueeze(1).unsqueeze(-1)).squeeze(-1)
    assert torch.allclose(euler, -linear, rtol=1e-4, atol=1e-5 * float(linear.abs().max()))  # second order: 1e-6


def test_a_linear_gaussian_bound_is_the_kalman_filters_covariance():
    """For ``y_k = J_k x + v_k`` the bound is the exact posterior covariance: the causal bound equals the Kalman
    filter's covariance step by step, the smoothing bound its last one, and the Euler bound ``Φ_k C Φ_kᵀ``."""
    g = torch.Generator().manual_seed(3)
    S, T1, n = 2, 30, 4
    J = torch.randn(S, T1, n, generator=g, dtype=DT)
    R = 0.1 + torch.rand(S, T1, generator=g, dtype=DT)
    P0 = torch.diag(torch.tensor([0.3, 0.2, 0.5, 1.0], dtype=DT))
    sens = torch.randn(S, T1, 3, n, generator=g, dtype=DT)
    bound = CramerRaoBound(StateLayout(offset=True), torch.arange(T1, dtype=DT), J, 1.0 / R,
                           torch.linalg.inv(P0).expand(S, n, n), sens)
    P, kalman = P0.expand(S, n, n).clone(), []
    for k in range(T1):
        h = J[:, k].unsqueeze(-1)
        gain = P @ h / (h.mT @ P @ h + R[:, k, None, None])
        P = P - gain @ h.mT @ P
        kalman.append(P)
    kalman = torch.stack(kalman, 1)
    assert torch.allclose(bound.causal_covariance(), kalman, rtol=1e-10, atol=1e-13)
    assert torch.allclose(bound.covariance, kalman[:, -1], rtol=1e-10, atol=1e-13)
    var = torch.diagonal(sens[..., [2, 1, 0], :] @ kalman @ sens[..., [2, 1, 0], :].mT, dim1=-2, dim2=-1)
    assert torch.allclose(bound.euler_std_deg(causal=True), torch.rad2deg(var.sqrt()), rtol=1e-10)
    window = bound.euler_rms_deg((10.0, 19.0), causal=True)
    assert torch.allclose(window, torch.rad2deg(var[:, 10:20].mean(1).sqrt()), rtol=1e-10)


def test_the_offset_of_a_known_attitude_is_bounded_by_the_weighted_mean(scene, truths):
    """Closed form through the renderer: with the attitude pinned by its prior, the offset's bound is that of a
    weighted mean, ``1 / (Σ_k 1/R_k + 1/σ_b²)``."""
    q0, omega0, surface = truths
    R = torch.linspace(0.01, 0.09, 51, dtype=DT)
    prior = torch.diag(torch.tensor([1e-20] * 3 + [0.25], dtype=DT))
    bound = cramer_rao_bound(scene, q0=q0, omega0=omega0, inertia=INERTIA, dt=1.0, noise_var=R, n_steps=50,
                             surface=surface, unknowns=("attitude", "offset"), prior=prior)
    expected = 1.0 / ((1.0 / R[1:]).sum() + 1.0 / 0.25)
    assert torch.allclose(bound.covariance[:, 3, 3], expected.expand(2), rtol=1e-8)


def test_without_a_prior_the_bound_scales_with_the_noise_and_a_prior_tightens_it(scene, truths):
    q0, omega0, surface = truths
    run = lambda R, prior=None: cramer_rao_bound(  # noqa: E731
        scene, q0=q0, omega0=omega0, inertia=INERTIA, dt=1.0, noise_var=R, n_steps=200, surface=surface,
        unknowns=("attitude", "surface"), prior=prior)
    low, high = run(0.01), run(0.04)
    assert torch.allclose(high.attitude_std_deg()[0], 2.0 * low.attitude_std_deg()[0], rtol=1e-9)
    assert torch.allclose(high.euler_rms_deg((100.0, 200.0)), 2.0 * low.euler_rms_deg((100.0, 200.0)), rtol=1e-9)
    prior = torch.diag(torch.tensor([math.radians(10.0) ** 2] * 3 + [1.0] * 4, dtype=DT))
    with_prior = run(0.04, prior)
    assert (with_prior.attitude_std_deg()[0] < high.attitude_std_deg()[0]).all()
    last = high.causal_covariance()[:, -1]  # the filtering bound at the end is the smoothing bound
    assert torch.allclose(last, high.covariance, rtol=1e-6)


def test_the_paper_trajectory_has_the_bound_the_issue_quotes(cfg, scene):
    """ρ and ω known, no prior, 600 s at 1 Hz: (0.95, 4.3, 22.2)° at σ² = 0.5, (0.13, 0.61, 3.1)° at σ = 0.1."""
    q0 = torch.tensor(cfg.scenario.q0, dtype=DT)
    omega0 = torch.deg2rad(torch.tensor(cfg.scenario.omega0_deg_s, dtype=DT))
    run = lambda R: cramer_rao_bound(scene, q0=q0, omega0=omega0, inertia=INERTIA, dt=1.0, noise_var=R,  # noqa: E731
                                     n_steps=600, rho=0.5).attitude_std_deg()[0][0]
    assert torch.allclose(run(0.5), torch.tensor([0.95, 4.30, 22.2], dtype=DT), atol=0.01, rtol=0.003)
    assert torch.allclose(run(0.01), torch.tensor([0.134, 0.608, 3.14], dtype=DT), rtol=0.003)


def test_bound_for_truths_is_the_bound_with_the_filters_prior(cfg, scene):
    draw = paper_case_draw(cfg, [100, 101], rho=0.5)
    unknowns = ("attitude", "offset", "surface")
    layout = state_layout(unknowns)
    prior = filter_prior(cfg, draw, layout, scene=scene)
    assert torch.allclose(torch.diagonal(prior, dim1=-2, dim2=-1)[0, :4],
                          torch.tensor([math.radians(10.0) ** 2] * 3 + [1.0], dtype=DT))
    bound = bound_for_truths(cfg, draw, unknowns=unknowns, noise_var=0.01)
    direct = cramer_rao_bound(scene, q0=draw.q0, omega0=draw.omega0, inertia=INERTIA, dt=1.0, noise_var=0.01,
                              n_steps=600, surface=draw.surface, unknowns=unknowns, prior=prior)
    assert torch.equal(bound.fisher, direct.fisher)
    no_prior = bound_for_truths(cfg, draw, unknowns=unknowns, noise_var=0.01, with_prior=False)
    assert no_prior.prior_information.eq(0).all()


def test_an_unidentified_state_has_an_infinite_bound(scene, truths):
    q0, omega0, surface = truths
    # offset and log ρ both shift the magnitudes of a diffuse surface alike: without a prior not separable
    diffuse = Surface(surface.rho, surface.f0, torch.full((2,), 1e4, dtype=DT), torch.full((2,), 1e4, dtype=DT))
    bound = cramer_rao_bound(scene, q0=q0, omega0=omega0, inertia=INERTIA, dt=1.0, noise_var=0.01, n_steps=2,
                             surface=diffuse, unknowns=ALL)
    assert torch.isinf(bound.attitude_std_deg()[0]).all()
    assert torch.isinf(bound.euler_rms_deg((0.0, 2.0))).all()


@pytest.mark.parametrize("kwargs, message", [
    ({"noise_var": 0.0}, "noise_var: every finite noise variance must be > 0 mag^2"),
    ({"noise_var": torch.tensor([0.1, -1.0, 0.1])}, "noise_var: every finite noise variance must be > 0 mag^2"),
    ({"noise_var": torch.ones(5)}, "noise_var: expected a number, (3,) or (1, 3), got (5,)"),
    ({"unknowns": ("omega",)}, "unknowns: the bound is of the attitude; 'attitude' must be among the unknowns"),
    ({"unknowns": ("attitude", "spin")}, "unknowns: 'spin' is not one of attitude, omega, offset, surface"),
    ({"unknowns": ("attitude", "surface")}, "unknowns: 'surface' needs the true surface (surface=), not rho"),
    ({"prior": torch.eye(4, dtype=DT)}, "prior: expected (3, 3) or (1, 3, 3)"),
])
def test_bad_inputs_are_one_line_errors(scene, kwargs, message):
    args = dict(q0=torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=DT), omega0=torch.tensor([0.01, 0.0, 0.0], dtype=DT),
                inertia=INERTIA, dt=1.0, noise_var=0.1, n_steps=2, rho=0.5)
    with pytest.raises(ValueError, match=None) as info:
        cramer_rao_bound(scene, **{**args, **kwargs})
    assert str(info.value).startswith(message)
