"""The answer's far probes: a state found under a body axis rotation that is not an exact image, or at a harmonic of
the truth's rate, is restarted where the truth's basin is (the body-turn and the harmonic probe)."""

import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.rotations import attitude_matrix, quat_mul, rotvec_to_quat
from lightcurve_gp.config.load import load_config
from lightcurve_gp.inference.answer import answer
from lightcurve_gp.inference.forward import GroupRenderer
from lightcurve_gp.inference.inversion import InversionSettings, polish
from lightcurve_gp.inference.probe_starts import (
    BODY_TURN_FAMILIES,
    HARMONIC_FACTORS,
    HARMONIC_TILTS_DEG,
    LOCAL_ITERATIONS,
    RIDGE_AZIMUTHS,
    body_turn_starts,
    harmonic_starts,
    near_body_turns,
    restarted_at,
)
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.photometry.ambiguity import ambiguity_group
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.photometry.symmetry import cube_rotations

from helpers import families_of, tumbler_light_curve

ROOT = Path(__file__).resolve().parents[1]
F64 = torch.float64
T = 300
SIGMA = 0.1
LOG_RHO = torch.tensor([math.log(0.5)], dtype=F64)
RANGE = (0.05, 5.0)


@pytest.fixture(scope="module")
def boxwing():
    cfg = load_config(ROOT / "configs" / "boxwing.yaml")
    scene = Scene.from_config(cfg, rho=0.5)
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=F64)
    group = ambiguity_group(scene, times_s=torch.arange(T + 1.0, dtype=F64), inertia=inertia, rate_known=False,
                            probes=2)
    return scene, inertia, group


def _problem(scene, inertia, y):
    return TrajectoryProblem(GroupRenderer(scene), torch.arange(T + 1.0, dtype=F64), y,
                             torch.full((T + 1,), SIGMA, dtype=F64), inertia, torch.zeros(0, 4, dtype=F64))


def _state(w):
    return torch.cat([torch.zeros(3, dtype=F64), w, LOG_RHO])[None]


def test_near_body_turns_are_the_axis_rotations_outside_the_group(boxwing):
    _, _, group = boxwing
    exact = attitude_matrix(group.body)
    near = near_body_turns(group)
    turns = attitude_matrix(near.body)
    assert torch.allclose(near.inertial, torch.tensor([0.0, 0, 0, 1], dtype=F64).expand(20, 4))
    distinct = {tuple(m.round().flatten().tolist()) for m in exact}
    assert len(distinct) == 4  # the box-wing's body images: the identity and the 180° turns about x, y, z
    assert turns.shape == (24 - 4, 3, 3)
    cube = {tuple(m.flatten().tolist()) for m in cube_rotations(dtype=F64)}
    found = {tuple(m.round().flatten().tolist()) for m in turns}
    assert len(found) == 20 and found <= cube and not (found & distinct)
    assert torch.allclose(turns, turns.round(), atol=1e-12)  # signed permutations, as quaternions and back


def test_body_turn_starts_turn_the_attitude_and_the_rate_with_the_body(boxwing):
    scene, inertia, group = boxwing
    q0, w0, y = tumbler_light_curve(scene, inertia, seed=0, rate_deg_s=2.0, samples=T, sigma=SIGMA)
    problem = _problem(scene, inertia, y)
    fam = families_of(group, polish(problem, q0[None], _state(w0), iterations=2), problem)
    turns = near_body_turns(group)
    q, x = body_turn_starts(turns, fam)
    n = min(BODY_TURN_FAMILIES, len(fam))
    assert q.shape == (n * 20, 4) and x.shape == (n * 20, 7)
    rot = attitude_matrix(turns.body)
    for k in range(20):  # A(q_R ⊗ q) = R A(q) and ω ↦ R ω; θ = 0, ln ρ kept
        assert torch.allclose(attitude_matrix(q[k]), rot[k] @ attitude_matrix(fam.q0[0]), atol=1e-12)
        assert torch.allclose(x[k, 3:6], rot[k] @ fam.omega0[0], atol=1e-15)
    assert bool((x[:, :3] == 0).all()) and torch.allclose(x[:20, 6], fam.log_rho[0].expand(20))


@pytest.mark.slow
def test_from_a_body_turned_basin_the_probe_reaches_the_truths(boxwing):
    scene, inertia, group = boxwing
    q0, w0, y = tumbler_light_curve(scene, inertia, seed=1, rate_deg_s=2.0, samples=T, sigma=SIGMA)
    problem = _problem(scene, inertia, y)
    basin = polish(problem, q0[None], _state(w0), iterations=LOCAL_ITERATIONS)
    turns = near_body_turns(group)
    rot = attitude_matrix(turns.body)
    # the truth turned by 90° about x (a face of the box onto another; the wings and the inertia break it)
    quarter_x = torch.tensor([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]], dtype=F64)
    k = next(i for i in range(len(rot)) if torch.allclose(rot[i], quarter_x, atol=1e-12))
    wrong = polish(problem, quat_mul(turns.body[k], q0)[None], _state(rot[k] @ w0), iterations=8)
    assert float(wrong.cost[0]) > float(basin.cost[0]) + 25.0
    q, x = body_turn_starts(turns, families_of(group, wrong, problem))
    back = polish(problem, q, x, iterations=LOCAL_ITERATIONS)
    assert float(back.cost.min()) == pytest.approx(float(basin.cost[0]), abs=1e-3)


def test_harmonic_starts_hold_each_factor_and_tilt_and_keep_the_middle_attitude(boxwing):
    scene, inertia, group = boxwing
    q0, w0, y = tumbler_light_curve(scene, inertia, seed=2, rate_deg_s=1.0, samples=T, sigma=SIGMA)
    problem = _problem(scene, inertia, y)
    fam = families_of(group, polish(problem, q0[None], _state(w0), iterations=2), problem)
    q, x = harmonic_starts(fam, span_s=float(T), rate_range_deg_s=RANGE)
    per = (1 + len(HARMONIC_TILTS_DEG) * RIDGE_AZIMUTHS) * len(HARMONIC_FACTORS)
    assert x.shape == (per * len(fam), 7)
    w = fam.omega0[0]
    ratio = torch.linalg.vector_norm(x[:per, 3:6], dim=-1) / torch.linalg.vector_norm(w)
    assert torch.allclose(ratio, torch.tensor(HARMONIC_FACTORS, dtype=F64).repeat(per // len(HARMONIC_FACTORS)))
    cosine = (x[:per, 3:6] @ w) / (torch.linalg.vector_norm(x[:per, 3:6], dim=-1) * torch.linalg.vector_norm(w))
    tilt = torch.rad2deg(torch.arccos(cosine.clamp(-1.0, 1.0))).reshape(-1, len(HARMONIC_FACTORS))[:, 0]
    expected = torch.tensor([0.0] + [t for t in HARMONIC_TILTS_DEG for _ in range(RIDGE_AZIMUTHS)], dtype=F64)
    assert torch.allclose(tilt, expected, atol=1e-5)
    mid = quat_mul(rotvec_to_quat(x[:per, 3:6] * T / 2), q[:per])
    kept = quat_mul(rotvec_to_quat(w * T / 2), fam.q0[0]).expand(per, 4)
    assert float(torch.minimum((mid - kept).abs().amax(-1), (mid + kept).abs().amax(-1)).max()) < 1e-12


def test_harmonic_starts_leave_out_rates_outside_the_range(boxwing):
    scene, inertia, group = boxwing
    q0, w0, y = tumbler_light_curve(scene, inertia, seed=3, rate_deg_s=4.0, samples=T, sigma=SIGMA)
    problem = _problem(scene, inertia, y)
    q, x = restarted_at(w0[None, None], q0=q0[None], omega0=w0[None], log_rho=LOG_RHO, span_s=float(T))
    fam = families_of(group, polish(problem, q, x, iterations=0), problem)
    _, x = harmonic_starts(fam, span_s=float(T), rate_range_deg_s=RANGE)
    rates = torch.rad2deg(torch.linalg.vector_norm(x[:, 3:6], dim=-1))
    # 4 °/s: 1.5× and 2× leave the 5 °/s range, ½× and ⅔× stay (13 axes each)
    assert x.shape[0] == 2 * 13 * len(fam) and float(rates.max()) < 5.0
    assert sorted({round(float(r), 6) for r in rates}) == pytest.approx([2.0, 8.0 / 3.0], abs=1e-6)


@pytest.mark.slow
def test_answer_runs_the_far_probes_and_they_only_add(boxwing):
    scene, inertia, group = boxwing
    q0, w0, y = tumbler_light_curve(scene, inertia, seed=4, rate_deg_s=1.5, samples=T, sigma=SIGMA)
    problem = _problem(scene, inertia, y)
    settings = InversionSettings(starts=128, attitudes=64, arcs_s=(30.0, 80.0, 0.0), keep=(32, 8))
    plain = answer(problem, group, settings=settings, ridge=False, local=False, far=False, widen=False)
    probed = answer(problem, group, settings=settings, ridge=False, local=False, widen=False)
    assert "body turn" not in plain.probe_rows and "harmonic" not in plain.probe_rows
    assert probed.probe_rows["body turn"] == 20 * min(BODY_TURN_FAMILIES, len(plain.families))
    assert probed.probe_rows["harmonic"] > 0 and "local again" not in probed.probe_rows  # no local probe asked
    assert float(probed.inversion.cost.min()) <= float(plain.inversion.cost.min()) + 1e-9
