"""simulate → estimate --light-curve on a tiny robust model: the round trip, the bank, geometry and bad files."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from astropy.table import Table
from scipy.stats import norm

from lightcurve_gp.commands import estimate, simulate
from lightcurve_gp.config.load import load_config
from lightcurve_gp.filters.selection import innovation_log_likelihood
from lightcurve_gp.filters.setup import run_filter
from lightcurve_gp.observed.lightcurve_file import read_light_curve, write_light_curve
from lightcurve_gp.observed.run import file_inputs
from lightcurve_gp.training.store import open_model

from helpers import as_sets, estimate_scenario, simulate_file, tiny_training, train_tiny

ROBUST = str(Path(__file__).resolve().parents[1] / "configs" / "boxwing_robust.yaml")
TINY = tiny_training("tiny_robust")
SETS = as_sets(TINY)

pytestmark = pytest.mark.slow  # trains a GP of its own


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    return train_tiny(ROBUST, tmp_path_factory.mktemp("runs"), "tiny_robust")


def simulated(tmp_path, *extra):
    return simulate_file(ROBUST, tmp_path, SETS, "--rho-true", "0.7", *extra)


def estimated(tmp_path, model_file, obs, *extra):
    out = tmp_path / "out"
    code = estimate.main([ROBUST, "--model", str(model_file), "--light-curve", str(obs), "--out", str(out),
                          "--no-progress", "--estimators", "gpukf", *SETS, *extra])
    return code, out / "estimates" / "tiny_robust" / f"light_curve_{obs.stem}"


def test_round_trip_reproduces_the_in_memory_run(tmp_path, model_file):
    obs = simulated(tmp_path, "--no-mag-err")
    q_est0 = Table.read(tmp_path / "obs.truth.ecsv").meta["q_est0"]
    code, folder = estimated(tmp_path, model_file, obs, "--initial-attitude=" + ",".join(repr(v) for v in q_est0))
    assert code == 0
    cfg = load_config(ROBUST, TINY)
    memory = estimate_scenario(cfg, open_model(model_file), seeds=[2], rho_true=0.7, estimators=["gpukf"])
    h = memory.results["gpukf"].history
    table = Table.read(folder / "attitude_history.ecsv")
    q_file = np.stack([table[f"q{i}"] for i in range(1, 5)], -1)
    # the file's increments are closed form, the simulation's RK4 steps of dt_s: they agree to RK4's error (~1e-11
    # rad per step at this rate), which is all that separates the two runs
    np.testing.assert_allclose(q_file, h.q_est[0].numpy(), rtol=0, atol=1e-8)
    np.testing.assert_allclose(table["mag_pred"][1:], h.y_pred[0, 1:].numpy(), rtol=0, atol=1e-7)
    np.testing.assert_allclose(table["offset_mag"], h.offset[0].numpy(), rtol=0, atol=1e-7)
    for name in ("light_curve.png", "attitude.png", "summary.json"):
        assert (folder / name).is_file()
    nis = json.loads((folder / "summary.json").read_text())["nis"]
    assert nis["n"] == 60 and nis["band_95"][0] < 1 < nis["band_95"][1]


def test_mag_err_becomes_the_per_sample_noise(tmp_path, model_file):
    obs = simulated(tmp_path)
    lc = read_light_curve(obs)
    cfg = load_config(ROBUST, TINY)
    y, increments, R = file_inputs(cfg, lc)
    assert torch.equal(R, torch.full_like(y, math.sqrt(0.5)) ** 2)
    q0 = torch.tensor(Table.read(tmp_path / "obs.truth.ecsv").meta["q_est0"], dtype=torch.float64)
    code, folder = estimated(tmp_path, model_file, obs, "--initial-attitude=" + ",".join(repr(float(v)) for v in q0))
    assert code == 0
    expected = run_filter(cfg, open_model(model_file), q_est0=q0[None], observations=y[None], increments=increments,
                          R=R[None])
    table = Table.read(folder / "attitude_history.ecsv")
    np.testing.assert_array_equal(table["mag_pred_sigma"][1:], expected.y_var[0, 1:].sqrt().numpy())


def test_bank_ranks_every_member_and_reports_the_best(tmp_path, model_file):
    obs = simulated(tmp_path)
    lc = read_light_curve(obs)
    keep = np.r_[0:10, 13:40, 52:61]  # gaps: the filter steps over them
    lc.t, lc.mag, lc.mag_err = lc.t[keep], lc.mag[keep], lc.mag_err[keep]
    gappy = write_light_curve(lc, tmp_path / "gappy.ecsv")
    code, folder = estimated(tmp_path, model_file, gappy, "--bank-size", "16", "--bank-keep", "3")
    assert code == 0
    bank = Table.read(folder / "bank.ecsv")
    assert len(bank) == 16 and sorted(bank["member"]) == list(range(16))
    assert np.all(np.diff(bank["log_likelihood"]) <= 0)
    assert bank["weight"].sum() == pytest.approx(1.0, abs=1e-12)
    history = Table.read(folder / "attitude_history.ecsv")
    assert len(history) == keep.size
    best = [bank[f"q0_{i}"][0] for i in range(1, 5)]
    np.testing.assert_allclose([history[f"q{i}"][0] for i in range(1, 5)], best, rtol=0, atol=1e-15)


def test_log_likelihood_is_the_gaussian_density_of_the_innovations(tmp_path, model_file):
    obs = simulated(tmp_path)
    cfg = load_config(ROBUST, TINY)
    y, increments, R = file_inputs(cfg, read_light_curve(obs))
    q0 = torch.tensor([[0.0, 0.0, 0.0, 1.0], [0.3, -0.2, 0.1, 0.9]], dtype=torch.float64)
    h = run_filter(cfg, open_model(model_file), q_est0=q0, observations=y.expand(2, -1), increments=increments)
    ll = innovation_log_likelihood(h)
    for b in range(2):
        mask = h.updated[b].numpy()
        expected = norm.logpdf(h.innovation[b].numpy()[mask], scale=np.sqrt(h.y_var[b].numpy()[mask])).sum()
        assert float(ll[b]) == pytest.approx(expected, rel=1e-12)


def test_geometry_a_fixed_geometry_model_cannot_use_is_refused(tmp_path, model_file, capsys):
    obs = simulated(tmp_path)
    lc = read_light_curve(obs)
    n = lc.t.size
    lc.geometry = {"sun": np.tile([1.0, 0.0, 0.0], (n, 1)), "obs": np.tile([0.0, 1.0, 0.0], (n, 1)),
                   "range_km": np.full(n, 36000.0)}
    geo = write_light_curve(lc, tmp_path / "geo.ecsv")
    code, folder = estimated(tmp_path, model_file, geo, "--initial-attitude=0,0,0,1")
    assert code == 2 and not folder.parent.exists()
    assert capsys.readouterr().err == (
        f"error: {geo}: the file gives per-sample geometry columns (sun_*, obs_*, range_km), but the model (inputs: "
        f"attitude_matrix) was trained under one fixed geometry and would ignore it; use a model with model.inputs: "
        f"body_geometry (e.g. configs/geo_pass.yaml) or remove the geometry from the file to run with the config's "
        f"fixed Sun and observer\n")


def test_a_bad_file_is_one_line_exit_2_and_nothing_written(tmp_path, model_file, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("time,mag,mag_err\n2025-01-01T00:00:00,13.0,0.5\n2025-01-01T00:00:01,13.1,-0.5\n")
    code, folder = estimated(tmp_path, model_file, bad)
    assert code == 2 and not (tmp_path / "out").exists()
    assert capsys.readouterr().err == f"error: {bad}: line 3: mag_err -0.5 is negative\n"


def test_simulate_refuses_to_overwrite_and_writes_both_files(tmp_path, capsys):
    obs = simulated(tmp_path)
    truth = Table.read(tmp_path / "obs.truth.ecsv")
    cfg = load_config(ROBUST, TINY)
    assert len(truth) == len(read_light_curve(obs).t) == round(cfg.scenario.duration_s / cfg.scenario.dt_s) + 1
    before = obs.read_bytes()
    code = simulate.main([ROBUST, "--out", str(obs), "--seed", "5", "--no-progress", *SETS])
    assert code == 2 and obs.read_bytes() == before
    assert capsys.readouterr().err.startswith(f"error: {obs}: already exists; pass --force")
    assert simulate.main([ROBUST, "--out", str(obs), "--seed", "5", "--force", "--no-progress", *SETS]) == 0
    assert obs.read_bytes() != before
