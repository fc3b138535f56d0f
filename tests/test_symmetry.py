"""Symmetries of a facet model: the box-wing's four rotations, checked against the mesh's own vertices and against
the renderer's light curves along the paper's trajectory."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from experiments.global_start import symmetric_scores, window_scores
from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.rotations import attitude_matrix, matrix_to_quat, quat_mul
from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation.harness import scenario_ambiguity_group
from lightcurve_gp.evaluation.scoring import Estimate, score
from lightcurve_gp.photometry.ambiguity import ambiguity_group
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.photometry.shapes import box_wing_mesh, facets_from_config, facets_from_mesh
from lightcurve_gp.photometry.symmetry import cube_rotations, symmetry_quaternions, symmetry_rotations
from lightcurve_gp.simulation.scenario import simulate_scenario


@pytest.fixture(scope="module")
def paper_case():
    """The paper's config (configs/boxwing.yaml) and its box-wing's facets at ρ = 0.5."""
    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "boxwing.yaml")
    return cfg, facets_from_config(cfg, rho=0.5)


def _as_set(rotations: torch.Tensor) -> set:
    return {tuple(int(v) for v in m.round().flatten()) for m in rotations}


def test_cube_rotations_are_the_24_proper_ones():
    r = cube_rotations()
    assert r.shape == (24, 3, 3) and len(_as_set(r)) == 24
    assert torch.allclose(torch.linalg.det(r), torch.ones(24, dtype=r.dtype))
    assert torch.allclose(r @ r.mT, torch.eye(3, dtype=r.dtype).expand(24, 3, 3))
    assert torch.equal(r[0], torch.eye(3, dtype=r.dtype))


def test_box_wing_group_matches_the_mesh_vertices(paper_case):
    cfg, facets = paper_case
    """Independent computation: the candidates that map the mesh's vertex set onto itself (trimesh's vertices,
    rounded) are the renderer's symmetries, and they are the identity and the three 180° axis turns."""
    s = cfg.shape
    vertices = np.asarray(box_wing_mesh(s.box_m, s.box_grid, s.wing_m, s.wing_grid).vertices)
    reference = {tuple(v) for v in np.round(vertices, 9) + 0.0}
    geometric = [m for m in cube_rotations() if {tuple(v) for v in np.round(vertices @ m.numpy().T, 9) + 0.0}
                 == reference]
    found = symmetry_rotations(facets)
    assert _as_set(found) == _as_set(torch.stack(geometric))
    assert _as_set(found) == {(1, 0, 0, 0, 1, 0, 0, 0, 1), (1, 0, 0, 0, -1, 0, 0, 0, -1),
                              (-1, 0, 0, 0, 1, 0, 0, 0, -1), (-1, 0, 0, 0, -1, 0, 0, 0, 1)}


def test_symmetric_attitudes_render_the_same_light_curve(paper_case):
    cfg, facets = paper_case
    """Along the paper's trajectory: q_R ⊗ q(t) gives the light curve of q(t) for every symmetry and a different
    one (by more than 0.01 mag somewhere) for each of the other 20 axis rotations."""
    q_true = simulate_scenario(cfg, seeds=[0]).q_true
    scene = Scene.from_config(cfg)
    m = scene.magnitude(q_true)
    symmetric = _as_set(symmetry_rotations(facets))
    for rotation in cube_rotations():
        diff = (scene.magnitude(quat_mul(matrix_to_quat(rotation), q_true)) - m).abs().max()
        if _as_set(rotation[None]) <= symmetric:
            assert float(diff) < 1e-12
        else:
            assert float(diff) > 1e-2


def test_anisotropic_cube_symmetries_agree_with_the_renderer():
    """A unit cube is symmetric under all 24 rotations with an isotropic lobe; with n_u ≠ n_v its tangent axes
    break some of them. Whatever the function keeps renders identically; whatever it drops does not."""
    mesh = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    isotropic = facets_from_mesh(mesh, rho=0.5, f0=0.5, n_u=800.0, n_v=800.0)
    assert symmetry_rotations(isotropic).shape[0] == 24
    facets = facets_from_mesh(mesh, rho=0.5, f0=0.5, n_u=20.0, n_v=2.0)  # wide lobes: the anisotropy shows
    kept = _as_set(symmetry_rotations(facets))
    assert 1 <= len(kept) < 24
    scene = Scene(facets, torch.tensor([1.0, 0.3, -0.2], dtype=torch.float64),
                  torch.tensor([0.6, -0.7, 0.4], dtype=torch.float64), 3.6e7)
    q = random_attitudes(64, seed=3, dtype=torch.float64)
    m = scene.magnitude(q)
    for rotation in cube_rotations():
        diff = float((scene.magnitude(quat_mul(matrix_to_quat(rotation), q)) - m).abs().max())
        assert (diff < 1e-12) == (_as_set(rotation[None]) <= kept)


def test_symmetry_quaternions_give_the_rotations(paper_case):
    facets = paper_case[1]
    assert torch.allclose(attitude_matrix(symmetry_quaternions(facets)), symmetry_rotations(facets), atol=1e-15)


def test_the_experiments_score_modulo_symmetry_finds_the_symmetric_truth(paper_case):
    cfg, facets = paper_case
    """An estimate that follows an image ``q_true ⊗ q_C`` of the scenario's derived group (the spin is known: the
    inertial turns) is far off strictly (a 180° turn about an inertial axis) and by nothing modulo the group."""
    sc = simulate_scenario(cfg, seeds=[0])
    q_true = sc.q_true[0]
    group = scenario_ambiguity_group(cfg, sc)
    assert group.rate_known and len(group) == 4 and group.labels[2] == "body identity · inertial bisector"
    q_est = torch.stack([group.attitudes(q_true)[2], q_true])  # (2, T+1, 4)
    window = (400.0, 600.0)
    strict = window_scores(q_true, q_est, sc.times, window)["median_abs"]
    scores = symmetric_scores(q_true, q_est, sc.times, window, group)
    assert float(strict[0].amax()) > 90.0 and float(strict[1].amax()) < 1e-9
    assert float(scores["median_abs"].amax()) < 1e-9
    assert scores["symmetry"].tolist() == [2, 0]


def test_mirrored_rate_trajectory_renders_the_same_light_curve_and_scores_zero_mod_symmetry(paper_case):
    """``(q_R ⊗ q(t), A(q_R) ω(t))`` is a torque-free trajectory of the box-wing (its symmetries are 180° turns
    about the principal axes) with the truth's light curve: the scores modulo symmetry find it, the strict ones
    see a 180° error."""
    cfg, facets = paper_case
    cfg = dataclasses.replace(cfg, scenario=dataclasses.replace(cfg.scenario, duration_s=60.0),
                              evaluation=dataclasses.replace(cfg.evaluation, rmse_window_s=[0.0, 60.0]))
    sc = simulate_scenario(cfg, seeds=[0, 1], rho_true=0.5)
    q_sym = symmetry_quaternions(facets)
    k = 3  # the 180° turn about body z: a yaw flip
    R = attitude_matrix(q_sym[k])
    q_true, omega_true = sc.q_true[0], sc.omega_true[0]  # both seeds share the config's truth
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=q_true.dtype)
    q_m, omega_m = propagate(quat_mul(q_sym[k], q_true[0]), R @ omega_true[0], inertia, cfg.scenario.dt_s, sc.steps)
    assert torch.allclose(q_m, quat_mul(q_sym[k], q_true).expand_as(q_m), atol=1e-10)  # a trajectory
    assert torch.allclose(omega_m, omega_true @ R.mT, atol=1e-12)
    scene = Scene.from_config(cfg, rho=0.5)
    assert torch.allclose(scene.magnitude(q_m), scene.magnitude(q_true), atol=1e-9)  # the same light curve
    q_est = torch.stack([q_true, q_m])  # seed 0 on the truth, seed 1 on its mirror
    group = ambiguity_group(scene, times_s=sc.times, inertia=inertia, rate_known=False,
                            body_candidates=symmetry_rotations(facets))
    image = group.labels.index("body 180° z · inertial identity")
    r = score(sc, Estimate(q_est, None), window=(0.0, 60.0), group=group, grp=(1.0, 4.0), seconds=1.0)
    assert r.symmetry_index.tolist() == [0, image]
    assert torch.allclose(r.rmse_mod_symmetry_deg, torch.zeros(2, 3, dtype=q_est.dtype), atol=1e-6)
    assert r.rmse_deg[1].max() > 170.0 and r.rmse_deg[0].max() < 1e-6
    assert (r.rmse_mod_symmetry_deg <= r.rmse_deg + 1e-9).all()
