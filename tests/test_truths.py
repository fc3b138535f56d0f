"""Random truths of the generalisation suite: per-seed reproducibility, ranges, the P0 rule, per-object surfaces."""

import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.rotations import attitude_matrix, quat_conj, quat_mul, quat_to_rotvec, rotvec_to_quat
from lightcurve_gp.config.load import load_config
from lightcurve_gp.inference.surface import cumulative_increments
from lightcurve_gp.photometry.brdf import Surface, ashikhmin_shirley
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.photometry.shapes import box_wing
from lightcurve_gp.simulation.scenario import simulate_scenario, simulate_truths
from lightcurve_gp.simulation.truths import (
    SPECULAR_CLASSES,
    TruthRanges,
    draw_truths,
    paper_case_draw,
    specular_class,
    specular_share,
)

DT = torch.float64
CONFIG = Path(__file__).resolve().parents[1] / "configs" / "boxwing_robust.yaml"


def random_quats(*shape, seed=0):
    q = torch.randn(*shape, 4, generator=torch.Generator().manual_seed(seed), dtype=DT)
    return q / q.norm(dim=-1, keepdim=True)


@pytest.fixture(scope="module")
def scene():
    return Scene.from_config(load_config(CONFIG), dtype=DT)


def test_a_seed_draws_the_same_truth_in_any_batch():
    alone = draw_truths([7])
    batch = draw_truths([5, 7, 9])
    for a, b in [(alone.q0, batch.q0), (alone.omega0, batch.omega0), (alone.error, batch.error),
                 (alone.sigma0, batch.sigma0), *zip(alone.surface, batch.surface)]:
        assert torch.equal(a[0], b[1])
    assert not torch.equal(batch.q0[0], batch.q0[1])


def test_draws_respect_the_ranges_and_the_p0_rule():
    r = TruthRanges()
    d = draw_truths(range(3000))
    omega = torch.rad2deg(d.omega0.norm(dim=-1))
    assert float(omega.min()) >= r.omega_deg_s[0] and float(omega.max()) <= r.omega_deg_s[1]
    assert torch.allclose(d.q0.norm(dim=-1), torch.ones(3000, dtype=DT))
    for field, (lo, hi) in [("rho", r.rho), ("f0", r.f0), ("n_u", r.lobe_exponent), ("n_v", r.lobe_exponent)]:
        value = getattr(d.surface, field)
        assert float(value.min()) >= lo and float(value.max()) <= hi, field
    typical = torch.rad2deg(d.sigma0) * math.sqrt(3.0)
    assert float(typical.min()) >= 5.0 and float(typical.max()) <= 20.0
    # e ~ N(0, σ0² I): |e|²/σ0² ~ χ²(3), mean 3 with standard error sqrt(6/3000) = 0.045
    normalised = d.error.pow(2).sum(-1) / d.sigma0.pow(2)
    assert abs(float(normalised.mean()) - 3.0) < 0.2
    # log-uniform |ω0|: the median is the geometric mean of the bounds, sqrt(0.05 * 1.5) = 0.27 deg/s
    assert abs(float(omega.median()) / math.sqrt(0.05 * 1.5) - 1.0) < 0.1


def test_fixed_angle_mode_keeps_the_truth_and_the_axis():
    random, fixed = draw_truths(range(20)), draw_truths(range(20), error_deg=30.0)
    assert torch.equal(random.q0, fixed.q0) and torch.equal(random.omega0, fixed.omega0)
    assert torch.allclose(torch.rad2deg(fixed.error.norm(dim=-1)), torch.full((20,), 30.0, dtype=DT))
    axis = lambda e: e / e.norm(dim=-1, keepdim=True)  # noqa: E731
    assert torch.allclose(axis(random.error), axis(fixed.error))
    assert torch.allclose(fixed.sigma0, torch.full((20,), math.radians(30.0) / math.sqrt(3.0), dtype=DT))
    with pytest.raises(ValueError, match="error_deg"):
        draw_truths([1], error_deg=0.0)


def test_initial_estimate_is_the_error_rotation_applied_to_the_truth():
    d = draw_truths(range(5))
    err = quat_mul(d.q_est0, quat_conj(d.q0))
    assert torch.allclose(quat_to_rotvec(err), d.error, atol=1e-12)


def test_batched_surfaces_equal_one_object_at_a_time(scene):
    B = 4
    q = random_quats(B, 9, seed=1)
    g = torch.Generator().manual_seed(2)
    surface = Surface(torch.rand(B, generator=g, dtype=DT), torch.rand(B, generator=g, dtype=DT),
                      10 ** (1 + 3 * torch.rand(B, generator=g, dtype=DT)),
                      10 ** (1 + 3 * torch.rand(B, generator=g, dtype=DT)))
    diffuse, specular = scene.flux_parts(q, surface=surface)
    for b in range(B):
        facets = scene.facets.with_surface(rho=surface.rho[b], f0=surface.f0[b], n_u=surface.n_u[b],
                                           n_v=surface.n_v[b])
        d1, s1 = Scene(facets, scene.sun, scene.observer, scene.r_obs).flux_parts(q[b])
        assert torch.allclose(diffuse[b], d1, rtol=1e-12, atol=1e-15)
        assert torch.allclose(specular[b], s1, rtol=1e-12, atol=1e-15)
    one = Surface(*(t[:1] for t in surface))  # a (1,) surface broadcasts over the batch
    assert torch.allclose(scene.flux(q, surface=one)[2], scene.flux(q[2:3], surface=one)[0], rtol=1e-12)
    with pytest.raises(ValueError, match=r"surface.rho: expected shape \(4,\) or \(1,\)"):
        scene.flux(q, surface=Surface(*(t[:2] for t in surface)))
    with pytest.raises(ValueError, match="rho or surface"):
        scene.flux(q, rho=0.3, surface=surface)


def test_specular_share_matches_a_facet_by_facet_computation():
    facets = box_wing([1.0, 1.0, 1.3], 1, [1.0, 2.0, 0.1], 1, rho=0.3, f0=0.6, n_u=30.0, n_v=300.0, dtype=DT)
    sun, observer = torch.tensor([1.0, 0.2, 0.1], dtype=DT), torch.tensor([0.8, -0.3, 0.4], dtype=DT)
    scene = Scene(facets, sun, observer, 3.6e7, grouped=False)
    q = random_quats(2, 5, seed=4)
    surface = Surface(*(torch.tensor(v, dtype=DT) for v in ([0.3, 0.7], [0.6, 0.1], [30.0, 2000.0], [300.0, 15.0])))
    shares = specular_share(scene, q, surface)
    s_in, v_in = sun / sun.norm(), observer / observer.norm()
    for b in range(2):
        ratios = []
        for k in range(5):
            A = attitude_matrix(q[b, k])
            s, v = A @ s_in, A @ v_in
            lit = ((facets.normals @ s) > 0) & ((facets.normals @ v) > 0)
            cd, cs = ashikhmin_shirley(s, v, facets.normals, facets.u, facets.v, surface.rho[b], surface.f0[b],
                                       surface.n_u[b], surface.n_v[b])
            weight = facets.areas * (facets.normals @ s) * (facets.normals @ v) * lit
            ratios.append(float((cs * weight).sum() / ((cd + cs) * weight).sum()))
        assert float(shares[b]) == pytest.approx(sum(ratios) / 5, rel=1e-10)


def test_specular_share_vanishes_in_the_fresnel_free_limit(scene):
    # F0 = 0 leaves F = (1 - v.h)^5 = 4.6e-8 at the 29.8 deg phase angle: the flux is Lambert-like diffuse
    q = random_quats(1, 200, seed=5)
    lambert_like = Surface(*(torch.tensor([v], dtype=DT) for v in (0.5, 0.0, 10.0, 10.0)))
    glossy = Surface(*(torch.tensor([v], dtype=DT) for v in (0.5, 0.9, 10.0, 10.0)))
    assert float(specular_share(scene, q, lambert_like)) < 1e-6
    assert float(specular_share(scene, q, glossy)) > 0.01


def test_specular_classes_have_the_documented_boundaries():
    share = torch.tensor([0.0, 0.0099, 0.01, 0.3, 0.30001, 1.0], dtype=DT)
    assert specular_class(share).tolist() == [0, 0, 1, 1, 2, 2]
    assert [c[0] for c in SPECULAR_CLASSES] == ["<1 %", "1-30 %", ">30 %"]


def test_simulated_truths_follow_their_own_spin_and_noise():
    cfg = load_config(CONFIG, ["scenario.duration_s=20.0", "evaluation.rmse_window_s=[10.0, 20.0]"])
    d = draw_truths([3, 11])
    truths = simulate_truths(cfg, d)
    single = simulate_truths(cfg, draw_truths([11]))
    assert torch.equal(truths.observations[1], single.observations[0])
    assert torch.equal(truths.q_true[1], single.q_true[0])
    q_ref, _ = propagate(d.q0[0], d.omega0[0], torch.tensor(cfg.shape.inertia_kg_m2, dtype=DT), 1.0, 20)
    assert torch.allclose(truths.q_true[0], q_ref, atol=1e-14)
    # the cumulative increments move any initial attitude along the same rate history
    assert torch.allclose(quat_mul(cumulative_increments(truths.increments), d.q0.unsqueeze(1)), truths.q_true,
                          atol=1e-13)
    assert truths.P0.shape == (2, 3, 3) and torch.allclose(truths.P0[1], d.sigma0[1] ** 2 * torch.eye(3, dtype=DT))
    # ω is known exactly: the rate the filters assume is the truth's
    assert torch.equal(truths.increments_assumed, truths.increments) and torch.equal(truths.omega_est0, d.omega0)
    assert truths.rho_true is None and truths.specular_share.shape == (2,) and truths.steps == 20


def test_conjugation_by_an_increment_turns_a_rotation_vector_by_its_attitude_matrix():
    # the MAP turns its initial-attitude covariance to time t with A(Δ_t): Δ ⊗ q(e) ⊗ Δ⁻¹ = q(A(Δ) e)
    delta, e = random_quats(6, seed=6), 0.2 * torch.randn(6, 3, generator=torch.Generator().manual_seed(7), dtype=DT)
    turned = quat_to_rotvec(quat_mul(quat_mul(delta, rotvec_to_quat(e)), quat_conj(delta)))
    assert torch.allclose(turned, (attitude_matrix(delta) @ e.unsqueeze(-1)).squeeze(-1), atol=1e-12)


def test_the_paper_case_draw_is_the_scenario_command_seed_by_seed():
    cfg = load_config(CONFIG)
    seeds = [3, 0]
    truths = simulate_truths(cfg, paper_case_draw(cfg, seeds, rho=0.7))
    sc = simulate_scenario(cfg, seeds=seeds, rho_true=0.7)
    assert truths.seeds == sc.seeds and torch.equal(truths.times, sc.times)
    for name in ("q_true", "omega_true", "increments", "increments_assumed", "omega_assumed"):
        assert getattr(sc, name).shape == getattr(truths, name).shape, name
        assert torch.allclose(getattr(truths, name), getattr(sc, name), atol=1e-12, rtol=0), name
    assert torch.allclose(truths.observations, sc.observations, atol=1e-10, rtol=0)
    assert torch.allclose(truths.q_est0, sc.q_est0, atol=1e-12, rtol=0)
    assert torch.allclose(truths.error, sc.error, atol=1e-15, rtol=0)
    assert all(torch.allclose(a, b, atol=0, rtol=1e-15) for a, b in zip(truths.surface, sc.surface))
    assert torch.equal(truths.sigma0, sc.sigma0)
    assert torch.allclose(truths.P0, torch.deg2rad(torch.tensor(cfg.filter.p0_deg, dtype=DT)) ** 2
                          * torch.eye(3, dtype=DT).expand(2, 3, 3), atol=1e-15, rtol=0)
    assert sc.rho_true == 0.7 and truths.rho_true is None
    with pytest.raises(ValueError, match=r"rho: 0 must lie in \(0, 1\]"):
        paper_case_draw(cfg, seeds, rho=0)
