"""Scenario simulation, the parametric model, and the estimators on the paper's scenario (short runs)."""

import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.dynamics import propagate_only
from lightcurve_gp.attitude.metrics import total_angle_deg
from lightcurve_gp.attitude.rotations import euler321_to_quat, quat_mul
from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation.reporting import scenario_summary
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario

from helpers import estimate_scenario

BOXWING = Path(__file__).resolve().parents[1] / "configs" / "boxwing.yaml"


def test_noise_of_a_seed_does_not_depend_on_its_neighbours():
    cfg = load_config(BOXWING, ["scenario.duration_s=50", "evaluation.rmse_window_s=[10, 50]"])
    alone = simulate_scenario(cfg, seeds=[3])
    together = simulate_scenario(cfg, seeds=[1, 3, 5])
    assert torch.equal(alone.observations[0], together.observations[1])
    assert not torch.equal(together.observations[0], together.observations[1])


def test_noise_has_the_configured_variance():
    cfg = load_config(BOXWING)
    sc = simulate_scenario(cfg, seeds=range(40))
    noise = sc.observations - sc.m_clean
    assert float(noise.mean()) == pytest.approx(0.0, abs=0.02)
    assert float(noise.var()) == pytest.approx(cfg.scenario.noise_var, rel=0.03)


def test_initial_estimate_carries_the_configured_euler_error():
    cfg = load_config(BOXWING)
    sc = simulate_scenario(cfg, seeds=[0])
    error = euler321_to_quat(torch.deg2rad(torch.tensor(cfg.scenario.initial_error_deg, dtype=torch.float64)))
    assert torch.allclose(quat_mul(error, sc.q_true[0, 0]), sc.q_est0[0], atol=1e-15)
    expected = math.degrees(2 * math.acos(abs(float(error[3]))))
    assert float(total_angle_deg(sc.q_true[0, 0], sc.q_est0[0])) == pytest.approx(expected, abs=1e-9)


def test_parametric_model_is_the_renderer_and_ignores_m_past():
    cfg = load_config(BOXWING)
    scene = Scene.from_config(cfg)
    model = Parametric(scene, rho=0.3)
    gen = torch.Generator().manual_seed(0)
    q = torch.nn.functional.normalize(torch.randn(2, 5, 4, dtype=torch.float64, generator=gen), dim=-1)
    mean, var = model(q=q, m_past=torch.full((2, 5), 11.0, dtype=torch.float64))
    assert torch.equal(mean, scene.magnitude(q, rho=0.3))
    assert torch.equal(var, torch.zeros_like(mean))
    mean2, none = model.predict(q, torch.zeros(2, 5, dtype=torch.float64), variance="none")
    assert none is None and torch.equal(mean, mean2)
    m32, _ = model.to(torch.float32)(q=q.float(), m_past=torch.zeros(2, 5))
    assert m32.dtype == torch.float32 and float((m32.double() - mean).abs().max()) < 1e-4
    with pytest.raises(ValueError, match="rho: 1.5 is outside"):
        Parametric(scene, rho=1.5)
    with pytest.raises(ValueError, match=r"q must have shape \(..., 4\)"):
        model(q=torch.zeros(3, 3, dtype=torch.float64), m_past=torch.zeros(3, dtype=torch.float64))


def test_no_update_baseline_reproduces_the_propagated_initial_error():
    cfg = load_config(BOXWING)
    sc = simulate_scenario(cfg, seeds=[0])
    q = propagate_only(sc.q_est0[0], sc.increments[0])
    # A(q_est) = A(err) A(q_true) at t0 and the dynamics act on the left: the error attitude is conjugated by the
    # motion, so its rotation angle is constant along the whole run
    angles = total_angle_deg(sc.q_true[0], q)
    assert float(angles.max() - angles.min()) < 1e-9


def test_matched_ukf_converges_with_noise_free_observations():
    """Locally (2 deg initial error, the paper's light curve without noise) the matched filter locks on below 1 deg.

    From the paper's 15 deg initial error it does not within 600 s: the light curve's sensitivity to the weakest
    attitude direction is 1.8 mag/rad summed over the whole run (see README).
    """
    cfg = load_config(BOXWING, ["scenario.noise_var=1e-12", "filter.measurement_noise=1e-3", "filter.process_noise=0",
                                "scenario.initial_error_deg=[-2, 1, -2]", "filter.p0_deg=3"])
    res = estimate_scenario(cfg, seeds=[0], estimators=("matched_ukf",))
    final = total_angle_deg(res.scenario.q_true[0, -1], res.results["matched_ukf"].q_est[0, -1])
    assert float(final) < 1.0


@pytest.mark.slow  # ~6 s on two loaded cores
def test_conventional_ukf_suffers_from_a_rho_mismatch_that_the_matched_one_does_not_have():
    """The paper's Fig. 10 without noise: ρ_ukf = 0.5 on ρ_true = 0.7 loses the attitude."""
    cfg = load_config(BOXWING, ["scenario.noise_var=1e-12", "filter.measurement_noise=0.02"])
    res = estimate_scenario(cfg, seeds=[0], rho_true=0.7, estimators=("ukf", "matched_ukf"))
    summary = scenario_summary(res)["estimators"]
    ukf, matched = summary["ukf"], summary["matched_ukf"]
    assert max(ukf["rmse_deg_median"]) > 3 * max(matched["rmse_deg_median"])
    assert ukf["lc_rmse_clean_median"] > 10 * matched["lc_rmse_clean_median"]


@pytest.mark.slow  # ~5 s on two loaded cores
def test_rho_is_a_pure_offset_for_the_matched_filter():
    """Diffuse-dominated light curve: the matched filter at ρ = 0.7 behaves as the one at ρ = 0.5 on the same noise.

    Not bit-identical: sigma points ~17° off the truth see a specular share of order 1e-6.
    """
    cfg = load_config(BOXWING, ["scenario.seeds=4"])
    a = estimate_scenario(cfg, rho_true=0.7, estimators=("matched_ukf",)).results["matched_ukf"]
    b = estimate_scenario(cfg, rho_true=0.5, estimators=("matched_ukf",)).results["matched_ukf"]
    assert float((a.q_est - b.q_est).abs().max()) < 1e-3
    assert float((a.rmse_deg - b.rmse_deg).abs().max()) < 0.02


def test_unknown_estimator_and_missing_model_are_reported():
    cfg = load_config(BOXWING)
    with pytest.raises(ValueError, match="unknown estimator 'kalman'"):
        estimate_scenario(cfg, seeds=[0], estimators=("kalman",))
    with pytest.raises(ValueError, match="needs a trained GP model"):
        estimate_scenario(cfg, seeds=[0], estimators=("gpukf",))


@pytest.mark.slow  # ~5 s on two loaded cores
def test_joint_ukf_estimates_the_offset_of_an_unknown_rho():
    """The renderer at rho_reference with the offset in the state: its offset converges to -2.5 log10(rho/rho_ref)
    within its own uncertainty and its attitude is as good as the matched-rho UKF's (every axis below 10°), while
    the conventional UKF with rho_assumed = 0.5 fails."""
    from lightcurve_gp.filters.offset import rho_to_offset

    cfg = load_config(BOXWING, ["scenario.noise_var=0.01", "filter.measurement_noise=0.01"])
    res = estimate_scenario(cfg, seeds=range(3), rho_true=0.3, estimators=("ukf", "matched_ukf", "joint_ukf"))
    joint = res.results["joint_ukf"]
    b_true = rho_to_offset(0.3, cfg.model.rho_reference)
    err_b = (joint.history.offset[:, -1] - b_true).abs()
    assert bool((err_b < 3 * joint.history.offset_var[:, -1].sqrt()).all()), err_b
    matched, ukf = res.results["matched_ukf"].rmse_deg, res.results["ukf"].rmse_deg
    assert bool((joint.rmse_deg < 10).all()) and bool((matched < 10).all())
    assert float(ukf.min()) > float(joint.rmse_deg.max())
