"""Config of the rate-state filter and the USQUE variant: keys, units, errors naming the key, and the unchanged keys
of configs that leave them off."""

import math

import pytest
import torch

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.config.load import ConfigError, config_to_dict, load_config
from lightcurve_gp.evaluation.reporting import scenario_summary
from lightcurve_gp.filters.setup import prior_covariance
from lightcurve_gp.filters.usque import UsqueParams
from lightcurve_gp.training.store import model_key

from helpers import estimate_scenario

ROBUST = "configs/boxwing_robust.yaml"


@pytest.mark.parametrize("override, message", [
    ("filter.p0_omega_deg_s=-0.01", "filter.p0_omega_deg_s"),
    ("filter.omega_process_noise=-1e-12", "filter.omega_process_noise"),
    ("filter.q_placement=before", "filter.q_placement"),
    ("filter.sigma_redraw=sometimes", "filter.sigma_redraw"),
    ("filter.inertia_kg_m2=[50, 0, 30]", r"filter.inertia_kg_m2\[1\]"),
    ("scenario.initial_omega_error_deg_s=[0.1, 0.2]", "scenario.initial_omega_error_deg_s"),
])
def test_bad_rate_settings_name_their_key(override, message):
    with pytest.raises(ConfigError, match=f"^{message}"):
        load_config(ROBUST, overrides=["filter.estimate_omega=true", override])


def test_estimate_omega_with_a_gp_that_cannot_names_the_key():
    with pytest.raises(ConfigError, match=r"^filter.estimate_omega: true needs an attitude-only GP"):
        load_config("configs/boxwing.yaml", overrides=["filter.estimate_omega=true"])


def test_off_options_leave_the_keys_and_the_model_key_unchanged():
    base = load_config(ROBUST)
    on = load_config(ROBUST, overrides=["filter.estimate_omega=true", "filter.sigma_redraw=true",
                                        "scenario.initial_omega_error_deg_s=[0.03, -0.03, 0.03]"])
    d = config_to_dict(base)
    for key in ("estimate_omega", "p0_omega_deg_s", "omega_process_noise", "sigma_redraw", "q_placement",
                "inertia_kg_m2"):
        assert key not in d["filter"]
    assert "initial_omega_error_deg_s" not in d["scenario"]
    d_on = config_to_dict(on)
    assert d_on["filter"]["estimate_omega"] is True and d_on["filter"]["sigma_redraw"] is True
    assert d_on["scenario"]["initial_omega_error_deg_s"] == [0.03, -0.03, 0.03]
    assert model_key(on) == model_key(base)  # the filter and the scenario do not change the model


def test_params_and_prior_from_config_in_code_units():
    cfg = load_config(ROBUST, overrides=["filter.estimate_omega=true", "filter.p0_omega_deg_s=0.1",
                                         "filter.omega_process_noise=1e-12", "filter.q_placement=after",
                                         "shape.inertia_kg_m2=[50, 40, 30]", "scenario.dt_s=2",
                                         "scenario.duration_s=600"])
    p = UsqueParams.from_config(cfg)
    assert (p.omega_process_noise, p.inertia, p.dt, p.q_placement, p.sigma_redraw) == \
        (1e-12, (50.0, 40.0, 30.0), 2.0, "after", False)
    assumed = load_config(ROBUST, overrides=["filter.inertia_kg_m2=[60.5, 36, 71.5]"])
    assert UsqueParams.from_config(assumed).inertia == (60.5, 36.0, 71.5)
    P0 = prior_covariance(cfg, offset=True, dtype=torch.float64)
    assert P0.shape == (7, 7)
    expected = [math.radians(10.0) ** 2] * 3 + [math.radians(0.1) ** 2] * 3 + [1.0]
    torch.testing.assert_close(P0.diagonal(), torch.tensor(expected, dtype=torch.float64), rtol=1e-15, atol=0)
    assert (P0 - torch.diag(P0.diagonal())).abs().max() == 0


def test_the_omega_unknown_estimators_run_from_the_config():
    """The matched-ρ UKF with ω in the state, started 0.05°/s off, learns the rate; the ω-known one propagates
    with the wrong rate and the no-update reference keeps the error."""
    over = ["filter.estimate_omega=true", "filter.p0_omega_deg_s=0.05", "scenario.duration_s=200",
            "evaluation.rmse_window_s=[150, 200]", "scenario.initial_omega_error_deg_s=[0.05, -0.05, 0.05]",
            "shape.box_grid=1", "shape.wing_grid=1"]
    cfg = load_config(ROBUST, overrides=over)
    res = estimate_scenario(cfg, seeds=[0, 1], estimators=("matched_ukf", "no_update"))
    ukf, ref = res.results["matched_ukf"], res.results["no_update"]
    assert ukf.history.omega.shape == (2, 201, 3) and ukf.nees_full_dof == 6
    torch.testing.assert_close(ukf.history.omega[:, 0], res.scenario.omega_est0)
    # no update keeps the torque-free motion of the wrong initial rate
    J = torch.tensor(cfg.shape.inertia_kg_m2, dtype=torch.float64)
    q0 = torch.tensor(cfg.scenario.q0, dtype=torch.float64)
    w_true = propagate(q0, torch.deg2rad(torch.tensor(cfg.scenario.omega0_deg_s, dtype=torch.float64)), J, 1.0, 200)[1]
    w_est0 = [w + e for w, e in zip(cfg.scenario.omega0_deg_s, cfg.scenario.initial_omega_error_deg_s)]
    w_wrong = propagate(q0, torch.deg2rad(torch.tensor(w_est0, dtype=torch.float64)), J, 1.0, 200)[1]
    final = torch.rad2deg(torch.linalg.vector_norm(w_wrong[-1] - w_true[-1]))
    torch.testing.assert_close(ref.omega_error_final_deg_s, final.expand(2), rtol=1e-12, atol=0)
    # the filter's rate moved away from that propagation, and the light curve shrank its rate covariance
    assert (torch.rad2deg(ukf.history.omega[:, -1] - w_wrong[-1]).abs().max(-1).values > 1e-3).all()
    P_w = ukf.history.P_full[..., 3:6, 3:6].diagonal(dim1=-2, dim2=-1).sum(-1)
    assert (P_w[:, -1] < P_w[:, 0]).all()
    summary = scenario_summary(res)["estimators"]["matched_ukf"]
    assert summary["nees_full_band_95"][0] < 6 < summary["nees_full_band_95"][1]
