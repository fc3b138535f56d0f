"""The estimator registry and harness: its checks, that an entry is the filter setup's run, the scores at the samples
an estimator gives, the MAP and the selecting surface filter through the harness, and the tables' views."""

import dataclasses
import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.rotations import quat_mul
from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation.harness import check_estimators, run_estimators, scenario_ambiguity_group
from lightcurve_gp.evaluation.registry import ESTIMATORS, map_checkpoints, run_surface_filter_selected
from lightcurve_gp.evaluation.reporting import scenario_summary, seed_rows
from lightcurve_gp.evaluation.scoring import Estimate, score
from lightcurve_gp.evaluation.suite_summary import suite_rows
from lightcurve_gp.filters.setup import run_filter, run_surface_filter
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario

from helpers import ToyModel

DT = torch.float64
CONFIGS = Path(__file__).resolve().parents[1] / "configs"
SHORT = ["scenario.duration_s=40", "evaluation.rmse_window_s=[20, 40]", "shape.box_grid=1", "shape.wing_grid=1"]


@pytest.fixture(scope="module")
def case():
    cfg = load_config(CONFIGS / "boxwing_robust.yaml", SHORT)
    scene = Scene.from_config(cfg)
    return cfg, scene, simulate_scenario(cfg, seeds=[0, 1, 2], rho_true=0.7, scene=scene)


def test_bad_estimator_lists_are_refused_with_the_reason(case):
    cfg = case[0]
    with pytest.raises(ValueError, match=f"^unknown estimator 'kalman'; choose from {', '.join(ESTIMATORS)}$"):
        check_estimators(cfg, ["ukf", "kalman"], None)
    with pytest.raises(ValueError, match="^the gpukf estimator needs a trained GP model"):
        check_estimators(cfg, ["gpukf"], None)
    toy = ToyModel()
    toy.config = {"target": "magnitude"}
    with pytest.raises(ValueError, match="^model.target: the GP was trained on target 'magnitude', the config says "
                                         "'rho_normalised'"):
        check_estimators(cfg, ["gpukf"], toy)
    rates = dataclasses.replace(cfg, filter=dataclasses.replace(cfg.filter, estimate_omega=True))
    with pytest.raises(ValueError, match="^map_offset: this estimator takes ω as known"):
        check_estimators(rates, ["ukf", "map_offset"], None)
    with pytest.raises(ValueError, match=r"^map_surface: this estimator runs under a fixed geometry only"):
        check_estimators(cfg, ["surface_ukf", "map_surface"], None, along_pass=True)


def test_an_entry_is_the_setups_filter_on_the_scenario(case):
    cfg, scene, sc = case
    result = run_estimators(cfg, sc, estimators=["ukf", "joint_ukf"], scene=scene)
    for name, rho, offset in (("ukf", cfg.filter.rho_assumed, False), ("joint_ukf", cfg.model.rho_reference, True)):
        direct = run_filter(cfg, Parametric(scene, rho), q_est0=sc.q_est0, observations=sc.observations,
                            increments=sc.increments_assumed, sigma0=sc.sigma0, offset=offset)
        assert torch.equal(result.results[name].q_est, direct.q_est)
        assert torch.equal(result.results[name].history.P, direct.P)
    assert torch.equal(result.results["joint_ukf"].offset_final, result.results["joint_ukf"].history.offset[:, -1])
    assert result.results["ukf"].offset_final is None


def test_scores_at_an_estimators_own_samples(case):
    cfg, scene, sc = case
    group = scenario_ambiguity_group(cfg, sc, scene)
    full = run_estimators(cfg, sc, estimators=["matched_ukf"], scene=scene).results["matched_ukf"]
    samples = torch.tensor([20, 30, 40])
    part = score(sc, Estimate(full.q_est[:, samples], full.history.P[:, samples], samples=samples),
                 window=(20.0, 40.0), group=group, grp=(1.0, 4.0), seconds=0.0)
    assert torch.equal(part.errors_deg, full.errors_deg[:, samples])
    by_hand = full.errors_deg[:, samples].pow(2).mean(1).sqrt()
    torch.testing.assert_close(part.rmse_deg, by_hand, rtol=1e-14, atol=0)
    torch.testing.assert_close(part.white_last, full.white_last, rtol=1e-12, atol=0)  # both end at t = 40 s
    # the truth itself scores zero everywhere, strictly and modulo symmetry, and has no NEES without a covariance
    truth = score(sc, Estimate(sc.q_true, None), window=(20.0, 40.0), group=group, grp=(1.0, 4.0), seconds=0.0)
    assert float(truth.rmse_deg.abs().max()) < 1e-6 and float(truth.rmse_mod_symmetry_deg.abs().max()) < 1e-6
    assert truth.symmetry_index.tolist() == [0, 0, 0] and bool(torch.isnan(truth.nees_mean).all())


def _image_curves(scene, sc, group, inertia):
    """Light curves ``(K, S, T+1)`` of the images of the scenario's initial states, each propagated with its own
    image rate (the known rate when the group keeps it), and the truths' curves ``(S, T+1)``."""
    q_img = group.attitudes(sc.q_true[:, 0])  # (K, S, 4)
    w_img = sc.omega_true[:, 0].expand(len(group), -1, 3) if group.rate_known else group.rates(sc.omega_true[:, 0])
    q, _ = propagate(q_img, w_img, inertia, sc.times[1] - sc.times[0], sc.steps)
    return scene.magnitude(q), scene.magnitude(sc.q_true)


@pytest.mark.parametrize("estimate_omega", [False, True])
def test_the_harness_scores_modulo_the_scenarios_derived_images(case, estimate_omega):
    """The harness's images are the scenario's derived group: with the spin known the four inertial turns and no
    body rotation (a body turn would turn the known rate: its curve differs), with the rate estimated body × inertial
    (16). Every image used reproduces the scenario's light curves to 1e-9 mag, is named in the summary, and the
    truth's image scores zero modulo the group."""
    cfg, scene, sc = case
    if estimate_omega:
        cfg = dataclasses.replace(cfg, filter=dataclasses.replace(cfg.filter, estimate_omega=True))
    group = scenario_ambiguity_group(cfg, sc, scene)
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=DT)
    curves, truth = _image_curves(scene, sc, group, inertia)
    assert float((curves - truth).abs().max()) < 1e-9
    identity = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=DT)
    if estimate_omega:
        assert len(group) == 16 and not group.rate_known
    else:
        assert len(group) == 4 and torch.equal(group.body, identity.expand(4, 4))
        turned = scene.magnitude(propagate(quat_mul(torch.tensor([0.0, 0.0, 1.0, 0.0], dtype=DT), sc.q_true[:, 0]),
                                           sc.omega_true[:, 0], inertia, 1.0, sc.steps)[0])
        assert float((turned - truth).abs().max()) > 1e-3  # the body 180° z turn with the known rate: no image
    result = run_estimators(cfg, sc, estimators=["no_update"], scene=scene)
    assert result.group.labels == group.labels
    assert scenario_summary(result)["ambiguity_images"]["labels"] == list(group.labels)
    q_est = group.attitudes(sc.q_true)[len(group) - 1]  # every seed on the last image
    r = score(sc, Estimate(q_est, None), window=(20.0, 40.0), group=group, grp=(1.0, 4.0), seconds=0.0)
    assert r.symmetry_index.tolist() == [len(group) - 1] * 3 and float(r.rmse_mod_symmetry_deg.max()) < 1e-6
    assert float(r.rmse_deg.min()) > 10.0


def test_along_a_pass_with_the_spin_known_the_only_image_is_the_truth():
    """Along the GEO pass (120 s) the moving Sun and observer break the inertial turns and the known rate rules out
    the body turns: the derived group is the identity alone, so the scores modulo symmetry are the strict ones."""
    cfg = load_config(CONFIGS / "geo_pass.yaml", ["scenario.duration_s=120", "evaluation.rmse_window_s=[0, 120]",
                                                  "shape.box_grid=1", "shape.wing_grid=1"])
    sc = simulate_scenario(cfg, seeds=[0])
    group = scenario_ambiguity_group(cfg, sc)
    assert group.labels == ("body identity · inertial identity",)
    assert torch.equal(group.body, torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=DT))


def test_the_map_runs_through_the_harness_at_its_checkpoints(case):
    cfg, scene, sc = case
    result = run_estimators(cfg, sc, estimators=["map_offset"], scene=scene, map_every_s=10.0)
    r = result.results["map_offset"]
    assert map_checkpoints(cfg, 10.0) == [20, 30, 40] and r.samples.tolist() == [20, 30, 40]
    assert r.q_est.shape == (3, 3, 4) and r.offset_final.shape == (3,) and r.history is None and not r.trajectory
    assert bool(torch.isfinite(r.rmse_deg).all()) and bool(torch.isfinite(r.nees_mean).all())
    assert bool(torch.isnan(r.lc_rmse_noisy).all())  # no light curve of its own


def test_tables_leave_the_no_update_nees_blank_and_the_suite_rows_want_drawn_truths(case):
    cfg, scene, sc = case
    result = run_estimators(cfg, sc, estimators=["ukf", "no_update"], scene=scene)
    nu = result.results["no_update"]
    # the propagated estimate keeps its prior: the NEES of the initial error against P0 = (p0_deg)² I at every step
    angle = sc.error.norm(dim=-1)
    torch.testing.assert_close(nu.nees_mean, (4 * torch.tan(angle / 4)) ** 2 / math.radians(cfg.filter.p0_deg) ** 2,
                               rtol=1e-9, atol=0)
    rows = {(r.estimator, r.seed): r for r in seed_rows(result)}
    assert rows["no_update", 1].nees_mean is None and rows["ukf", 1].nees_mean is not None
    summary = scenario_summary(result)["estimators"]
    assert math.isnan(summary["no_update"]["nees_mean"]) and math.isfinite(summary["ukf"]["nees_mean"])
    with pytest.raises(ValueError, match="^suite_rows: the scenario's truths were not drawn"):
        suite_rows(result, (0.2, 9.0), error_mode="random")


def test_the_selecting_surface_filter_runs_along_a_pass():
    cfg = load_config(CONFIGS / "geo_pass.yaml", ["scenario.duration_s=30", "evaluation.rmse_window_s=[10, 30]",
                                                  "shape.box_grid=1", "shape.wing_grid=1"])
    scene = Scene.from_config(cfg)
    sc = simulate_scenario(cfg, seeds=[0, 1], scene=scene)
    run = dict(q_est0=sc.q_est0, observations=sc.observations, increments=sc.increments, sigma0=sc.sigma0,
               geometry=sc.geometry)
    kept, index = run_surface_filter_selected(cfg, scene, **run)
    julier = dataclasses.replace(cfg, filter=dataclasses.replace(cfg.filter, lam_rule="julier"))
    alone = [run_surface_filter(c, scene, **run) for c in (cfg, julier)]
    for b, k in enumerate(index.tolist()):
        assert torch.equal(kept.q_est[b], alone[k].q_est[b])
