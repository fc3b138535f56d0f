"""The surface as filter states: a generic parameter block in the USQUE, the renderer per sigma point, the prior."""

import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.config.load import load_config
from lightcurve_gp.filters.offset import offset_covariance
from lightcurve_gp.filters.usque import UsqueParams, run_usque
from lightcurve_gp.observation.base import ObservationModule
from lightcurve_gp.observation.parametric import Parametric, SurfaceStateRenderer
from lightcurve_gp.observation.surface_state import LOG_LOBE_MAX, surface_from_state, surface_state_prior
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.truths import TruthRanges

from helpers import ToyModel, scenario

DT = torch.float64
CONFIGS = Path(__file__).resolve().parents[1] / "configs"


class OffsetAsParameter(ObservationModule):
    """``h(q) + θ_0``: the offset filter's model written as a one-parameter model."""

    uses_m_past = False

    def __init__(self):
        super().__init__()
        self.toy = ToyModel()

    def forward(self, *, q, m_past, variance="fast", theta):
        mean, var = self.toy(q=q, m_past=m_past, variance=variance)
        return mean + theta[..., 0], var


def test_a_parameter_state_that_enters_additively_is_the_offset_filter():
    q_true, y, q_est0, inc = scenario(B=4, T=60, seed=2, noise=0.05)
    y = y + 0.3  # an unknown offset
    P0 = offset_covariance(8.0, 0.5, dtype=DT)
    params = UsqueParams(R=0.05 ** 2, Q=1e-7, offset_process_noise=1e-6, parameter_process_noise=1e-6)
    b0 = torch.full((4,), 0.1, dtype=DT)
    common = dict(q_est0=q_est0, P0=P0, observations=y, m_past0=y[:, 0], increments=inc, params=params)
    as_offset = run_usque(model=ToyModel(), offset0=b0, **common)
    as_theta = run_usque(model=OffsetAsParameter(), theta0=b0.unsqueeze(-1), **common)
    assert torch.allclose(as_theta.q_est, as_offset.q_est, atol=1e-12, rtol=0)
    assert torch.allclose(as_theta.P_full, as_offset.P_full, atol=1e-12, rtol=0)
    assert torch.allclose(as_theta.theta[..., 0], as_offset.offset, atol=1e-12, rtol=0)
    assert as_offset.theta is None and as_theta.offset is None
    # the estimate moved from 0.1 towards the true offset 0.3
    assert abs(float(as_theta.theta[:, -1, 0].mean()) - 0.3) < 0.05


def test_theta_and_covariance_shapes_are_checked():
    q_true, y, q_est0, inc = scenario(B=2, T=5)
    with pytest.raises(ValueError, match=r"theta0 must have shape \(B=2, 1\) or \(1,\), got \(3, 1\)"):
        run_usque(model=OffsetAsParameter(), q_est0=q_est0, P0=torch.eye(4, dtype=DT), observations=y,
                  m_past0=y[:, 0], increments=inc, theta0=torch.zeros(3, 1, dtype=DT))
    with pytest.raises(ValueError, match=r"P0 must have shape \(4, 4\) .* for the state \[dp, theta \(1\)\]"):
        run_usque(model=OffsetAsParameter(), q_est0=q_est0, P0=torch.eye(3, dtype=DT), observations=y,
                  m_past0=y[:, 0], increments=inc, theta0=torch.zeros(1, dtype=DT))


def test_surface_state_renderer_renders_every_point_with_its_own_surface():
    cfg = load_config(CONFIGS / "boxwing.yaml")
    scene = Scene.from_config(cfg, dtype=DT)
    q = random_attitudes(2 * 5, seed=4, dtype=DT).view(2, 5, 4)
    g = torch.Generator().manual_seed(0)
    theta = torch.stack([torch.log(0.1 + 0.8 * torch.rand(2, 5, generator=g, dtype=DT)),
                         torch.randn(2, 5, generator=g, dtype=DT),
                         math.log(10) + 6 * torch.rand(2, 5, generator=g, dtype=DT),
                         math.log(10) + 6 * torch.rand(2, 5, generator=g, dtype=DT)], -1)
    mean, var = SurfaceStateRenderer(scene)(q=q, m_past=torch.zeros(2, 5, dtype=DT), theta=theta)
    assert mean.shape == (2, 5) and torch.equal(var, torch.zeros_like(mean))
    for b in range(2):
        for i in range(5):  # independent: the fixed-surface renderer at that point's surface
            surface = Surface(*(torch.tensor([float(v)], dtype=DT) for v in surface_from_state(theta[b, i])))
            expected, _ = Parametric(scene, surface=surface)(q=q[b, i].view(1, 4), m_past=torch.zeros(1, dtype=DT))
            assert torch.allclose(mean[b, i], expected[0], atol=1e-12, rtol=0)
    with pytest.raises(ValueError, match=r"theta must have shape \(2, 5, 4\)"):
        SurfaceStateRenderer(scene)(q=q, m_past=torch.zeros(2, 5, dtype=DT), theta=theta[..., :3])


def test_surface_coordinates_map_back_and_hold_the_lobe_in_range():
    theta = torch.tensor([[math.log(0.3), math.log(0.25 / 0.75), math.log(50.0), 100.0]], dtype=DT)
    s = surface_from_state(theta)
    assert torch.allclose(torch.cat(list(s)), torch.tensor([0.3, 0.25, 50.0, math.exp(LOG_LOBE_MAX)], dtype=DT),
                          rtol=1e-12)


def test_surface_prior_reads_rho_from_the_first_sample_and_spans_the_drawing_ranges():
    cfg = load_config(CONFIGS / "boxwing.yaml")
    scene = Scene.from_config(cfg, dtype=DT)
    q0 = random_attitudes(3, seed=9, dtype=DT)
    reference = Surface(*(torch.tensor([v], dtype=DT) for v in (0.5, 0.5, 800.0, 800.0)))
    y_ref = scene.magnitude(q0.unsqueeze(1), surface=Surface(*(t.expand(3) for t in reference)))[:, 0]
    ranges = TruthRanges()
    mean, std = surface_state_prior(scene=scene, q_est0=q0, y0=y_ref - 2.5 * math.log10(1.4), reference=reference,
                                    offset_std=1.0, ranges=ranges)
    # one magnitude brighter by 2.5 log10(1.4): ρ 1.4 times the reference
    assert torch.allclose(mean[:, 0], torch.full((3,), math.log(0.7), dtype=DT), atol=1e-12)
    assert torch.allclose(mean[:, 2:], torch.full((3, 2), 0.5 * math.log(10 * 1e4), dtype=DT), atol=1e-12)
    assert abs(float(mean[0, 1])) < 1e-12  # the logit of a range symmetric about 0.5
    assert float(std[0]) == pytest.approx(math.log(10) / 2.5)
    assert float(std[2]) == pytest.approx(math.log(1e3) / math.sqrt(12))
