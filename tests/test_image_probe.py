"""The inversion's image probe: along a moving geometry the first sample's inertial turns make near-exact images of a
state, basins of their own; restarted at its images, a state found in the wrong one reaches the truth's."""

import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.rotations import attitude_matrix, quat_mul
from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.config.load import load_config
from lightcurve_gp.inference.answer import answer
from lightcurve_gp.inference.forward import GroupRenderer
from lightcurve_gp.inference.inversion import InversionSettings, polish
from lightcurve_gp.inference.probe_starts import IMAGE_FAMILIES, image_starts
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.photometry.ambiguity import ambiguity_group, inertial_turns, near_image_turns
from lightcurve_gp.photometry.render import Scene

from helpers import tumbler_light_curve

ROOT = Path(__file__).resolve().parents[1]
F64 = torch.float64
T = 300
SIGMA = 0.05
LOG_RHO = math.log(0.5)


@pytest.fixture(scope="module")
def moving():
    """The box-wing with the paper's Sun and an observer turning 0.04 °/s about the z axis (12° over 300 s)."""
    cfg = load_config(ROOT / "configs" / "boxwing.yaml")
    fixed = Scene.from_config(cfg, rho=0.5)
    t = torch.arange(T + 1.0, dtype=F64)
    a = torch.deg2rad(0.04 * t)
    o = fixed.observer / torch.linalg.vector_norm(fixed.observer)
    observer = torch.stack([torch.cos(a) * o[0] - torch.sin(a) * o[1], torch.sin(a) * o[0] + torch.cos(a) * o[1],
                            o[2].expand(T + 1)], -1)
    scene = fixed.with_geometry(fixed.sun.expand(T + 1, 3), observer, torch.full((T + 1,), float(fixed.r_obs),
                                                                                dtype=F64))
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=F64)
    return fixed, scene, t, inertia


def _truth(scene, inertia, seed):
    return tumbler_light_curve(scene, inertia, seed=seed, rate_deg_s=1.5, samples=T, sigma=SIGMA)


def _problem(scene, t, inertia, y):
    return TrajectoryProblem(GroupRenderer(scene), t, y, torch.full((T + 1,), SIGMA, dtype=F64), inertia,
                             torch.zeros(0, 4, dtype=F64))


def test_near_image_turns_exact_at_the_first_sample_only_and_none_under_a_fixed_geometry(moving):
    fixed, scene, _, _ = moving
    assert near_image_turns(fixed).shape == (0, 4)
    turns = near_image_turns(scene)
    assert turns.shape == (3, 4)
    # the first sample's 180° turns about the plane normal, the bisector and the in-plane perpendicular
    expected = inertial_turns(scene.sun[0], scene.observer[0])[1:]
    assert torch.allclose(attitude_matrix(turns), expected, atol=1e-12)
    q = random_attitudes(5, seed=3, dtype=F64)
    images = quat_mul(q[:, None], turns[None])  # (5, 3, 4)
    first = Scene(scene.facets, scene.sun[0], scene.observer[0], float(scene.r_obs[0]))
    last = Scene(scene.facets, scene.sun[-1], scene.observer[-1], float(scene.r_obs[-1]))
    assert (first.magnitude(images) - first.magnitude(q)[:, None]).abs().max() < 1e-9
    assert (last.magnitude(images) - last.magnitude(q)[:, None]).abs().max() > 1e-3


def test_image_starts_compose_each_state_with_each_turn():
    q0 = random_attitudes(2, seed=1, dtype=F64)
    omega0 = torch.tensor([[0.01, 0.02, -0.03], [0.0, 0.04, 0.0]], dtype=F64)
    log_rho = torch.tensor([-0.5, -1.0], dtype=F64)
    turns = random_attitudes(3, seed=2, dtype=F64)
    q, x = image_starts(turns, q0=q0, omega0=omega0, log_rho=log_rho)
    assert q.shape == (6, 4) and x.shape == (6, 7)
    for i in range(2):
        for j in range(3):
            assert torch.allclose(q[3 * i + j], quat_mul(q0[i], turns[j]))
            assert torch.equal(x[3 * i + j, :3], torch.zeros(3, dtype=F64))
            assert torch.equal(x[3 * i + j, 3:6], omega0[i]) and float(x[3 * i + j, 6]) == float(log_rho[i])


@pytest.mark.parametrize("seed", [0, 2])
def test_from_an_image_basin_the_probe_reaches_the_truths(moving, seed):
    _, scene, t, inertia = moving
    q0, w0, y = _truth(scene, inertia, seed)
    problem = _problem(scene, t, inertia, y)
    x0 = torch.cat([torch.zeros(3, dtype=F64), w0, torch.tensor([LOG_RHO], dtype=F64)])
    basin = polish(problem, q0[None], x0[None], iterations=12)
    turns = near_image_turns(scene)
    q, x = image_starts(turns, q0=q0[None], omega0=w0[None], log_rho=torch.tensor([LOG_RHO], dtype=F64))
    wrong = polish(problem, q, x, iterations=12)  # the images' own basins: worse than the truth's by > 1 nat
    assert bool((wrong.cost > basin.cost[0] + 1.0).all())
    q, x = image_starts(turns, q0=wrong.q0, omega0=wrong.omega0, log_rho=wrong.log_rho)
    back = polish(problem, q, x, iterations=8).cost.reshape(3, 3).diagonal()  # each image basin's own turn back
    assert torch.allclose(back, basin.cost[0].expand(3), atol=1e-3)


@pytest.mark.slow
def test_answer_runs_the_probe_on_its_leading_families(moving):
    _, scene, t, inertia = moving
    q0, w0, y = _truth(scene, inertia, 0)
    problem = _problem(scene, t, inertia, y)
    group = ambiguity_group(scene, times_s=t, inertia=inertia, rate_known=False, probes=2)
    settings = InversionSettings(starts=128, attitudes=64, arcs_s=(30.0, 80.0, 0.0), keep=(32, 8))
    plain = answer(problem, group, settings=settings, ridge=False, local=False, far=False, widen=False)
    probed = answer(problem, group, settings=settings, ridge=False, local=False, far=False, widen=False,
                    image_turns=near_image_turns(scene))
    assert "image" not in plain.probe_rows and "image probe" not in plain.seconds
    assert probed.probe_rows["image"] == 3 * min(IMAGE_FAMILIES, len(plain.families))
    assert probed.as_dict()["probe_rows"]["image"] == probed.probe_rows["image"]
    # the probe only adds solutions: the best fit found can only improve
    assert float(probed.inversion.cost.min()) <= float(plain.inversion.cost.min()) + 1e-9
