"""The train and estimate commands on a tiny config: outputs, metrics and clear errors."""

import json
from pathlib import Path

import pytest
import torch

from lightcurve_gp.commands import estimate, train
from lightcurve_gp.observation import load_model

BOXWING = str(Path(__file__).resolve().parents[1] / "configs" / "boxwing.yaml")
TINY = ["data.icosphere_subdivisions=0", "data.phi_step_deg=120", "data.heldout_size=40", "scenario.duration_s=60",
        "evaluation.rmse_window_s=[30, 60]", "model.exact.fast_variance_neighbors=32", "name=tiny"]


def sets(overrides):
    return [arg for o in overrides for arg in ("--set", o)]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    assert train.main([BOXWING, "--out", str(out), "--no-progress", *sets(TINY)]) == 0
    return out


def test_train_writes_model_metrics_and_figures(trained, capsys):
    run = trained / "tiny"
    for name in ("model.pt", "metrics.json", "config.yaml", "heldout_scatter.png", "heldout_residuals.png"):
        assert (run / name).is_file(), name
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["train_points"] == 12 * 3 * 5
    held = metrics["heldout"]
    assert held["n"] == 40 and held["mae"] <= held["rmse"]  # the mean of |r| never exceeds the root mean square
    fv = metrics["fast_variance_vs_exact"]
    assert fv["n"] == 40 and fv["median_rel"] <= fv["max_rel"]
    # the saved model predicts the held-out RMSE it reported
    model = load_model(run / "model.pt")
    assert model.num_train == 180


def test_train_recomputes_its_heldout_metrics_from_the_saved_model(trained):
    from lightcurve_gp.config.load import load_config
    from lightcurve_gp.training.sets import generate_heldout_set

    cfg = load_config(BOXWING, TINY)
    held = generate_heldout_set(cfg)
    model = load_model(trained / "tiny" / "model.pt")
    mean, var = model(q=held.q, m_past=held.m_past, variance=cfg.model.variance)
    resid = mean - held.y
    std_y = (var + float(model.noise)).sqrt()  # predictive std of a noisy target
    reported = json.loads((trained / "tiny" / "metrics.json").read_text())["heldout"]
    assert float(resid.pow(2).mean().sqrt()) == pytest.approx(reported["rmse"], rel=1e-9)
    assert float(resid.abs().mean()) == pytest.approx(reported["mae"], rel=1e-9)
    assert float((resid.abs() <= 2 * std_y).double().mean()) == reported["within_2sigma"]


def test_sparse_model_trains_from_the_command_line(tmp_path):
    assert train.main([BOXWING, "--out", str(tmp_path), "--no-progress",
                       *sets([s for s in TINY if not s.startswith("model.exact.")]  # settings of the exact GP
                             + ["model.kind=sparse", "model.sparse.num_inducing=20",
                                "model.sparse.iterations=0"])]) == 0
    metrics = json.loads((tmp_path / "tiny" / "metrics.json").read_text())
    assert metrics["model"] == "sparse" and metrics["fast_variance_vs_exact"] is None


def test_bad_config_value_is_reported_with_its_key(tmp_path, capsys):
    assert train.main([BOXWING, "--out", str(tmp_path), "--set", "model.noise_std=-1"]) == 2
    assert capsys.readouterr().err == "error: model.noise_std: -1 must be > 0\n"
    assert not (tmp_path / "boxwing").exists()


@pytest.mark.slow
def test_estimate_prints_the_table_and_writes_results(trained, tmp_path, capsys):
    code = estimate.main([BOXWING, "--model", str(trained / "tiny" / "model.pt"), "--seeds", "3", "--rho-true", "0.7",
                          "--estimators", "paper", "--out", str(tmp_path), *sets(TINY)])
    assert code == 0
    printed = capsys.readouterr().out
    for name in ("gpukf", "ukf", "matched_ukf", "no_update", "rho_true = 0.7"):
        assert name in printed
    folder = tmp_path / "estimates" / "tiny" / "rho0.7"
    results = json.loads((folder / "results.json").read_text())
    assert set(results["estimators"]) == {"gpukf", "ukf", "matched_ukf", "no_update"}
    assert len(results["per_seed_rmse_deg"]["gpukf"]) == 3
    assert all(len(row) == 3 for row in results["per_seed_rmse_deg"]["ukf"])
    for png in ("euler_errors.png", "light_curves.png", "rmse_boxplot.png"):
        assert (folder / png).stat().st_size > 1000


def test_estimate_errors_are_clear(tmp_path, capsys):
    bad = tmp_path / "model.pt"
    bad.write_bytes(b"garbage")
    assert estimate.main([BOXWING, "--model", str(bad), *sets(TINY)]) == 2
    assert capsys.readouterr().err == (f"error: {bad}: not a lightcurve-gp model file (not a PyTorch archive; "
                                       f"train one with python -m lightcurve_gp.train)\n")
    assert estimate.main([BOXWING, "--rho-true", "1.5", *sets(TINY)]) == 2
    assert capsys.readouterr().err == "error: --rho-true: 1.5 is outside (0, 1]\n"
    assert estimate.main([BOXWING, "--estimators", "ukf,kalman", "--seeds", "1", "--out", str(tmp_path),
                          *sets(TINY)]) == 2
    assert capsys.readouterr().err == ("error: --estimators: unknown estimator 'kalman'; choose from gpukf, ukf, "
                                       "matched_ukf, joint_ukf, surface_ukf, surface_ukf_select, map_surface, "
                                       "map_offset, map, matched_map, no_update\n")
    assert list(tmp_path.iterdir()) == [bad]


ROBUST = str(Path(__file__).resolve().parents[1] / "configs" / "boxwing_robust.yaml")
ROBUST_TINY = ["data.num_random=100", "data.rho_grid=[0.3, 0.5, 0.7]", "data.heldout_size=40",
               "model.sparse.num_inducing=60",
               "scenario.duration_s=60", "evaluation.rmse_window_s=[30, 60]", "name=robust_tiny"]


@pytest.mark.slow  # trains a GP of its own
def test_offset_config_trains_on_normalised_magnitudes_and_estimates_with_the_offset_filter(tmp_path, capsys):
    """The robust config end to end from the commands: the GP learns the reference curve (rho_reference) and the
    estimate command runs the offset filter, whose offset recovers rho_true."""
    from lightcurve_gp.config.load import load_config
    from lightcurve_gp.training.sets import generate_heldout_set

    assert train.main([ROBUST, "--out", str(tmp_path), "--no-progress", *sets(ROBUST_TINY)]) == 0
    run = tmp_path / "robust_tiny"
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["target"] == "rho_normalised"
    # held-out metrics are on the normalised targets: recompute them from the model and the raw held-out set
    cfg = load_config(ROBUST, ROBUST_TINY)
    held = generate_heldout_set(cfg)
    model = load_model(run / "model.pt")
    mean, _ = model(q=held.q, m_past=held.m_past, variance="none")
    reference = held.y + 2.5 * torch.log10(held.rho / cfg.model.rho_reference)
    assert float((mean - reference).pow(2).mean().sqrt()) == pytest.approx(metrics["heldout"]["rmse"], rel=1e-9)
    raw_rmse = float((mean - held.y).pow(2).mean().sqrt())
    assert abs(raw_rmse - metrics["heldout"]["rmse"]) > 1e-3  # the reported metric is not on raw magnitudes

    assert estimate.main([ROBUST, "--model", str(run / "model.pt"), "--seeds", "3", "--rho-true", "0.3",
                          "--estimators", "gpukf,joint_ukf", "--out", str(tmp_path), *sets(ROBUST_TINY)]) == 0
    result = json.loads((tmp_path / "estimates" / "robust_tiny" / "rho0.3" / "results.json").read_text())
    assert set(result["estimators"]) == {"gpukf", "joint_ukf"}
    assert "gpukf" in capsys.readouterr().out


def test_a_model_trained_for_another_config_is_refused(trained, tmp_path, capsys):
    model = trained / "tiny" / "model.pt"
    assert estimate.main([ROBUST, "--model", str(model), "--seeds", "2", "--out", str(tmp_path),
                          *sets(ROBUST_TINY)]) == 2
    assert capsys.readouterr().err == (f"error: --model {model}: data.rho_grid: the model was trained with [0.1, "
                                       f"0.3, 0.5, 0.7, 0.9], the config says [0.3, 0.5, 0.7]; train a model with "
                                       f"this config or pass --allow-model-mismatch\n")


def test_offset_filter_without_a_normalised_gp_is_a_config_error(tmp_path, capsys):
    assert train.main([BOXWING, "--out", str(tmp_path), "--no-progress", *sets(TINY),
                       "--set", "filter.estimate_offset=true"]) == 2
    assert "filter.estimate_offset: true needs model.target: rho_normalised" in capsys.readouterr().err
