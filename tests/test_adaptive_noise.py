"""Innovation-based adaptive measurement noise (``filter.adaptive_noise: innovation``): covariance matching.

A model that predicts a constant has no sigma-point spread, so the filter's ``Pyy = R̂ + v`` and its innovation
``ν = ỹ − ŷ`` is the observation noise (plus any injected bias): the rule's averages are known in closed form.
"""

import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.config.load import ConfigError, load_config
from lightcurve_gp.filters.usque import UsqueParams, adapted_noise, run_usque
from lightcurve_gp.observation.base import ObservationModule

from helpers import DT, ToyModel, scenario

ROOT = Path(__file__).resolve().parents[1]


class ConstantModel(ObservationModule):
    """``h(q) = level`` with latent variance ``v`` everywhere."""

    uses_m_past = False

    def __init__(self, level: float, v: float):
        super().__init__()
        self.level, self.v = level, v

    def _predict(self, q, m_past, variance):
        mean = torch.full(q.shape[:-1], self.level, dtype=q.dtype)
        return mean, None if variance == "none" else torch.full_like(mean, self.v)


def _run_constant(*, bias: float, R: float, v: float, rate: float, B: int = 400, T: int = 1500, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    # a correct model: the truth deviates from its mean with the model's variance v, plus the noise R
    y = 2.0 + bias + math.sqrt(R + v) * torch.randn(B, T + 1, generator=g, dtype=DT)
    q0 = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=DT).expand(B, 4)
    inc = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=DT).expand(T, 4)
    params = UsqueParams(Q=0.0, R=R, adaptive_noise="innovation", adaptive_noise_rate=rate)
    hist = run_usque(model=ConstantModel(2.0, v), q_est0=q0, P0=1e-4 * torch.eye(3, dtype=DT), observations=y,
                     m_past0=torch.zeros(B, dtype=DT), increments=inc, params=params)
    return hist, hist.y_var - hist.model_var  # R̂_k used at every step


@pytest.mark.slow
def test_correct_model_leaves_R_in_expectation():
    """White noise, correct model: ``ν ~ N(0, R + v)``, the excess ``e = ν² − v`` has mean R and variance
    ``2(R + v)²``, so the average ``c`` (stationary std ``σ_c = √(λ/(2−λ) · 2(R + v)²)``) is centred on R;
    ``R̂ = max(R, c)`` then has mean ``R + σ_c/√(2π)`` (c near Gaussian after ~2/λ samples) and the NIS stays
    near 1."""
    R, v, rate = 0.5, 0.1, 0.01
    hist, r_hat = _run_constant(bias=0.0, R=R, v=v, rate=rate)
    late = slice(500, None)  # 5 forgetting times after the start at c = R
    sigma_c = math.sqrt(rate / (2 - rate) * 2 * (R + v) ** 2)
    assert float(r_hat[:, late].min()) >= R  # never below the configured noise
    assert float(r_hat[:, late].mean()) == pytest.approx(R + sigma_c / math.sqrt(2 * math.pi), abs=0.25 * sigma_c)
    assert float(hist.nis()[:, late].mean()) == pytest.approx(1.0, abs=0.06)


@pytest.mark.slow
def test_model_bias_raises_R_toward_R_plus_bias_squared():
    """A constant model error β adds β² to ``E ν²``: ``c → R + β²`` (the clamp at R is 3σ_c away)."""
    R, v, bias = 0.5, 0.1, 0.5
    hist, r_hat = _run_constant(bias=bias, R=R, v=v, rate=0.01)
    assert float(r_hat[:, 500:].mean()) == pytest.approx(R + bias**2, rel=0.02)
    assert float(hist.nis()[:, 500:].mean()) == pytest.approx(1.0, abs=0.03)  # consistent again
    fixed = run_usque(model=ConstantModel(2.0, v), q_est0=torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=DT),
                      P0=1e-4 * torch.eye(3, dtype=DT), observations=torch.full((1, 3), 2.0 + bias, dtype=DT),
                      m_past0=torch.zeros(1, dtype=DT), increments=torch.tensor([[0.0, 0.0, 0.0, 1.0]] * 2, dtype=DT),
                      params=UsqueParams(Q=0.0, R=R))
    assert torch.equal(fixed.y_var[:, 1:], torch.full((1, 2), R + v, dtype=DT))  # without the rule R stays R


def test_adapted_noise_is_the_exponential_average_of_the_excess():
    avg = torch.tensor([0.5, 0.5], dtype=DT)
    out = adapted_noise(avg, nu=torch.tensor([1.0, 0.0], dtype=DT), P_yy=torch.tensor([0.7, 0.7], dtype=DT),
                        R_k=torch.tensor([0.5, 0.5], dtype=DT), rate=0.1)
    # excess = ν² − (Pyy − R_k) = 0.8 and −0.2
    assert torch.allclose(out, torch.tensor([0.9 * 0.5 + 0.1 * 0.8, 0.9 * 0.5 - 0.1 * 0.2], dtype=DT))


def test_rate_one_without_excess_is_the_fixed_filter():
    """Noise-free observations of the true toy trajectory: with the excess never above R the rule keeps R̂ = R,
    and the run equals the fixed-R run exactly."""
    _, y, q_est0, inc = scenario(B=3, T=60, noise=0.0)
    common = dict(model=ToyModel(), q_est0=q_est0, P0=1e-4 * torch.eye(3, dtype=DT), observations=y,
                  m_past0=torch.zeros(3, dtype=DT), increments=inc)
    fixed = run_usque(**common, params=UsqueParams(Q=0.0, R=10.0, variance="none"))
    adaptive = run_usque(**common, params=UsqueParams(Q=0.0, R=10.0, variance="none", adaptive_noise="innovation",
                                                      adaptive_noise_rate=1.0))
    assert float(fixed.nis()[:, 1:].max()) < 1.0  # ν² < Pyy: every excess stays below R
    assert torch.equal(adaptive.q_est, fixed.q_est) and torch.equal(adaptive.y_var[:, 1:], fixed.y_var[:, 1:])


def test_config_maps_forgetting_time_to_rate_and_names_bad_keys():
    cfg = load_config(ROOT / "configs" / "boxwing_robust.yaml",
                      ["filter.adaptive_noise=innovation", "filter.adaptive_noise_time_s=50"])
    params = UsqueParams.from_config(cfg)
    assert params.adaptive_noise == "innovation" and params.adaptive_noise_rate == pytest.approx(1.0 / 50)
    assert UsqueParams.from_config(load_config(ROOT / "configs" / "boxwing_robust.yaml")).adaptive_noise == "none"
    with pytest.raises(ConfigError, match=r"^filter.adaptive_noise: 'sage' is not one of none, innovation$"):
        load_config(ROOT / "configs" / "boxwing_robust.yaml", ["filter.adaptive_noise=sage"])
    with pytest.raises(ConfigError, match=r"^filter.adaptive_noise_time_s: "):
        load_config(ROOT / "configs" / "boxwing_robust.yaml", ["filter.adaptive_noise_time_s=0"])


def test_options_that_are_off_leave_the_config_dict_unchanged():
    """``adaptive_noise: none`` and ``data.surfaces: null`` are absent from the dict that cache and case keys hash."""
    from lightcurve_gp.config.load import config_to_dict

    base = config_to_dict(load_config(ROOT / "configs" / "boxwing_robust.yaml"))
    assert "adaptive_noise" not in base["filter"] and "surfaces" not in base["data"]
    on = config_to_dict(load_config(ROOT / "configs" / "boxwing_robust.yaml", ["filter.adaptive_noise=innovation"]))
    assert on["filter"]["adaptive_noise"] == "innovation" and on["filter"]["adaptive_noise_time_s"] == 100.0
