"""The recommended estimator: the choice by config and data, and what ``estimate`` without ``--estimators`` does."""

import json
from pathlib import Path

import pytest

from lightcurve_gp.commands import estimate
from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation.recommend import GP_NOISE_MAG, recommend_estimator

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
REALISTIC = CONFIGS / "boxwing_realistic.yaml"
SHORT = ["scenario.duration_s=60", "evaluation.rmse_window_s=[30, 60]", "name=short"]


@pytest.mark.parametrize("sigma", [0.01, 0.05, 0.71])
@pytest.mark.parametrize("have_model", [False, True])
def test_a_shape_the_renderer_knows_with_omega_known_gets_the_whole_arc_map(sigma, have_model):
    rec = recommend_estimator(load_config(REALISTIC), noise_std=sigma, have_model=have_model)
    assert rec.name == "map"
    assert rec.line().startswith(f"recommended estimator: map — σ = {sigma:g} mag, the renderer knows the shape "
                                 "(box_wing)")
    assert ("the GP is not needed" in rec.reason) is have_model


def test_omega_estimated_gets_a_filter_that_estimates_it():
    cfg = load_config(REALISTIC, ["filter.estimate_omega=true"])
    assert recommend_estimator(cfg, noise_std=0.05, have_model=True).name == "joint_ukf"
    assert recommend_estimator(cfg, noise_std=GP_NOISE_MAG, have_model=True).name == "gpukf"
    assert recommend_estimator(cfg, noise_std=0.71, have_model=False).name == "joint_ukf"


def test_without_a_renderable_shape_only_the_gp_filter_is_left():
    cfg = load_config(REALISTIC)
    assert recommend_estimator(cfg, noise_std=0.05, have_model=True, shape_known=False).name == "gpukf"
    with pytest.raises(ValueError, match="^--model: without a shape the renderer knows"):
        recommend_estimator(cfg, noise_std=0.05, have_model=False, shape_known=False)
    for bad in (0.0, -0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="must be finite and > 0"):
            recommend_estimator(cfg, noise_std=bad, have_model=False)


@pytest.mark.slow
def test_estimate_without_estimators_runs_the_recommended_one_and_says_why(tmp_path, capsys):
    args = [str(REALISTIC), "--seeds", "2", "--out", str(tmp_path), "--no-progress",
            *[a for s in SHORT for a in ("--set", s)]]
    assert estimate.main(args) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == ("recommended estimator: map — σ = 0.05 mag, the renderer knows the shape (box_wing), surface "
                      "unknown, ω known: the surface-state filter, then the whole-arc MAP of attitude and surface "
                      "from 16 starts (24 below 0.1 mag), 8 more and 8 of 2048 screened prior attitudes and lobes "
                      "where the fit fails the misfit test, 2 more along each seed's weakest direction "
                      "(--estimators paper: the paper's estimators)")
    results = json.loads((tmp_path / "estimates" / "short" / "rho0.5" / "results.json").read_text())
    assert list(results["estimators"]) == ["map"]
    assert results["run"]["recommended"] == out[0].removesuffix(" (--estimators paper: the paper's estimators)")
    assert results["estimators"]["map"]["crb_deg_median"][0] > 0  # the bound beside the RMSE
    assert estimate.main([*args, "--force", "--estimators", "paper"]) == 0
    printed = capsys.readouterr().out
    assert "recommended estimator" not in printed
    results = json.loads((tmp_path / "estimates" / "short" / "rho0.5" / "results.json").read_text())
    assert list(results["estimators"]) == ["ukf", "matched_ukf", "no_update"]  # the paper's, no GP given
