"""``filter.surface_measurement_noise``: the R of the surface-state filters alone, every other filter and the model
key untouched, an unset key the config's ``measurement_noise``, and errors naming the key."""

import pytest
import torch

from lightcurve_gp.config.load import ConfigError, config_to_dict, load_config
from lightcurve_gp.filters.setup import filter_params, run_surface_filter
from lightcurve_gp.filters.usque import UsqueParams
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario
from lightcurve_gp.training.store import model_key

ROBUST = "configs/boxwing_robust.yaml"
SHORT = ["scenario.duration_s=20", "evaluation.rmse_window_s=[10, 20]"]


def test_the_key_sets_the_surface_filters_r_and_nothing_else():
    cfg = load_config(ROBUST, ["filter.measurement_noise=0.5", "filter.surface_measurement_noise=2.5"])
    unset = load_config(ROBUST, ["filter.measurement_noise=0.5", "filter.surface_measurement_noise=null"])
    assert filter_params(cfg, surface=True).R == 2.5
    assert UsqueParams.from_config(cfg).R == 0.5  # the GP, matched and joint filters keep measurement_noise
    assert filter_params(cfg).R == 0.5
    assert filter_params(unset, surface=True).R == 0.5
    assert model_key(cfg) == model_key(unset)
    assert "surface_measurement_noise" not in config_to_dict(unset)["filter"]  # older case keys unchanged
    assert config_to_dict(cfg)["filter"]["surface_measurement_noise"] == 2.5


def test_the_surface_filter_with_the_key_is_the_filter_with_that_measurement_noise():
    by_key = load_config(ROBUST, SHORT + ["filter.measurement_noise=0.5", "filter.surface_measurement_noise=1.7"])
    by_r = load_config(ROBUST, SHORT + ["filter.measurement_noise=1.7", "filter.surface_measurement_noise=null"])
    scene = Scene.from_config(by_key)
    sc = simulate_scenario(by_key, seeds=[0, 1])
    run = dict(observations=sc.observations, q_est0=sc.q_est0, increments=sc.increments, sigma0=sc.sigma0)
    a, b = run_surface_filter(by_key, scene, **run), run_surface_filter(by_r, scene, **run)
    assert torch.equal(a.q_est, b.q_est) and torch.equal(a.P_full, b.P_full)
    assert float(a.y_var[:, 1:].min()) > 1.7  # P_yy = HPHᵀ + R with R = 1.7


def test_bad_values_name_the_key():
    for value in ("0", "-1", "loud"):
        with pytest.raises(ConfigError, match="^filter.surface_measurement_noise"):
            load_config(ROBUST, [f"filter.surface_measurement_noise={value}"])
