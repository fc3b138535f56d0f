"""Carrying a first pass's solution across a long gap: the rate grid and the bridge itself."""

import math

import torch

from lightcurve_gp.attitude.rotations import quat_mul
from lightcurve_gp.attitude.torque_free import torque_free_motion
from lightcurve_gp.config.load import load_config
from lightcurve_gp.inference.bridge import bridge, first_pass_samples, pass_bounds, rate_offsets
from lightcurve_gp.observations import Observations
from lightcurve_gp.observed.inversion_run import trajectory_problem
from lightcurve_gp.photometry.render import Scene

F64 = torch.float64
CONFIG = "configs/boxwing.yaml"


def test_the_rate_grid_spans_its_sigmas_at_a_fraction_of_a_turn_and_holds_zero():
    sigma = torch.tensor([1e-4, 2e-4, 0.0], dtype=F64)
    grid = rate_offsets(sigma, span_s=2000.0, span=3.0, phase_rad=0.5, max_points=100_000)
    step = 0.5 / 2000.0
    assert bool((grid == 0).all(-1).any())  # the first pass's own rate
    assert torch.allclose(grid.max(0).values, torch.tensor([2, 3, 0], dtype=F64) * step)  # ⌈3σ/step⌉ steps
    assert grid.shape == (5 * 7 * 1, 3)
    coarse = rate_offsets(sigma, span_s=2000.0, span=3.0, phase_rad=0.5, max_points=10)
    assert coarse.shape[0] <= 10 and bool((coarse.abs().max(0).values >= 0.9 * 3 * sigma).all())


def test_the_first_pass_ends_at_the_first_long_gap():
    t = torch.tensor([0.0, 1.0, 2.0, 900.0, 901.0, 5000.0], dtype=F64)
    assert first_pass_samples(t) == 3 and first_pass_samples(t[:3]) == 3
    assert first_pass_samples(t, gap_s=5000.0) == 6


def test_a_rate_two_sigma_off_is_carried_to_the_truth_across_half_an_hour():
    """Two 100 s passes 1800 s apart at 0.02 mag; the first pass's rate 2σ off on one axis (σ = 0.01 °/s): 36° of
    turn at the second pass, which the grid crosses and the polish closes to the noise."""
    cfg = load_config(CONFIG, ["scenario.duration_s=100", "evaluation.rmse_window_s=[0, 100]"])
    q0 = torch.tensor([0.2, -0.3, 0.1, 0.927], dtype=F64)
    q0 = q0 / q0.norm()
    w0 = torch.deg2rad(torch.tensor([0.8, -1.1, 0.6], dtype=F64))
    times = torch.cat([torch.arange(0.0, 100.0), 1800.0 + torch.arange(0.0, 100.0)]).to(F64)
    delta, _ = torque_free_motion(w0, inertia=cfg.shape.inertia_kg_m2, times=times)
    y = Scene.from_config(cfg).magnitude(quat_mul(delta, q0), rho=0.5)
    y = y + 0.02 * torch.randn(times.shape, generator=torch.Generator().manual_seed(0), dtype=F64)
    problem, _ = trajectory_problem(cfg, Observations.single(t=times, mag=y, sigma=0.02))
    sigma = math.radians(0.01)
    start = w0 + torch.tensor([2 * sigma, 0.0, 0.0], dtype=F64)
    x = torch.cat([torch.zeros(3, dtype=F64), start, torch.tensor([math.log(0.5)], dtype=F64)])[None]
    covariance = torch.diag(torch.tensor([1e-4] * 3 + [sigma ** 2] * 3 + [1e-4], dtype=F64))[None]
    far = problem.with_anchors(q0[None])
    before = float(0.5 * far.residual(x, torch.zeros(1, dtype=torch.long)).square().sum())
    anchors, out, cost, cov = bridge(problem, anchors=q0[None], x=x, covariance=covariance)
    best = int(cost.argmin())
    assert before > 10 * float(cost[best])  # the starting rate does not fit the second pass
    assert float(cost[best]) < 0.5 * 200 + 3 * math.sqrt(100)  # χ²/2 within its spread: the noise
    assert float((out[best, 3:6] - w0).norm()) < 0.1 * sigma
    assert bool(torch.isfinite(cov[best]).all())


def test_passes_split_at_every_long_gap():
    t = torch.tensor([0.0, 1.0, 2.0, 900.0, 901.0, 5000.0], dtype=F64)
    assert pass_bounds(t) == [(0, 3), (3, 5), (5, 6)]
    assert pass_bounds(t[:3]) == [(0, 3)]


def _two_passes(gap_s: float):
    cfg = load_config(CONFIG, ["scenario.duration_s=100", "evaluation.rmse_window_s=[0, 100]"])
    q0 = torch.tensor([0.2, -0.3, 0.1, 0.927], dtype=F64)
    q0 = q0 / q0.norm()
    w0 = torch.deg2rad(torch.tensor([0.8, -1.1, 0.6], dtype=F64))
    times = torch.cat([torch.arange(0.0, 100.0), gap_s + torch.arange(0.0, 100.0)]).to(F64)
    delta, omega = torque_free_motion(w0, inertia=cfg.shape.inertia_kg_m2, times=times)
    y = Scene.from_config(cfg).magnitude(quat_mul(delta, q0), rho=0.5)
    y = y + 0.02 * torch.randn(times.shape, generator=torch.Generator().manual_seed(0), dtype=F64)
    problem, _ = trajectory_problem(cfg, Observations.single(t=times, mag=y, sigma=0.02))
    return problem, quat_mul(delta, q0), omega


def test_a_state_moved_to_another_epoch_has_the_same_cost_and_a_window_is_its_own_pass():
    """The cost of the truth anchored at the second pass (``with_epoch``) equals that of the truth anchored at the
    first sample: the closed form runs backwards; ``window`` is the second pass alone with its own epoch."""
    problem, q, w = _two_passes(1800.0)
    rho = torch.tensor([math.log(0.5)], dtype=F64)
    row = torch.zeros(1, dtype=torch.long)
    at = lambda p, k: float(0.5 * p.with_anchors(q[k][None]).residual(  # noqa: E731
        torch.cat([torch.zeros(3, dtype=F64), w[k], rho])[None], row).square().sum())
    first, second = at(problem, 0), at(problem.with_epoch(100), 100)
    assert abs(first - second) < 1e-8 * first
    alone = problem.window(100, 200)
    assert float(alone.times[0]) == 0.0 and alone.samples == 100
    own = at(alone, 100)
    assert abs(own + at(problem.arc(100), 0) - second) < 1e-8 * second  # the two passes' costs add up


def test_a_rate_two_sigma_off_at_the_second_pass_is_carried_back_to_the_first():
    """The bridge from the second pass's epoch (earlier samples at negative times) crosses 36° of turn backwards."""
    problem, q, w = _two_passes(1800.0)
    sigma = math.radians(0.01)
    start = w[100] + torch.tensor([2 * sigma, 0.0, 0.0], dtype=F64)
    x = torch.cat([torch.zeros(3, dtype=F64), start, torch.tensor([math.log(0.5)], dtype=F64)])[None]
    covariance = torch.diag(torch.tensor([1e-4] * 3 + [sigma ** 2] * 3 + [1e-4], dtype=F64))[None]
    _, out, cost, _ = bridge(problem.with_epoch(100), anchors=q[100][None], x=x, covariance=covariance)
    best = int(cost.argmin())
    assert float(cost[best]) < 0.5 * 200 + 3 * math.sqrt(100)
    assert float((out[best, 3:6] - w[100]).norm()) < 0.1 * sigma
