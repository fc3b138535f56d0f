"""The rate profile of a slow family: its interval and tolerance share against closed forms, the pin holding each
point's rate, a resolved slow rate told from a ridge, the rule that caps p_right."""

import math
from pathlib import Path

import pytest
import torch
from scipy.stats import norm

from lightcurve_gp.config.load import load_config
from lightcurve_gp.inference.families import RIGHT_RATE_REL
from lightcurve_gp.inference.forward import GroupRenderer
from lightcurve_gp.inference.rate_profile import (
    PIN_REL,
    PROFILE_CUT_NATS,
    PROFILE_FACTORS,
    RateProfile,
    profile_interval,
    profile_share,
    rate_profile,
    ridge_rule,
)
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.photometry.render import Scene

from helpers import tumbler_light_curve

ROOT = Path(__file__).resolve().parents[1]
F64 = torch.float64
SIGMA = 0.05


def test_the_interval_of_a_parabola_is_its_closed_form_and_a_flat_profile_is_open():
    s, r0 = 0.03, 0.4
    log_rate = torch.linspace(math.log(r0) - 0.3, math.log(r0) + 0.3, 6001, dtype=F64)
    delta = (log_rate - math.log(r0)) ** 2 / (2 * s * s)
    lo, hi, open_lo, open_hi = profile_interval(log_rate, delta)
    half = s * math.sqrt(2 * PROFILE_CUT_NATS)
    assert math.log(lo) == pytest.approx(math.log(r0) - half, abs=1e-6)
    assert math.log(hi) == pytest.approx(math.log(r0) + half, abs=1e-6)
    assert not open_lo and not open_hi
    lo, hi, open_lo, open_hi = profile_interval(log_rate, torch.zeros_like(log_rate))
    assert (open_lo, open_hi) == (True, True)
    assert lo == pytest.approx(math.exp(float(log_rate[0]))) and hi == pytest.approx(math.exp(float(log_rate[-1])))


def test_the_share_of_a_gaussian_profile_is_the_normal_mass_with_the_priors_shift():
    # exp(-(u - u0)^2 / 2 s^2) e^{3u} is a normal in u = ln r of mean u0 + 3 s^2 and deviation s
    s, r0 = 0.02, 0.3
    u0 = math.log(r0)
    log_rate = torch.linspace(u0 - 12 * s, u0 + 12 * s, 801, dtype=F64)
    delta = (log_rate - u0) ** 2 / (2 * s * s)
    got = profile_share(log_rate, delta, rate=r0, points=40001)
    mean = u0 + 3 * s * s
    lo, hi = math.log(r0 / (1 + RIGHT_RATE_REL)), math.log(r0 / (1 - RIGHT_RATE_REL))  # |r - r0| < 2 % of r
    expected = norm.cdf(hi, mean, s) - norm.cdf(lo, mean, s)
    assert got == pytest.approx(expected, abs=2e-3)
    assert 0.5 < got < 0.8  # the tolerance is about one deviation: the share is far from 0 and 1


def _light_curve(span: int, rate_deg_s: float, seed: int):
    cfg = load_config(ROOT / "configs" / "boxwing.yaml")
    scene = Scene.from_config(cfg, rho=0.5)
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=F64)
    q0, w0, y = tumbler_light_curve(scene, inertia, seed=seed, rate_deg_s=rate_deg_s, samples=span, sigma=SIGMA,
                                    rho=0.4)
    problem = TrajectoryProblem(GroupRenderer(scene), torch.arange(span + 1, dtype=F64), y,
                                torch.full((span + 1,), SIGMA, dtype=F64), inertia, torch.zeros(0, 4, dtype=F64))
    return problem, q0, w0


def _profile(span: int, rate_deg_s: float, seed: int) -> tuple[RateProfile, float]:
    problem, q0, w0 = _light_curve(span, rate_deg_s, seed)
    return rate_profile(problem, q0=q0, omega0=w0, log_rho=torch.tensor(math.log(0.4), dtype=F64),
                        span_s=float(span), rate_range_deg_s=(0.05, 5.0)), rate_deg_s


@pytest.mark.slow  # two profiles over 600 samples: ~5 s
def test_a_slow_rate_the_light_curve_fixes_is_resolved_and_its_points_keep_their_rates():
    # 0.5 deg/s over 600 s: 300 deg of turn, less than one, yet the light curve fixes the rate
    profile, rate = _profile(600, 0.5, 3)
    lo, hi = profile.interval_deg_s
    assert profile.resolved and not any(profile.open)
    assert lo < rate < hi and hi / lo < 1.0 + RIGHT_RATE_REL
    assert profile.share > 0.99
    # every point polished at its pinned rate (the factors inside the range): unpinned, those 10-50 % off would
    # have slid back to the minimum; pinned, each |w| stays within 0.2 % of its target
    targets = torch.tensor(sorted(f * rate for f in PROFILE_FACTORS if 0.05 <= f * rate <= 5.0), dtype=F64)
    assert profile.rates_deg_s.shape == targets.shape
    assert torch.allclose(profile.rates_deg_s, targets, rtol=20 * PIN_REL)
    assert float((profile.cost - profile.cost.min()).max()) > 1000.0  # and fit far worse there
    # another seed at the same rate: the profile 4 % wide, not resolved, though the turn is the same
    other, _ = _profile(600, 0.5, 2)
    assert not other.resolved and 0.5 < other.share < 0.9


def test_a_rate_the_arc_cannot_fix_is_a_ridge_whose_share_caps_p_right():
    # 0.1 deg/s over 200 s: 20 deg of turn
    profile, rate = _profile(200, 0.1, 1)
    lo, hi = profile.interval_deg_s
    assert not profile.resolved and hi / lo > 1.2 and lo < rate < hi
    assert profile.share < 0.5
    p_right, ridge = ridge_rule(profile, weight=0.9, p_right=0.95)
    assert ridge and p_right == pytest.approx(0.9 * profile.share)
    p_right, _ = ridge_rule(profile, weight=1.0, p_right=0.01)
    assert p_right == 0.01  # the rule only lowers


def test_a_family_below_the_rate_range_is_profiled_on_its_side_and_one_factor_is_refused():
    problem, q0, w0 = _light_curve(60, 0.03, 4)
    kw = dict(q0=q0, omega0=w0, log_rho=torch.tensor(math.log(0.4), dtype=F64), span_s=60.0)
    profile = rate_profile(problem, rate_range_deg_s=(0.05, 5.0), **kw)
    # 0.03 deg/s is below the range's 0.05: the profile runs from it upwards, its own rate the grid's lowest point
    assert float(profile.rates_deg_s[0]) == pytest.approx(0.03, rel=1e-3)
    assert float(profile.rates_deg_s[-1]) == pytest.approx(0.06, rel=1e-3) and profile.rates_deg_s.shape == (15,)
    with pytest.raises(ValueError, match=r"rate profile: 1 of the factors put the rate 0\.03 deg/s inside "
                                         r"\(0\.05, 5\.0\) deg/s; it needs two"):
        rate_profile(problem, rate_range_deg_s=(0.05, 5.0), factors=(0.5, 1.0), **kw)
