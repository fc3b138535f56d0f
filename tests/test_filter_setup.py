"""From a config to a filter's start (filters/setup.py): P0 block by block, R and its replacements, m_past,0, the
models along a pass, and the run it starts against a hand-built run_usque call."""

import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.config.load import load_config
from lightcurve_gp.filters.offset import initial_offset
from lightcurve_gp.filters.setup import filter_params, first_observation, prior_covariance, run_filter, step_models
from lightcurve_gp.filters.usque import UsqueParams, run_usque
from lightcurve_gp.observation.along_pass import AlongPass

from helpers import ToyModel, scenario

DT = torch.float64
ROBUST = Path(__file__).resolve().parents[1] / "configs" / "boxwing_robust.yaml"


@pytest.fixture(scope="module")
def cfg():
    return load_config(ROBUST, ["filter.p0_deg=8", "filter.offset_prior_std=0.7", "filter.p0_omega_deg_s=0.2"])


def test_p0_holds_each_block_on_its_diagonal(cfg):
    std = torch.tensor([0.5, 1.5, 2.0, 3.0], dtype=DT)
    P0 = prior_covariance(cfg, offset=True, omega=True, parameter_std=std, dtype=DT)
    expected = [math.radians(8.0) ** 2] * 3 + [math.radians(0.2) ** 2] * 3 + [0.7 ** 2] + std.pow(2).tolist()
    torch.testing.assert_close(P0, torch.diag(torch.tensor(expected, dtype=DT)), rtol=1e-15, atol=0)
    assert prior_covariance(cfg, dtype=DT).shape == (3, 3)  # the attitude alone


def test_per_filter_sigma0_gives_one_p0_per_filter(cfg):
    sigma0 = torch.tensor([0.1, 0.2], dtype=DT)
    P0 = prior_covariance(cfg, sigma0=sigma0, offset=True, omega=False, dtype=DT)
    assert P0.shape == (2, 4, 4)
    for b in range(2):
        torch.testing.assert_close(P0[b], torch.diag(torch.tensor([sigma0[b] ** 2] * 3 + [0.49], dtype=DT)),
                                   rtol=1e-15, atol=0)
    # sigma0 = filter.p0_deg for every filter is the shared P0, bit for bit
    same = prior_covariance(cfg, sigma0=torch.full((3,), math.radians(8.0), dtype=DT), offset=True, dtype=DT)
    assert torch.equal(same, prior_covariance(cfg, offset=True, dtype=DT).expand(3, 4, 4))


def test_r_is_the_measurement_noise_unless_replaced(cfg):
    assert filter_params(cfg).R == cfg.filter.measurement_noise
    assert filter_params(cfg, surface=True).R == cfg.filter.surface_measurement_noise
    R = torch.tensor([0.3, 0.4], dtype=DT)
    assert torch.equal(filter_params(cfg, R=R, surface=True).R, R)  # a given R wins over both keys
    assert filter_params(cfg, variance="none").variance == "none"
    assert filter_params(cfg).variance == UsqueParams.from_config(cfg).variance


def test_m_past0_is_the_first_finite_observation():
    y = torch.tensor([[math.nan, 2.0, 3.0], [1.0, math.nan, 3.0], [math.nan] * 3], dtype=DT)
    assert first_observation(y).tolist() == [2.0, 1.0, 0.0]


def test_run_filter_is_run_usque_with_the_config_start(cfg):
    _, y, q_est0, increments = scenario(B=3, T=30, seed=2, noise=0.05)
    model = ToyModel()
    sigma0 = torch.tensor([0.1, 0.15, 0.2], dtype=DT)
    got = run_filter(cfg, model, q_est0=q_est0, observations=y, increments=increments, sigma0=sigma0)
    P0 = torch.zeros(3, 4, 4, dtype=DT)
    P0[:, :3, :3] = sigma0.pow(2).view(-1, 1, 1) * torch.eye(3, dtype=DT)
    P0[:, 3, 3] = 0.7 ** 2
    expected = run_usque(model=model, q_est0=q_est0, P0=P0, observations=y, m_past0=y[:, 0], increments=increments,
                         params=UsqueParams.from_config(cfg), offset0=initial_offset(model, q_est0, y[:, 0], y[:, 0]))
    assert torch.equal(got.q_est, expected.q_est) and torch.equal(got.P_full, expected.P_full)
    assert torch.equal(got.offset, expected.offset)
    without = run_filter(cfg, model, q_est0=q_est0, observations=y, increments=increments, offset=False)
    assert without.offset is None and without.P_full.shape[-1] == 3


def test_models_step_along_a_pass_and_stay_put_without_one():
    model = ToyModel()
    assert step_models(model) == (model, model)

    class Geometry:  # two samples: what AlongPass needs of a pass
        sun = observer = torch.eye(3, dtype=DT)[:2]
        range_m = torch.ones(2, dtype=DT)

        def __len__(self):
            return 2

    first, steps = step_models(model, geometry=Geometry())
    assert first is model  # a model that takes no geometry is itself at sample 0
    assert isinstance(steps, AlongPass) and steps.next_sample == 1
