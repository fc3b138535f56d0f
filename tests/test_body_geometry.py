"""Geometry-aware GP (model.inputs: body_geometry): the canonical geometry frame, sign and rotation invariance,
the range term; observation models along a pass (AlongPass) against the per-sample renderer and the fixed filter."""

import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.rotations import attitude_matrix, quat_mul
from lightcurve_gp.config.load import load_config
from lightcurve_gp.filters.usque import UsqueParams, initial_covariance, run_usque
from lightcurve_gp.observation.along_pass import AlongPass, bind_geometry
from lightcurve_gp.observation.body_geometry import GeometryBound, canonical_frame
from lightcurve_gp.observation.inputs import body_geometry_features
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.observation.sparse_gp import SparseGP
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.training.geometry import geometry_training_set
from lightcurve_gp.training.sets import model_targets

ROOT = Path(__file__).resolve().parents[1]
F64 = torch.float64


def _unit(x):
    return x / x.norm(dim=-1, keepdim=True)


def _random(shape, seed):
    return torch.randn(*shape, generator=torch.Generator().manual_seed(seed), dtype=F64)


@pytest.fixture(scope="module")
def cfg():
    return load_config(ROOT / "configs" / "geo_pass.yaml",
                       overrides=["data.num_random=256", "model.sparse.num_inducing=64",
                                  "model.fit_hyperparameters=false", "data.heldout_size=50"])


@pytest.fixture(scope="module")
def gp(cfg):
    data = model_targets(geometry_training_set(cfg), cfg.model)
    return SparseGP.from_data(data.q, data.m_past, data.y, cfg.model)


def test_canonical_frame_maps_the_canonical_geometry():
    sun, observer = _unit(_random((50, 3), 0)), _unit(_random((50, 3), 1))
    observer[0] = sun[0]  # zero phase angle: any frame normal to s does
    observer[1] = -sun[1]
    c, alpha = canonical_frame(sun, observer)
    frame = attitude_matrix(c)
    ex = torch.tensor([1.0, 0.0, 0.0], dtype=F64)
    assert torch.allclose(frame @ ex, sun, atol=1e-12)
    canonical_v = torch.stack([torch.cos(alpha), torch.sin(alpha), torch.zeros_like(alpha)], -1)
    assert torch.allclose((frame @ canonical_v.unsqueeze(-1)).squeeze(-1), observer, atol=1e-12)
    assert float(alpha[0]) == pytest.approx(0.0, abs=1e-12) and float(alpha[1]) == pytest.approx(math.pi)
    # the features of (q ⊗ c, α) are the body-frame directions A(q) s, A(q) v
    q = _unit(_random((50, 4), 2))
    direct = torch.cat([(attitude_matrix(q) @ sun.unsqueeze(-1)).squeeze(-1),
                        (attitude_matrix(q) @ observer.unsqueeze(-1)).squeeze(-1)], -1)
    assert torch.allclose(body_geometry_features(quat_mul(q, c), alpha), direct, atol=1e-12)


def test_q_and_minus_q_give_the_same_prediction(gp):
    sun, observer = _unit(_random((3,), 3)), _unit(_random((3,), 4))
    bound = GeometryBound(gp, sun=sun, observer=observer, range_m=3.7e7)
    q = _unit(_random((4, 7, 4), 5))
    mean, var = bound(q=q, m_past=torch.zeros(4, 7, dtype=F64))
    mean_neg, var_neg = bound(q=-q, m_past=torch.zeros(4, 7, dtype=F64))
    assert torch.allclose(mean, mean_neg, rtol=0, atol=1e-12) and torch.allclose(var, var_neg, rtol=0, atol=1e-12)


def test_prediction_depends_on_body_frame_directions_and_range_only(gp):
    sun, observer = _unit(_random((3,), 6)), _unit(_random((3,), 7))
    q = _unit(_random((9, 4), 8))
    p = _unit(_random((4,), 9))  # rotate attitude and geometry together: the body frame sees the same
    a_p = attitude_matrix(p)
    mean, _ = GeometryBound(gp, sun=sun, observer=observer, range_m=4e7)(q=q, m_past=torch.zeros(9, dtype=F64))
    turned = GeometryBound(gp, sun=a_p.T @ sun, observer=a_p.T @ observer, range_m=4e7)
    mean_turned, _ = turned(q=quat_mul(q, p), m_past=torch.zeros(9, dtype=F64))
    assert torch.allclose(mean, mean_turned, rtol=0, atol=1e-9)
    farther, _ = GeometryBound(gp, sun=sun, observer=observer, range_m=8e7)(q=q, m_past=torch.zeros(9, dtype=F64))
    assert torch.allclose(farther - mean, torch.full_like(mean, 5 * math.log10(2.0)), atol=1e-12)


def test_binding_needs_a_body_geometry_gp(gp):
    wrong = SparseGP(gp.inputs, gp.z, gp.w, gp.p, gp.y_mean, gp.outputscale, gp.lengthscale, gp.noise,
                     config={**gp.config, "inputs": "attitude_matrix"})
    with pytest.raises(ValueError, match="^model.inputs: binding a geometry needs a body_geometry GP"):
        GeometryBound(wrong, sun=torch.ones(3, dtype=F64), observer=torch.ones(3, dtype=F64), range_m=1.0)
    assert bind_geometry(wrong, sun=torch.ones(3, dtype=F64), observer=torch.ones(3, dtype=F64), range_m=1.0) is wrong


def _pass_scene(T, seed=10):
    cfg = load_config(ROOT / "configs" / "boxwing.yaml")
    fixed = Scene.from_config(cfg, rho=0.5)
    sun = _unit(fixed.sun + 0.3 * _random((T, 3), seed))
    observer = _unit(fixed.observer + 0.3 * _random((T, 3), seed + 1))
    return fixed, Scene(fixed.facets, sun, observer, fixed.r_obs * (1 + 0.1 * torch.rand(T, dtype=F64)))


def test_along_pass_predicts_each_sample_with_its_geometry():
    from lightcurve_gp.passes.geometry import PassGeometry

    T = 6
    _, scene = _pass_scene(T)
    geometry = PassGeometry.from_columns(times_s=torch.arange(T), sun=scene.sun, observer=scene.observer,
                                         range_m=scene.r_obs)
    model = AlongPass(Parametric(scene, 0.5), geometry, first=1)
    q = _unit(_random((T, 2, 3, 4), 12))
    expected = scene.magnitude(q.permute(1, 2, 0, 3), rho=0.5)  # (2, 3, T): sample along the last dimension
    for k in range(1, T):
        mean, var = model(q=q[k], m_past=torch.zeros(2, 3, dtype=F64))
        assert torch.allclose(mean, expected[..., k], rtol=0, atol=1e-12) and bool((var == 0).all())
    with pytest.raises(RuntimeError, match="called for sample 6 of a pass of 6 samples"):
        model(q=q[0], m_past=torch.zeros(2, 3, dtype=F64))


def test_filter_along_a_constant_pass_equals_the_fixed_filter():
    from lightcurve_gp.passes.geometry import PassGeometry

    T = 40
    fixed, _ = _pass_scene(2)
    geometry = PassGeometry.from_columns(times_s=torch.arange(T + 1), sun=fixed.sun.expand(T + 1, 3),
                                         observer=fixed.observer.expand(T + 1, 3),
                                         range_m=torch.full((T + 1,), fixed.r_obs, dtype=F64))
    q0 = _unit(_random((3, 4), 13))
    inc = _unit(torch.tensor([0.001, -0.002, 0.0015, 1.0], dtype=F64)).expand(T, 4)
    obs = 13.0 + _random((3, T + 1), 14)
    kwargs = dict(q_est0=q0, P0=initial_covariance(10.0, dtype=F64), observations=obs, m_past0=obs[:, 0],
                  increments=inc, params=UsqueParams())
    plain = run_usque(model=Parametric(fixed, 0.5), **kwargs)
    along = run_usque(model=AlongPass(Parametric(fixed, 0.5), geometry), **kwargs)
    assert torch.allclose(plain.q_est, along.q_est, rtol=0, atol=1e-9)
    assert torch.allclose(plain.P, along.P, rtol=0, atol=1e-9)


def test_along_pass_binds_a_body_geometry_gp_sample_by_sample(gp):
    from lightcurve_gp.passes.geometry import PassGeometry

    T = 5
    geometry = PassGeometry.from_columns(times_s=torch.arange(T), sun=_random((T, 3), 20),
                                         observer=_random((T, 3), 21), range_m=3.6e7 + 1e6 * torch.arange(T))
    along = AlongPass(gp, geometry, first=0)
    q = _unit(_random((T, 4, 7, 4), 22))
    for k in range(T):
        bound = GeometryBound(gp, sun=geometry.sun[k], observer=geometry.observer[k], range_m=geometry.range_m[k])
        expected, _ = bound(q=q[k], m_past=torch.zeros(4, 7, dtype=F64))
        mean, _ = along(q=q[k], m_past=torch.zeros(4, 7, dtype=F64))
        assert torch.allclose(mean, expected, rtol=0, atol=1e-12)


def test_along_pass_passes_the_filters_parameters_to_a_surface_state_renderer():
    from lightcurve_gp.observation.parametric import SurfaceStateRenderer
    from lightcurve_gp.observation.surface_state import surface_from_state
    from lightcurve_gp.passes.geometry import PassGeometry

    T = 4
    _, scene = _pass_scene(T, seed=30)
    geometry = PassGeometry.from_columns(times_s=torch.arange(T), sun=scene.sun, observer=scene.observer,
                                         range_m=scene.r_obs)
    along = AlongPass(SurfaceStateRenderer(scene), geometry, first=2)
    q = _unit(_random((2, 3, 4), 31))
    theta = torch.tensor([-0.7, 0.0, 5.0, 6.0], dtype=F64) + 0.1 * _random((2, 3, 4), 32)
    mean, _ = along(q=q, m_past=torch.zeros(2, 3, dtype=F64), theta=theta)
    expected = scene.sample(2).magnitude(q.reshape(-1, 1, 4), surface=surface_from_state(theta.reshape(-1, 4)))
    assert torch.allclose(mean, expected.reshape(2, 3), rtol=0, atol=1e-12)
    assert along.next_sample == 3
