"""experiments/realistic_noise.py --quick: one table row per (σ, case, estimator) with the bound beside the RMSE, the
cases kept in the store (a rerun computes nothing), and a missing GP refused instead of trained."""

import csv

import pytest

from experiments import realistic_noise
from lightcurve_gp.config.load import ConfigError, load_config


@pytest.mark.slow  # ~20 s: four estimators on two cases of two seeds
def test_quick_run_writes_one_row_per_estimator_and_resumes(tmp_path, capsys):
    args = ["--quick", "--sigmas", "0.1", "--paper-seeds", "0:2", "--random-seeds", "2000:2002",
            "--runs", str(tmp_path / "runs"), "--out", str(tmp_path / "out")]
    assert realistic_noise.main(args) == 0
    rows = list(csv.DictReader((tmp_path / "out" / "summary.csv").open()))
    assert [(r["case"], r["estimator"]) for r in rows] == [
        (case, name) for case in ("paper", "random") for name in ("map", "matched_map", "surface_ukf_select",
                                                                   "matched_ukf")]
    for r in rows:
        rmse, crb, ratio = (list(map(float, r[k].split(" / "))) for k in (
            "RMSE yaw / pitch / roll (°)", "CRB yaw / pitch / roll (°)", "RMSE / CRB"))
        assert all(c > 0 for c in crb)
        assert ratio == pytest.approx([a / b for a, b in zip(rmse, crb)], abs=0.051)
    assert {r["share / matched_map"] for r in rows if r["estimator"] == "matched_map"} == {"1.00"}
    stored = sorted((tmp_path / "runs" / "realistic_noise" / "cases").iterdir())
    assert len(stored) == 8
    before = [p.stat().st_mtime_ns for p in stored]
    capsys.readouterr()
    assert realistic_noise.main(args) == 0
    assert [p.stat().st_mtime_ns for p in stored] == before  # every case read back, none rerun
    assert list(csv.DictReader((tmp_path / "out" / "summary.csv").open())) == rows


def test_a_missing_gp_is_an_error_not_a_training(tmp_path):
    cfg = load_config(realistic_noise.ROOT / "configs" / "boxwing_realistic.yaml")
    with pytest.raises(ConfigError, match=r"^--models: .*model.pt missing; train the robust GP"):
        realistic_noise.stored_model(cfg, tmp_path)
