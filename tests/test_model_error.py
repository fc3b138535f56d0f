"""``filter.model_error: heldout``: the GP's held-out excess variance, computed by ``train``, stored with the model and
added to the R of the filters that use the GP — the renderers and the default untouched."""

import json
import math

import pytest
import torch

from lightcurve_gp.config.load import ConfigError, config_to_dict, load_config
from lightcurve_gp.filters.usque import UsqueParams, model_error_variance
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.observation.serialization import load_model
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.training.fit import heldout_metrics
from lightcurve_gp.training.store import model_key

from helpers import estimate_scenario, tiny_training, train_tiny

ROBUST = "configs/boxwing_robust.yaml"


class Stored:
    """A stand-in for a loaded trained model: its training ``config`` and its file's ``extra``."""

    def __init__(self, extra):
        self.config = {"kind": "sparse"}
        self.extra = extra


@pytest.fixture(scope="module")
def tiny_model_file(tmp_path_factory):
    return train_tiny(ROBUST, tmp_path_factory.mktemp("runs"), "tiny_model_error")


def test_excess_variance_is_the_squared_error_beyond_the_predicted_variance():
    y = torch.zeros(4, dtype=torch.float64)
    mean = torch.tensor([1.0, -1.0, 2.0, 0.0], dtype=torch.float64)  # mean r² = 1.5
    var = torch.full((4,), 0.2, dtype=torch.float64)
    assert heldout_metrics(mean, var, y, noise_var=0.3)["excess_variance"] == pytest.approx(1.5 - 0.5, abs=1e-15)
    assert heldout_metrics(mean, var, y, noise_var=1.3)["excess_variance"] == 0.0  # covered: nothing to add


def test_heldout_adds_the_stored_excess_to_r_of_a_trained_model_only():
    on = load_config(ROBUST, ["filter.model_error=heldout", "filter.measurement_noise=0.5"])
    off = load_config(ROBUST, ["filter.measurement_noise=0.5"])
    gp = Stored({"heldout": {"excess_variance": 0.7}})
    renderer = Parametric(Scene.from_config(on), 0.5)
    assert UsqueParams.from_config(on, model=gp).R == pytest.approx(1.2, abs=1e-15)
    assert UsqueParams.from_config(off, model=gp).R == 0.5
    assert UsqueParams.from_config(on, model=renderer).R == 0.5 and model_error_variance(on, None) == 0.0
    assert model_key(on) == model_key(off)
    assert "model_error" not in config_to_dict(off)["filter"]  # older configs keep their case keys
    assert config_to_dict(on)["filter"]["model_error"] == "heldout"


def test_a_model_file_without_heldout_metrics_is_refused_with_the_key():
    on = load_config(ROBUST, ["filter.model_error=heldout"])
    with pytest.raises(ValueError, match="^filter.model_error: heldout needs the held-out metrics that train stores "
                                         "in the model file; this model file has none: train it again$"):
        UsqueParams.from_config(on, model=Stored({"model_key": "x"}))
    in_memory = Stored({})
    del in_memory.extra  # a model built in memory has no file metadata at all
    with pytest.raises(ValueError, match="^filter.model_error: heldout needs the held-out metrics"):
        UsqueParams.from_config(on, model=in_memory)
    with pytest.raises(ConfigError, match="^filter.model_error"):
        load_config(ROBUST, ["filter.model_error=always"])


def test_train_stores_its_heldout_metrics_in_the_model_file(tiny_model_file):
    stored = load_model(tiny_model_file).extra["heldout"]
    written = json.loads((tiny_model_file.parent / "metrics.json").read_text())["heldout"]
    assert stored == written and stored["excess_variance"] >= 0.0
    assert stored["rmse"] ** 2 >= stored["excess_variance"]


def test_the_gpukf_with_heldout_is_the_gpukf_with_that_larger_r(tiny_model_file):
    model = load_model(tiny_model_file)
    excess = model.extra["heldout"]["excess_variance"]
    base = [*tiny_training("tiny_model_error"), "filter.measurement_noise=0.5"]
    on = load_config(ROBUST, [*base, "filter.model_error=heldout"])
    by_r = load_config(ROBUST, [*base[:-1], f"filter.measurement_noise={0.5 + excess!r}"])
    runs = [estimate_scenario(c, model, seeds=[0, 1], estimators=["gpukf", "matched_ukf"]) for c in (on, by_r)]
    torch.testing.assert_close(runs[0].results["gpukf"].q_est, runs[1].results["gpukf"].q_est, rtol=0, atol=1e-12)
    if excess > 0:  # the matched UKF keeps R = 0.5 under heldout, so it differs from the run with the larger R
        assert not torch.equal(runs[0].results["matched_ukf"].q_est, runs[1].results["matched_ukf"].q_est)
    assert math.isfinite(excess)
