"""``data.omega0_deg_s`` as one rate, a list of rates or a range: parsing, errors naming the key, and the training
trajectories each attitude gets."""

import dataclasses

import pytest
import torch

from lightcurve_gp.config.load import ConfigError, SpinRangeConfig, config_from_dict, config_to_dict, load_config
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.training.store import model_key
from lightcurve_gp.training.windows import training_rates, window_samples

PAPER = "configs/boxwing.yaml"
SMALL = ["data.icosphere_subdivisions=0", "data.phi_step_deg=120", "data.rho_grid=[0.5]"]


def test_the_three_forms_parse_and_round_trip():
    one = load_config(PAPER)
    listed = load_config(PAPER, overrides=["data.omega0_deg_s=[[0.1, -0.1, -0.25], [0.2, 0.0, 0.1]]"])
    ranged = load_config(PAPER, overrides=["data.omega0_deg_s={low: [-0.3, -0.3, -0.3], high: [0.3, 0.3, 0.3]}"])
    assert one.data.omega0_deg_s == [0.1, -0.1, -0.25]
    assert listed.data.omega0_deg_s == [[0.1, -0.1, -0.25], [0.2, 0.0, 0.1]]
    assert ranged.data.omega0_deg_s == SpinRangeConfig(low=[-0.3] * 3, high=[0.3] * 3)
    for cfg in (one, listed, ranged):
        assert config_from_dict(config_to_dict(cfg)) == cfg
    assert len({model_key(c) for c in (one, listed, ranged)}) == 3  # the spins change the model


@pytest.mark.parametrize("value, message", [
    ("[0.1, 0.2]", r"^data.omega0_deg_s: expected 3 values \(or a list of rates, or a range\), got 2"),
    ("[[0.1, 0.2, 0.3], [0.1, 0.2]]", r"^data.omega0_deg_s\[1\]: expected 3 values, got 2"),
    ("{low: [0, 0, 0.5], high: [0.1, 0.1, 0.1]}", r"^data.omega0_deg_s.low\[2\]: 0.5 is above high 0.1"),
    ("{low: [0, 0, 0]}", r"^data.omega0_deg_s.high"),
    ("[[0.1, x, 0.3]]", r"^data.omega0_deg_s\[0\]\[1\]"),
])
def test_bad_spins_name_the_key(value, message):
    with pytest.raises(ConfigError, match=message):
        load_config(PAPER, overrides=[f"data.omega0_deg_s={value}"])


def test_the_paper_gp_may_estimate_omega_once_trained_over_spins():
    with pytest.raises(ConfigError, match="^filter.estimate_omega"):
        load_config(PAPER, overrides=["filter.estimate_omega=true"])
    cfg = load_config(PAPER, overrides=["filter.estimate_omega=true",
                                        "data.omega0_deg_s={low: [-0.3, -0.3, -0.3], high: [0.3, 0.3, 0.3]}"])
    assert cfg.filter.estimate_omega


def test_rates_per_attitude():
    listed = load_config(PAPER, overrides=["data.omega0_deg_s=[[1, 2, 3], [4, 5, 6]]"]).data
    w = torch.rad2deg(training_rates(listed, 5, dtype=torch.float64))
    expected = torch.tensor([[1, 2, 3], [4, 5, 6], [1, 2, 3], [4, 5, 6], [1, 2, 3]], dtype=torch.float64)
    torch.testing.assert_close(w, expected, rtol=1e-15, atol=0)
    ranged = load_config(PAPER, overrides=["data.omega0_deg_s={low: [-1, 0, 2], high: [1, 0.5, 2]}"]).data
    w = torch.rad2deg(training_rates(ranged, 4000, dtype=torch.float64))
    assert (w[:, 0].abs() <= 1).all() and (w[:, 1] >= 0).all() and (w[:, 1] <= 0.5).all()
    assert torch.allclose(w[:, 2], torch.full((4000,), 2.0, dtype=torch.float64))
    assert abs(float(w[:, 0].mean())) < 0.05 and float(w[:, 0].std()) == pytest.approx(2 / 12 ** 0.5, rel=0.05)
    assert torch.equal(training_rates(ranged, 10), training_rates(ranged, 10))  # seeded by data.seed
    other = dataclasses.replace(ranged, seed=ranged.seed + 1)
    assert not torch.equal(training_rates(ranged, 10), training_rates(other, 10))


def test_a_list_of_rates_gives_each_attitude_its_own_trajectory():
    """Attitudes taking rates in turn equal the single-rate sets of those attitudes, point for point."""
    rates = [[0.1, -0.1, -0.25], [1.0, 2.0, -1.5]]
    cfg = load_config(PAPER, overrides=[*SMALL, f"data.omega0_deg_s={rates}"])
    scene = Scene.from_config(cfg)
    q0 = torch.nn.functional.normalize(torch.randn(6, 4, generator=torch.Generator().manual_seed(0),
                                                   dtype=torch.float64), dim=-1)
    rho = torch.tensor([[0.5]], dtype=torch.float64)
    J = torch.tensor(cfg.shape.inertia_kg_m2, dtype=torch.float64)
    mixed = window_samples(scene, q0, rho, cfg.data, J, chunk=4)
    for k, rate in enumerate(rates):
        single = window_samples(scene, q0[k::2], rho, dataclasses.replace(cfg.data, omega0_deg_s=rate), J)
        torch.testing.assert_close(mixed.m_past[k::2], single.m_past, rtol=0, atol=1e-12)
        torch.testing.assert_close(mixed.y[k::2], single.y, rtol=0, atol=1e-12)
    assert not torch.allclose(mixed.m_past[0::2], window_samples(
        scene, q0[0::2], rho, dataclasses.replace(cfg.data, omega0_deg_s=rates[1]), J).m_past)
