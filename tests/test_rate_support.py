"""The prior's rate ball bounds the families: a mode beyond it by more than SUPPORT_SIGMAS of its own rate
standard deviation is no family, one at the edge within them is, and the likelihood-ratio cut runs from the best
mode inside the ball."""

import math
from pathlib import Path

import torch

from lightcurve_gp.config.load import load_config
from lightcurve_gp.inference.answer import best_fit
from lightcurve_gp.inference.families import SUPPORT_SIGMAS, beyond_support, families, prior_precision
from lightcurve_gp.inference.fit_verdict import fit_test
from lightcurve_gp.inference.forward import GroupRenderer
from lightcurve_gp.inference.inversion import Inversion
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup
from lightcurve_gp.photometry.render import Scene

ROOT = Path(__file__).resolve().parents[1]

F64 = torch.float64
R = math.radians(5.0)  # the fastest rate searched, rad/s


def identity_group() -> AmbiguityGroup:
    one = torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=F64)
    return AmbiguityGroup(body=one, inertial=one, labels=("identity",), rate_known=False)


def covariance(rate_var: float) -> torch.Tensor:
    return torch.diag(torch.tensor([1e-6] * 3 + [rate_var] * 3 + [1e-4], dtype=F64))


def bounded_sd(rate_var: float) -> float:
    """The rate's standard deviation after the prior's precision, by hand: ``(1/v + p)^{-1/2}``."""
    p = float(prior_precision(R, dtype=F64)[3])
    return (1.0 / rate_var + p) ** -0.5


def test_a_mode_is_beyond_the_ball_only_past_three_of_its_standard_deviations():
    var = (0.02 * R) ** 2
    sd = bounded_sd(var)
    axis = torch.tensor([0.0, 0.6, 0.8], dtype=F64)
    rates = torch.tensor([0.5 * R, R, R + SUPPORT_SIGMAS * sd * 0.99, R + SUPPORT_SIGMAS * sd * 1.01, 3.0 * R],
                         dtype=F64)
    got = beyond_support(rates[:, None] * axis, covariance(var).expand(5, 7, 7), R)
    assert got.tolist() == [False, False, False, True, True]


def test_a_rate_known_only_across_its_axis_is_judged_by_its_spread_along_it():
    # wide along x (the mode's axis), sharp across: 1.2 R along x is within 3 sd; the same mode along y is not
    cov = torch.diag(torch.tensor([1e-6] * 3 + [(0.2 * R) ** 2, 1e-12, 1e-12, 1e-4], dtype=F64))
    along_x = torch.tensor([[1.2 * R, 0.0, 0.0]], dtype=F64)
    along_y = torch.tensor([[0.0, 1.2 * R, 0.0]], dtype=F64)
    assert not bool(beyond_support(along_x, cov[None], R)[0])
    assert bool(beyond_support(along_y, cov[None], R)[0])


def test_a_covariance_that_is_not_finite_leaves_the_rate_alone_to_decide():
    cov = torch.full((2, 7, 7), math.nan, dtype=F64)
    rates = torch.tensor([[0.0, 0.0, 0.99 * R], [0.0, 0.0, 1.01 * R]], dtype=F64)
    assert beyond_support(rates, cov, R).tolist() == [False, True]


def test_a_better_mode_beyond_the_ball_is_left_out_and_counted_and_the_cut_runs_from_the_best_inside():
    q = torch.tensor([[0.0, 0.0, 0.0, 1.0], [0.6, 0.0, 0.0, 0.8], [0.0, 0.6, 0.0, 0.8]], dtype=F64)
    w = torch.tensor([[0.0, 0.0, 3.0 * R], [0.0, 0.0, 0.5 * R], [0.5 * R, 0.0, 0.0]], dtype=F64)
    # the mode at 3 R fits 15 nats better than the best inside; the third is 8 nats below the best inside
    cost = torch.tensor([100.0, 115.0, 123.0], dtype=F64)
    cov = covariance(1e-10).expand(3, 7, 7)
    sigma = torch.full((100,), 0.1, dtype=F64)
    fam = families(identity_group(), q0=q, omega0=w, log_rho=torch.zeros(3, dtype=F64), cost=cost, covariance=cov,
                   sigma=sigma, rate_max_rad_s=R, max_log_ratio=10.0)
    assert len(fam) == 2 and fam.beyond == 1
    rates = sorted(float(r) for r in torch.linalg.vector_norm(fam.omega0, dim=-1) / R)
    assert rates == [0.5, 0.5]
    torch.testing.assert_close(fam.weight.sum(), torch.tensor(1.0, dtype=F64))
    # without the ball's bound the 3 R mode takes the weight and the third is cut (23 nats below it)
    wide = families(identity_group(), q0=q, omega0=w, log_rho=torch.zeros(3, dtype=F64), cost=cost, covariance=cov,
                    sigma=sigma, rate_max_rad_s=4.0 * R, max_log_ratio=10.0)
    assert len(wide) == 1 and wide.beyond == 0
    assert math.isclose(float(torch.linalg.vector_norm(wide.omega0[0])), 3.0 * R)


def test_when_every_mode_is_beyond_the_ball_they_are_all_kept():
    q = torch.tensor([[0.0, 0.0, 0.0, 1.0], [0.6, 0.0, 0.0, 0.8]], dtype=F64)
    w = torch.tensor([[0.0, 0.0, 2.0 * R], [0.0, 3.0 * R, 0.0]], dtype=F64)
    fam = families(identity_group(), q0=q, omega0=w, log_rho=torch.zeros(2, dtype=F64),
                   cost=torch.tensor([50.0, 52.0], dtype=F64), covariance=covariance(1e-10).expand(2, 7, 7),
                   sigma=torch.full((50,), 0.1, dtype=F64), rate_max_rad_s=R)
    assert len(fam) == 2 and fam.beyond == 0


def test_the_fit_test_judges_the_best_solution_inside_the_ball():
    cfg = load_config(ROOT / "configs" / "boxwing.yaml")
    scene = Scene.from_config(cfg, rho=0.5)
    n = 61
    problem = TrajectoryProblem(GroupRenderer(scene), torch.arange(float(n), dtype=F64), torch.zeros(n, dtype=F64),
                                torch.full((n,), 0.1, dtype=F64), torch.tensor(cfg.shape.inertia_kg_m2, dtype=F64),
                                torch.zeros(0, 4, dtype=F64))
    q = torch.tensor([[0.0, 0.0, 0.0, 1.0]] * 2, dtype=F64)
    w = torch.tensor([[0.0, 0.0, 3.0 * R], [0.0, 0.0, 0.5 * R]], dtype=F64)
    inv = Inversion(q0=q, omega0=w, log_rho=torch.zeros(2, dtype=F64), cost=torch.tensor([20.0, 400.0], dtype=F64),
                    covariance=covariance(1e-10).expand(2, 7, 7).clone(), periodogram=None,
                    rate_grid=torch.zeros(0, 3, dtype=F64))
    # the mode at 3 R fits; the one inside does not, and it is the one the answer can report
    got = best_fit(inv, problem, rate_max_rad_s=R)
    assert got == fit_test(400.0, samples=n, parameters=7) and not got.fits
    assert best_fit(inv, problem, rate_max_rad_s=4.0 * R) == fit_test(20.0, samples=n, parameters=7)
