"""A light-curve file along a pass: simulate writes the pass's geometry, estimate runs every step with its own
sample's geometry (a tiny body_geometry GP), with the bank and its pruning (the refusal of a model that takes no
geometry: tests/test_observed_cli.py)."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from astropy.table import Table

from lightcurve_gp.commands import estimate, simulate
from lightcurve_gp.config.load import load_config
from lightcurve_gp.observed.lightcurve_file import read_light_curve, write_light_curve
from lightcurve_gp.observed.run import file_geometry
from lightcurve_gp.passes.geometry import pass_geometry
from lightcurve_gp.training.store import open_model

from helpers import as_sets, estimate_scenario, simulate_file, tiny_training, train_tiny

ROOT = Path(__file__).resolve().parents[1]
GEO = str(ROOT / "configs" / "geo_pass.yaml")
TINY = tiny_training("tiny_geo")
SETS = as_sets(TINY)

pytestmark = pytest.mark.slow  # trains a GP of its own


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    return train_tiny(GEO, tmp_path_factory.mktemp("runs"), "tiny_geo")


def simulated(tmp_path, *extra):
    return simulate_file(GEO, tmp_path, SETS, *extra)


def estimated(tmp_path, model_file, obs, *extra, config=GEO, sets=SETS):
    out = tmp_path / "out"
    code = estimate.main([config, "--model", str(model_file), "--light-curve", str(obs), "--out", str(out),
                          "--no-progress", "--estimators", "gpukf", *sets, *extra])
    return code, out


def test_simulate_writes_the_pass_geometry(tmp_path):
    lc = read_light_curve(simulated(tmp_path, "--no-mag-err"))
    cfg = load_config(GEO, TINY)
    g = pass_geometry(cfg)
    assert lc.start.isot.startswith(cfg.geometry.start_utc)
    np.testing.assert_allclose(lc.geometry["sun"], g.sun.numpy(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(lc.geometry["obs"], g.observer.numpy(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(lc.geometry["range_km"] * 1e3, g.range_m.numpy(), rtol=1e-15)
    read_back = file_geometry(lc)
    torch.testing.assert_close(read_back.sun, g.sun, rtol=0, atol=1e-15)
    torch.testing.assert_close(read_back.times_s, g.times_s, rtol=0, atol=0)


def test_simulate_refuses_a_start_for_a_pass(tmp_path, capsys):
    assert simulate.main([GEO, "--out", str(tmp_path / "x.ecsv"), "--start", "2025-01-01T00:00:00", "--no-progress",
                          *SETS]) == 2
    assert capsys.readouterr().err.startswith("error: --start: a pass config starts at geometry.start_utc")
    assert not (tmp_path / "x.ecsv").exists()


def test_file_along_a_pass_reproduces_the_in_memory_run(tmp_path, model_file):
    obs = simulated(tmp_path, "--no-mag-err")
    q_est0 = Table.read(tmp_path / "obs.truth.ecsv").meta["q_est0"]
    code, out = estimated(tmp_path, model_file, obs, "--initial-attitude=" + ",".join(repr(v) for v in q_est0))
    assert code == 0
    folder = out / "estimates" / "tiny_geo" / "light_curve_obs"
    cfg = load_config(GEO, TINY)
    memory = estimate_scenario(cfg, open_model(model_file), seeds=[2], estimators=["gpukf"])
    h = memory.results["gpukf"].history
    table = Table.read(folder / "attitude_history.ecsv")
    # the file's increments are closed form, the simulation's RK4 steps of dt_s: they agree to RK4's error, which is
    # all that separates the two runs (6.6e-14 here)
    np.testing.assert_allclose(np.stack([table[f"q{i}"] for i in range(1, 5)], -1), h.q_est[0].numpy(), rtol=0,
                               atol=1e-8)
    np.testing.assert_allclose(table["mag_pred"][1:], h.y_pred[0, 1:].numpy(), rtol=0, atol=1e-7)
    assert json.loads((folder / "summary.json").read_text())["geometry"] == "per-sample columns"


def test_the_geometry_changes_the_prediction(tmp_path, model_file):
    """The same file with every sample's geometry replaced by sample 0's predicts differently: the columns are
    used (the in-memory run above is the pass's own geometry)."""
    obs = simulated(tmp_path, "--no-mag-err")
    lc = read_light_curve(obs)
    q_est0 = Table.read(tmp_path / "obs.truth.ecsv").meta["q_est0"]
    start = "--initial-attitude=" + ",".join(repr(v) for v in q_est0)
    for key in ("sun", "obs", "range_km"):
        lc.geometry[key] = np.repeat(lc.geometry[key][:1], lc.t.size, axis=0)
    frozen = write_light_curve(lc, tmp_path / "frozen.ecsv")
    assert estimated(tmp_path, model_file, obs, start)[0] == 0
    assert estimated(tmp_path, model_file, frozen, start)[0] == 0
    tables = [Table.read(tmp_path / "out" / "estimates" / "tiny_geo" / f"light_curve_{n}" / "attitude_history.ecsv")
              for n in ("obs", "frozen")]
    assert tables[0]["offset_mag"][0] == tables[1]["offset_mag"][0]  # b0: sample 0's geometry in both ...
    assert float(np.abs(tables[0]["mag_pred"][1:] - tables[1]["mag_pred"][1:]).min()) > 1e-6  # ... each step its own


def test_the_bank_runs_along_the_pass_with_pruning(tmp_path, model_file):
    obs = simulated(tmp_path)
    code, out = estimated(tmp_path, model_file, obs, "--bank-size", "16", "--bank-keep", "2",
                          "--bank-prune-after-s", "20", "--bank-prune-keep", "4")
    assert code == 0
    folder = out / "estimates" / "tiny_geo" / "light_curve_obs"
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["bank"]["pruned_to"] == 4 and summary["bank"]["size"] == 16
    bank = Table.read(folder / "bank.ecsv")
    assert np.all(bank["weight"][4:] == 0) and bank["weight"][:4].sum() == pytest.approx(1.0, abs=1e-12)
    assert list(bank["whole_curve"]) == [True] * 4 + [False] * 12
