"""Renderer: the paper's reference magnitude, a hand-computed facet, ρ scaling, precision, gradients, zero flux."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp

from lightcurve_gp.attitude.rotations import attitude_matrix, quat_mul
from lightcurve_gp.config.load import load_config
from lightcurve_gp.photometry.brdf import Surface, ashikhmin_shirley
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.photometry.shapes import Facets, facets_from_config

BOXWING = Path(__file__).resolve().parents[1] / "configs" / "boxwing.yaml"
F64 = torch.float64


@pytest.fixture(scope="module")
def cfg():
    return load_config(BOXWING)


@pytest.fixture(scope="module")
def scene(cfg):
    return Scene.from_config(cfg, rho=0.5)


def random_quats(n, dtype=F64, seed=0):
    q = torch.randn(n, 4, generator=torch.Generator().manual_seed(seed), dtype=F64)
    return (q / q.norm(dim=-1, keepdim=True)).to(dtype)


@pytest.fixture(scope="module")
def true_trajectory(cfg):
    """The paper's truth (scenario section), integrated here independently of the dynamics module."""
    sc = cfg.scenario
    J = np.array(cfg.shape.inertia_kg_m2)

    def rhs(_, x):
        q, w = x[:4], x[4:]
        qv, q4 = q[:3], q[3]
        dq = 0.5 * np.concatenate([q4 * w - np.cross(w, qv), [-w @ qv]])  # ½ [ω; 0] ⊗ q (paper product)
        return np.concatenate([dq, -np.cross(w, J * w) / J])

    t = np.arange(0.0, sc.duration_s + sc.dt_s / 2, sc.dt_s)
    x0 = np.concatenate([sc.q0, np.deg2rad(sc.omega0_deg_s)])
    sol = solve_ivp(rhs, (0.0, t[-1]), x0, t_eval=t, rtol=1e-11, atol=1e-12, method="DOP853")
    q = torch.tensor(sol.y[:4].T, dtype=F64)
    return q / q.norm(dim=-1, keepdim=True)


def test_reference_magnitude(scene):
    assert scene.phase_angle_deg == pytest.approx(29.8478, abs=1e-3)
    m = scene.magnitude(torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=F64))
    assert float(m) == pytest.approx(13.294, abs=1e-3)


def _single_facet(n_u=10.0, n_v=20.0, rho=0.4, f0=0.3, area=2.0, normal=(0.0, 0.0, 1.0)):
    t = lambda x: torch.tensor(x, dtype=F64)  # noqa: E731
    # tangent axes of +z by the documented rule: e = e_x, u = e_x × e_z = −e_y, v = n × u = e_x
    return Facets(normals=t([normal]), areas=t([area]), centroids=t([[0.0, 0.0, 0.0]]), u=t([[0.0, -1.0, 0.0]]),
                  v=t([[1.0, 0.0, 0.0]]), rho=t([rho]), f0=t([f0]), n_u=t([n_u]), n_v=t([n_v]))


def test_single_facet_by_hand():
    rho, f0, n_u, n_v, area, r = 0.4, 0.3, 10.0, 20.0, 2.0, 1000.0
    # Sun overhead, observer at 0.6 x + 0.8 z: n·s = 1, n·v = 0.8, h = (0.6, 0, 1.8)/√3.6
    ns, nv = 1.0, 0.8
    nh = vh = 1.8 / math.sqrt(3.6)
    hw2 = 0.36 / 3.6  # (h·v_axis)², v_axis = e_x; h·u = 0
    gamma = n_v * hw2 / (1.0 - nh**2)  # = 20
    c_d = 28 * rho / (23 * math.pi) * (1 - f0) * (1 - (1 - ns / 2) ** 5) * (1 - (1 - nv / 2) ** 5)
    fresnel = f0 + (1 - f0) * (1 - vh) ** 5
    c_s = math.sqrt((n_u + 1) * (n_v + 1)) / (8 * math.pi) * fresnel * nh**gamma / (vh * max(ns, nv))
    flux = (c_d + c_s) * area * ns * nv
    m_expected = -26.7 - 2.5 * math.log10(flux / r**2)

    facet = _single_facet(n_u, n_v, rho, f0, area)
    scene = Scene(facet, torch.tensor([0.0, 0.0, 5.0], dtype=F64), torch.tensor([0.6, 0.0, 0.8], dtype=F64), r)
    q = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=F64)
    d, s = scene.flux_parts(q)
    assert float(d) == pytest.approx(c_d * area * ns * nv, rel=1e-13)
    assert float(s) == pytest.approx(c_s * area * ns * nv, rel=1e-13)
    assert float(scene.magnitude(q)) == pytest.approx(m_expected, abs=1e-12)

    # the pure BRDF gives the same parts
    t = lambda x: torch.tensor(x, dtype=F64)  # noqa: E731
    bd, bs = ashikhmin_shirley(t([0.0, 0.0, 1.0]), t([0.6, 0.0, 0.8]), facet.normals[0], facet.u[0], facet.v[0],
                               rho, f0, n_u, n_v)
    assert float(bd) == pytest.approx(c_d, rel=1e-13) and float(bs) == pytest.approx(c_s, rel=1e-13)


def test_brdf_lobe_is_one_where_h_parallel_n():
    t = lambda x: torch.tensor(x, dtype=F64)  # noqa: E731
    n, u, w = t([0.0, 0.0, 1.0]), t([0.0, -1.0, 0.0]), t([1.0, 0.0, 0.0])
    s = t([0.6, 0.0, 0.8])
    v = t([-0.6, 0.0, 0.8])  # h = z exactly
    _, c_s = ashikhmin_shirley(s, v, n, u, w, 0.5, 0.5, 800.0, 800.0)
    fresnel = 0.5 + 0.5 * (1 - 0.8) ** 5
    assert float(c_s) == pytest.approx(801 / (8 * math.pi) * fresnel / (0.8 * 0.8), rel=1e-13)


def test_diffuse_linear_in_rho_and_override_matches_rebuilt_facets(cfg, scene):
    q = random_quats(64)
    d1, s1 = scene.flux_parts(q, rho=1.0)
    for rho in (0.1, 0.37, 0.9):
        d, s = scene.flux_parts(q, rho=rho)
        assert torch.allclose(d, rho * d1, rtol=1e-14, atol=0) and torch.equal(s, s1)
        rebuilt = Scene.from_config(cfg, rho=rho)
        assert torch.allclose(scene.magnitude(q, rho=rho), rebuilt.magnitude(q), rtol=0, atol=1e-12)
    # a ρ grid renders at once, with a leading ρ dimension
    grid = torch.tensor([0.1, 0.5, 0.9], dtype=F64).reshape(3, 1)
    m = scene.magnitude(q, rho=grid)
    assert m.shape == (3, 64)
    assert torch.allclose(m[1], scene.magnitude(q), atol=1e-12)
    # per-attitude ρ (paired)
    paired = torch.linspace(0.1, 0.9, 64, dtype=F64)
    assert torch.allclose(scene.magnitude(q, rho=paired)[5], scene.magnitude(q[5], rho=paired[5]), atol=1e-12)


def test_rho_scaling_along_true_trajectory(scene, true_trajectory):
    m05 = scene.magnitude(true_trajectory, rho=0.5)
    d, s = scene.flux_parts(true_trajectory, rho=0.5)
    share = float((s / (d + s)).max())
    assert share < 1e-7  # the specular glint never points at the observer on this trajectory
    worst = 0.0
    for rho in (0.1, 0.3, 0.7, 0.9):
        dm = scene.magnitude(true_trajectory, rho=rho) - m05
        worst = max(worst, float((dm + 2.5 * math.log10(rho / 0.5)).abs().max()))
    assert worst < 1e-6  # measured 1.3e-9 mag (specular share 3e-10); the specular share bounds it


def test_float32_matches_float64(scene, true_trajectory):
    q = torch.cat([true_trajectory, random_quats(500)])
    m64 = scene.magnitude(q)
    m32 = scene.to(dtype=torch.float32).magnitude(q.float())
    assert m32.dtype == torch.float32
    assert float((m32.double() - m64).abs().max()) < 1e-4


@pytest.mark.slow  # ~3 s on two loaded cores
def test_grouped_equals_per_facet_and_chunking(scene):
    q = random_quats(3000).reshape(30, 100, 4)
    grouped = scene.magnitude(q, rho=torch.tensor([[[0.2]], [[0.8]]], dtype=F64))
    plain = scene.with_grouping(False).magnitude(q, rho=torch.tensor([[[0.2]], [[0.8]]], dtype=F64))
    assert grouped.shape == (2, 30, 100)
    assert float((grouped - plain).abs().max()) < 1e-10
    tiny_chunks = Scene(scene.facets, scene.sun, scene.observer, scene.r_obs, chunk_elements=7)
    assert torch.allclose(tiny_chunks.flux(q), scene.flux(q), rtol=1e-13, atol=0)


def test_magnitude_of_body_vectors_equals_magnitude_of_attitudes(cfg, scene):
    """The body-vector path (:meth:`Scene.body_vectors`, :meth:`Scene.magnitude_of_body`) renders what the quaternion
    path renders — per-object surfaces, a per-sample pass geometry and the composed ``A(Δ) A(q_0)`` included — and its
    vectors are the attitude matrix applied to the inertial Sun, observer and half-angle directions."""
    q = random_quats(40, seed=5).reshape(4, 10, 4)
    surface = Surface(*(torch.tensor(v, dtype=F64) for v in ([0.2, 0.5, 0.9, 0.3], [0.1, 0.5, 0.9, 0.7],
                                                              [10.0, 800.0, 1e4, 50.0], [30.0, 800.0, 1e3, 5e3])))
    body = scene.body_vectors(q)
    assert body.shape == (4, 10, 3, 3)
    assert torch.allclose(body[..., 0, :], (attitude_matrix(q) @ scene.sun).squeeze(-1), atol=1e-15)
    assert torch.allclose(scene.magnitude_of_body(body, surface=surface), scene.magnitude(q, surface=surface),
                          rtol=0, atol=1e-12)
    turn = random_quats(10, seed=6)  # A(Δ_k) A(q_0): the vectors of Δ_k ⊗ q_0 without forming the product
    composed = scene.frame().mT @ attitude_matrix(q[:, :1]).mT @ attitude_matrix(turn).mT
    assert torch.allclose(scene.magnitude_of_body(composed), scene.magnitude(quat_mul(turn, q[:, :1])), rtol=0,
                          atol=1e-12)
    T = 10
    sun = torch.randn(T, 3, generator=torch.Generator().manual_seed(7), dtype=F64)
    per_sample = scene.with_geometry(sun, scene.observer.expand(T, 3), torch.full((T,), 3.6e7, dtype=F64))
    assert torch.allclose(per_sample.magnitude_of_body(per_sample.body_vectors(q), surface=surface),
                          per_sample.magnitude(q, surface=surface), rtol=0, atol=1e-12, equal_nan=True)


def test_gradcheck_wrt_quaternion(scene):
    q = random_quats(6, seed=3).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: scene.magnitude(x), (q,), eps=1e-6, atol=1e-6)
    plain = scene.with_grouping(False)
    assert torch.autograd.gradcheck(lambda x: plain.flux(x, rho=0.3), (q,), eps=1e-6, atol=1e-6)


def test_zero_flux_policy():
    # a single facet facing +z, Sun from −z: never lit at the identity, lit when rotated by 180° about x
    scene = Scene(_single_facet(), torch.tensor([0.0, 0.0, -1.0], dtype=F64), torch.tensor([0.6, 0.0, 0.8], dtype=F64),
                  1000.0)
    q = torch.tensor([[0.0, 0.0, 0.0, 1.0], [math.sin(0.5), 0.0, 0.0, math.cos(0.5)]], dtype=F64)
    flip = torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=F64)  # 180° about x: normal → −z, still not visible
    assert float(scene.flux(q[:1])) == 0.0
    m, visible = scene.magnitude(torch.cat([q, flip]), return_visible=True)
    assert visible.tolist() == [False, False, False]
    assert bool(torch.isnan(m).all()) and not bool(torch.isinf(m).any())
    with pytest.raises(ValueError, match="zero flux"):
        scene.magnitude(q, zero_flux="raise")
    # a mixed batch: finite where visible, NaN elsewhere, and finite gradients everywhere
    lit_scene = Scene(_single_facet(), torch.tensor([0.0, 0.0, 1.0], dtype=F64),
                      torch.tensor([0.6, 0.0, 0.8], dtype=F64), 1000.0)
    qq = torch.tensor([[0.0, 0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0]], dtype=F64, requires_grad=True)
    m, visible = lit_scene.magnitude(qq, return_visible=True)
    assert visible.tolist() == [True, False]
    assert math.isfinite(float(m[0].detach())) and math.isnan(float(m[1].detach()))
    m[visible].sum().backward()
    assert bool(torch.isfinite(qq.grad).all())


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu(scene):
    q = random_quats(1000)
    gpu = scene.to(device="cuda")
    assert torch.allclose(gpu.magnitude(q.cuda()).cpu(), scene.magnitude(q), atol=1e-10)
    assert float((scene.to(device="cuda", dtype=torch.float32).magnitude(q.float().cuda()).double().cpu()
                  - scene.magnitude(q)).abs().max()) < 1e-4


def test_from_config_defaults(cfg):
    scene = Scene.from_config(cfg)
    assert bool((scene.facets.rho == cfg.scenario.rho_true).all())
    assert scene.r_obs == pytest.approx(np.linalg.norm(cfg.geometry.observer_km) * 1e3)
    with pytest.raises(ValueError, match="scene is"):
        scene.magnitude(random_quats(2, dtype=torch.float32))
    facets = facets_from_config(cfg, rho=0.5)
    assert len(facets) == 472
