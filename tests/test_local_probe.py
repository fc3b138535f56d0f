"""The answer's local probe: a state stopped a few per cent off in rate, in a neighbouring basin, is brought back to
the truth's basin by the restarts about it; the starts keep the attitude at the middle of the arc."""

import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.rotations import quat_mul, rotvec_to_quat
from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.config.load import load_config
from lightcurve_gp.inference.forward import GroupRenderer
from lightcurve_gp.inference.inversion import polish
from lightcurve_gp.inference.probe_starts import (
    LOCAL_FACTORS,
    LOCAL_FAMILIES,
    LOCAL_ITERATIONS,
    LOCAL_TILTS_DEG,
    RIDGE_AZIMUTHS,
    local_starts,
    restarted_at,
)
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.photometry.ambiguity import ambiguity_group
from lightcurve_gp.photometry.render import Scene

from helpers import families_of, tumbler_light_curve

ROOT = Path(__file__).resolve().parents[1]
F64 = torch.float64
T = 600
SIGMA = 0.1
LOG_RHO = torch.tensor([math.log(0.5)], dtype=F64)


@pytest.fixture(scope="module")
def boxwing():
    cfg = load_config(ROOT / "configs" / "boxwing.yaml")
    scene = Scene.from_config(cfg, rho=0.5)
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=F64)
    group = ambiguity_group(scene, times_s=torch.arange(T + 1.0, dtype=F64), inertia=inertia, rate_known=False,
                            probes=2)
    return scene, inertia, group


def _case(scene, inertia, seed):
    q0, w0, y = tumbler_light_curve(scene, inertia, seed=seed, rate_deg_s=2.0, samples=T, sigma=SIGMA)
    problem = TrajectoryProblem(GroupRenderer(scene), torch.arange(T + 1.0, dtype=F64), y,
                                torch.full((T + 1,), SIGMA, dtype=F64), inertia, torch.zeros(0, 4, dtype=F64))
    return problem, q0, w0


def test_restarts_keep_the_attitude_at_the_middle_of_the_arc():
    q0 = random_attitudes(2, seed=4, dtype=F64)
    w0 = torch.tensor([[0.01, -0.02, 0.03], [0.0, 0.02, -0.01]], dtype=F64)
    omega = torch.stack([w0 * 1.05, w0 * 0.9], 1)  # (2, 2, 3)
    q, x = restarted_at(omega, q0=q0, omega0=w0, log_rho=torch.tensor([-0.3, -0.7], dtype=F64), span_s=600.0)
    assert q.shape == (4, 4) and x.shape == (4, 7)
    for i in range(2):
        for j in range(2):
            k = 2 * i + j
            mid = quat_mul(rotvec_to_quat(x[k, 3:6] * 300.0), q[k])
            expected = quat_mul(rotvec_to_quat(w0[i] * 300.0), q0[i])
            assert min(float((mid - expected).abs().max()), float((mid + expected).abs().max())) < 1e-12
            assert torch.allclose(x[k, 3:6], omega[i, j]) and float(x[k, 6]) == [-0.3, -0.7][i]


def test_local_starts_are_the_family_its_rate_factors_and_its_tilted_axes(boxwing):
    scene, inertia, group = boxwing
    problem, q0, w0 = _case(scene, inertia, 0)
    x0 = torch.cat([torch.zeros(3, dtype=F64), w0, LOG_RHO])[None]
    fam = families_of(group, polish(problem, q0[None], x0, iterations=4), problem)
    q, x = local_starts(fam, span_s=600.0)
    per = 1 + len(LOCAL_FACTORS) + len(LOCAL_TILTS_DEG) * RIDGE_AZIMUTHS
    assert x.shape == (per * len(fam), 7)
    w = fam.omega0[0]
    assert torch.allclose(q[0], fam.q0[0]) and torch.allclose(x[0, 3:6], w)  # the family itself first
    ratios = torch.linalg.vector_norm(x[1:1 + len(LOCAL_FACTORS), 3:6], dim=-1) / torch.linalg.vector_norm(w)
    assert torch.allclose(ratios, torch.tensor(LOCAL_FACTORS, dtype=F64))
    axes = x[1 + len(LOCAL_FACTORS):per, 3:6]
    cosine = (axes @ w) / (torch.linalg.vector_norm(axes, dim=-1) * torch.linalg.vector_norm(w))
    tilts = torch.rad2deg(torch.arccos(cosine.clamp(-1, 1)))
    expected = torch.tensor([t for t in LOCAL_TILTS_DEG for _ in range(RIDGE_AZIMUTHS)], dtype=F64)
    assert torch.allclose(tilts, expected, atol=1e-6)


def test_settling_restarts_the_leading_families_from_themselves_and_ends_a_polish_stopped_short(boxwing):
    scene, inertia, group = boxwing
    problem, q0, w0 = _case(scene, inertia, 0)
    x0 = torch.cat([torch.zeros(3, dtype=F64), w0, LOG_RHO])[None]
    basin = polish(problem, q0[None], x0, iterations=LOCAL_ITERATIONS)
    # 5.7° off the truth about y, one iteration: a polish stopped short of its basin (hundreds of nats above it)
    turned = quat_mul(rotvec_to_quat(torch.tensor([[0.0, 0.1, 0.0]], dtype=F64)), q0[None])
    stopped = polish(problem, turned, x0, iterations=1)
    assert float(stopped.cost[0]) > float(basin.cost[0]) + 100.0
    short = families_of(group, stopped, problem)
    q, x = local_starts(short, span_s=600.0, factors=(), tilts_deg=())
    assert x.shape == (min(LOCAL_FAMILIES, len(short)), 7)
    torch.testing.assert_close(q, short.q0, rtol=0.0, atol=1e-12)
    torch.testing.assert_close(x[:, 3:6], short.omega0, rtol=0.0, atol=1e-15)
    assert float(x[:, :3].abs().max()) == 0.0 and torch.equal(x[:, 6], short.log_rho)
    settled = polish(problem, q, x, iterations=LOCAL_ITERATIONS)
    assert float(settled.cost.min()) - float(basin.cost[0]) < 0.1


@pytest.mark.slow
@pytest.mark.parametrize(("seed", "factor"), [(0, 1.08), (3, 1.05)])
def test_from_a_neighbouring_rate_basin_the_local_probe_reaches_the_truths(boxwing, seed, factor):
    scene, inertia, group = boxwing
    problem, q0, w0 = _case(scene, inertia, seed)
    basin = polish(problem, q0[None], torch.cat([torch.zeros(3, dtype=F64), w0, LOG_RHO])[None],
                   iterations=LOCAL_ITERATIONS)
    q, x = restarted_at((w0 * factor)[None, None], q0=q0[None], omega0=w0[None], log_rho=LOG_RHO, span_s=600.0)
    off = polish(problem, q, x, iterations=8)  # a few per cent off in rate: another basin, > 25 nats worse
    assert float(off.cost[0]) > float(basin.cost[0]) + 25.0
    q, x = local_starts(families_of(group, off, problem), span_s=600.0)
    back = polish(problem, q, x, iterations=LOCAL_ITERATIONS)
    assert float(back.cost.min()) == pytest.approx(float(basin.cost[0]), abs=1e-3)
