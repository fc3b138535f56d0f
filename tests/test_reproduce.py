"""The section-4 reproduction script end to end on its tiny --quick configuration."""

import csv
import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the experiments package lives at the repository root

from experiments import reproduce_paper as rp  # noqa: E402

TABLES = ("models", "variance_check", "rho_mismatch", "tspan", "robustness_attitude", "robustness_lightcurve", "cost")
FIGURES = ("rho_mismatch_euler_errors", "rho_mismatch_light_curves", "rho_mismatch_boxplot", "tspan_euler_errors",
           "tspan_light_curves", "tspan_boxplot",
           *(f"robustness_{kind}_rho{rho:g}" for rho in rp.RHOS_ROBUST
             for kind in ("euler_errors", "light_curves", "boxplot")))


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    base = tmp_path_factory.mktemp("repro")
    args = ["--quick", "--out", str(base / "runs"), "--results", str(base / "results"), "--no-progress"]
    assert rp.main(args) == 0
    return base, args


def test_quick_run_writes_every_promised_file(quick):
    base, _ = quick
    res = base / "results"
    for stem in TABLES:
        assert (res / f"{stem}.md").read_text().startswith("|"), stem
        assert read_csv(res / f"{stem}.csv"), stem
    for stem in FIGURES:
        assert (res / f"{stem}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", stem
    info = json.loads((res / "reproduction.json").read_text())
    assert sorted(info["figures"]) == sorted(f"{s}.png" for s in FIGURES)
    assert info["failed_cases"] == {} and info["seeds"] == 3 and info["wall_seconds"] > 0
    md = (res / "results.md").read_text()
    assert all(f"![{s}.png]({s}.png)" in md for s in FIGURES)
    # raw per-seed rows of each experiment: cases x seeds x estimators
    n_rows = {"tspan": 4 * 3 * 4, "robustness": 4 * 3 * 4, "rho_mismatch": 2 * 3 * 4, "variance_check": 2 * 2}
    for name, n in n_rows.items():
        rows = read_csv(base / "runs" / "paper_quick" / "sweep" / name / "results.csv")
        assert len(rows) == n and {r["status"] for r in rows} == {"ok"}, name


def test_tables_carry_the_paper_numbers_and_every_estimator(quick):
    base, _ = quick
    res = base / "results"
    rows = read_csv(res / "robustness_attitude.csv")
    assert [(float(r["rho_true"]), r["estimator"]) for r in rows] == [
        (rho, est) for rho in rp.RHOS_ROBUST for est in ("gpukf", "ukf", "matched_ukf", "no_update")]
    for r in rows:
        paper = rp.PAPER_ATTITUDE[float(r["rho_true"])].get(r["estimator"])
        got = tuple(float(r[f"{a}_paper"]) for a in ("yaw", "pitch", "roll")) if paper else None
        assert got == paper
        assert float(r["yaw_q25"]) <= float(r["yaw_median"]) <= float(r["yaw_q75"])
    lc = {(float(r["rho_true"]), r["estimator"]): r for r in read_csv(res / "robustness_lightcurve.csv")}
    assert float(lc[(0.4, "ukf")]["lc_noisy_paper"]) == 3.7277
    # the light curve against noisy observations can never beat the noise-free reference by much
    assert all(float(r["lc_noisy_median"]) > float(r["lc_clean_median"]) for r in lc.values())
    cost = read_csv(res / "cost.csv")
    assert {r["estimator"] for r in cost} == {"gpukf", "ukf", "matched_ukf", "no_update"}
    assert {float(r["paper_seconds_per_step"]) for r in cost if r["estimator"] == "gpukf"} == {
        0.8793, 0.8476, 0.8289, 0.8382}
    for stem in ("rho_mismatch", "tspan"):
        assert {r["estimator"] for r in read_csv(res / f"{stem}.csv")} == {"gpukf", "ukf", "matched_ukf", "no_update"}
    # the matched-rho UKF and the UKF with rho_ukf = rho_true = 0.5 are the same filter
    mm = {(float(r["rho_true"]), r["estimator"]): r for r in read_csv(res / "rho_mismatch.csv")}
    assert mm[(0.5, "ukf")]["rmse_yaw_median"] == mm[(0.5, "matched_ukf")]["rmse_yaw_median"]
    assert mm[(0.7, "ukf")]["rmse_yaw_median"] != mm[(0.7, "matched_ukf")]["rmse_yaw_median"]


def test_rerun_reuses_every_case_and_reproduces_the_numbers(quick):
    base, args = quick
    res = base / "results"
    before = {stem: (res / f"{stem}.csv").read_text() for stem in ("tspan", "robustness_attitude", "rho_mismatch")}
    again = base / "again"
    assert rp.main([*args[:-3], "--results", str(again), "--no-progress"]) == 0
    info = json.loads((again / "reproduction.json").read_text())
    assert info["cases_run_now"] == {"variance_check": 0, "tspan": 0, "robustness": 0, "rho_mismatch": 0}
    for stem, text in before.items():
        assert (again / f"{stem}.csv").read_text() == text
