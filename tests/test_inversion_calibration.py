"""A family's probability of being right: the Gaussian mass of the tolerance region against closed forms (an
attitude spread about one axis, a rate spread along itself, both at once), the bounded covariance against its
explicit inverse, and ``p_right = weight · mass`` of families, small for a family the data leave free."""

import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.config.load import load_config
from lightcurve_gp.inference.families import (
    RIGHT_ANGLE_DEG,
    RIGHT_RATE_REL,
    bounded_covariance,
    families,
    prior_precision,
    tolerance_mass,
)
from lightcurve_gp.inference.inversion import entry_stages
from lightcurve_gp.photometry.ambiguity import ambiguity_group
from lightcurve_gp.photometry.render import Scene

ROOT = Path(__file__).resolve().parents[1]
F64 = torch.float64
DRAWS = 40_000
TOL = 4.0 * math.sqrt(0.25 / DRAWS)  # four binomial standard deviations at worst


def _phi(x: float) -> float:
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))


def _mass(cov: torch.Tensor, omega: list[float]) -> float:
    q = random_attitudes(1, seed=4, dtype=F64)
    return float(tolerance_mass(q, torch.tensor([omega], dtype=F64), cov[None], draws=DRAWS)[0])


def test_an_attitude_spread_about_the_yaw_axis_has_the_normal_mass_within_the_angle():
    s = math.radians(8.0)
    cov = torch.zeros(7, 7, dtype=F64)
    cov[2, 2] = s * s  # exp(δθ) ⊗ q about body-side z: the 3-2-1 error is yaw = δθ_z exactly
    expected = math.erf(math.radians(RIGHT_ANGLE_DEG) / (s * math.sqrt(2.0)))
    assert _mass(cov, [0.0, 0.01, 0.0]) == pytest.approx(expected, abs=TOL)


def test_a_rate_spread_along_itself_has_the_asymmetric_normal_mass():
    w, s = 0.01, 0.0003  # rad/s; the tolerance is 2 % of the *true* rate |ω_f + t|, so t ∈ (−2w/102, 2w/98)
    omega = torch.tensor([0.6, 0.0, 0.8], dtype=F64) * w
    cov = torch.zeros(7, 7, dtype=F64)
    cov[3:6, 3:6] = s * s * torch.outer(omega, omega) / (w * w)
    r = RIGHT_RATE_REL
    expected = _phi(r * w / (1 - r) / s) - _phi(-r * w / (1 + r) / s)
    assert _mass(cov, omega.tolist()) == pytest.approx(expected, abs=TOL)
    # both spreads at once, independent: the product
    cov[2, 2] = math.radians(8.0) ** 2
    both = expected * math.erf(math.radians(RIGHT_ANGLE_DEG) / (math.radians(8.0) * math.sqrt(2.0)))
    assert _mass(cov, omega.tolist()) == pytest.approx(both, abs=TOL)


def test_bounded_covariance_is_the_inverse_of_the_summed_precisions():
    a = torch.randn(7, 7, generator=torch.Generator().manual_seed(1), dtype=F64)
    cov = 1e-4 * (a @ a.T + 0.1 * torch.eye(7, dtype=F64))
    p = prior_precision(math.radians(5.0))
    explicit = torch.linalg.inv(torch.linalg.inv(cov) + torch.diag(p))
    torch.testing.assert_close(bounded_covariance(cov, math.radians(5.0)), explicit, rtol=1e-9, atol=1e-15)


def test_p_right_is_the_weight_times_the_mass_and_small_for_a_free_family():
    scene = Scene.from_config(load_config(ROOT / "configs" / "boxwing.yaml"))
    group = ambiguity_group(scene, times_s=torch.arange(31.0), inertia=[55.0, 40.0, 65.0], rate_known=False, probes=2)
    q = random_attitudes(2, seed=3, dtype=F64)
    w = torch.tensor([[0.03, 0.0, 0.0], [0.0, 0.03, 0.0]], dtype=F64)
    sharp = torch.diag(torch.tensor([1e-6] * 3 + [1e-10] * 3 + [1e-4], dtype=F64))  # 0.06°, 1e-5 rad/s: all inside
    flat = torch.eye(7, dtype=F64) * 1e12
    fam = families(group, q0=q, omega0=w, log_rho=torch.zeros(2, dtype=F64), cost=torch.tensor([10.0, 10.5], dtype=F64),
                   covariance=torch.stack([flat, sharp]), sigma=torch.full((31,), 0.05, dtype=F64),
                   rate_max_rad_s=math.radians(5.0))
    torch.testing.assert_close(fam.p_right, fam.weight * fam.mass)
    sharp_row = int(torch.nonzero(fam.covariance[:, 0, 0] < 1.0)[0, 0])
    assert float(fam.mass[sharp_row]) == 1.0
    # the free family's spread is the prior's (attitude 1σ ~ 1.7 rad, rate 1σ ~ 0.06 rad/s): almost no mass
    assert float(fam.mass[1 - sharp_row]) < 1e-2


def test_each_rate_enters_at_the_first_arc_it_turns_enough_over_and_never_at_the_polish():
    deg = torch.tensor([2.0, 0.6, 0.3, 0.1, 0.01], dtype=F64)  # turns over 30 s: 60°, 18°, 9°, 3°, 0.3°
    rates = torch.deg2rad(deg)[:, None] * torch.tensor([[0.0, 0.6, 0.8]], dtype=F64)
    arcs = (30.0, 60.0, 120.0, 240.0, 0.0)
    got = entry_stages(rates, arcs_s=arcs, span_s=600.0, turn_deg=30.0)
    # 0.6 °/s turns 36° over 60 s, 0.3 °/s 36° over 120 s; 0.1 °/s only 24° over 240 s: the last partial arc
    assert got.tolist() == [0, 1, 2, 3, 3]
    assert entry_stages(rates, arcs_s=arcs, span_s=600.0, turn_deg=0.0).tolist() == [0] * 5
    assert entry_stages(rates, arcs_s=(0.0,), span_s=600.0, turn_deg=30.0).tolist() == [0] * 5
