"""estimate --light-curve FILE --solutions solutions.ecsv: the filter starts from the inversion's best family (its
attitude and its body rate), and conflicting or broken inputs are one-line errors."""

import json
import math
from pathlib import Path

import pytest
import torch
from astropy.table import Table

from lightcurve_gp.commands import estimate
from lightcurve_gp.commands.layout import light_curve_folder
from lightcurve_gp.inference.families import Families
from lightcurve_gp.observed.solutions import solutions_table, write_solutions

from helpers import as_sets, simulate_file, tiny_training, train_tiny

ROBUST = str(Path(__file__).resolve().parents[1] / "configs" / "boxwing_robust.yaml")
SETS = as_sets(tiny_training("tiny_inv"))

pytestmark = pytest.mark.slow  # trains a GP of its own


def _solutions(path: Path, q: list[float], omega_deg_s: list[float]) -> Path:
    """A two-family solutions file whose best family is ``(q, ω)``."""
    f64 = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    fam = Families(q0=f64([q, [0.0, 0.0, 0.0, 1.0]]), omega0=torch.deg2rad(f64([omega_deg_s, [0.1, 0.0, 0.0]])),
                   log_rho=f64([math.log(0.7), math.log(0.3)]), log_likelihood=f64([10.0, 5.0]),
                   log_evidence=f64([1.0, -4.0]), weight=f64([0.99, 0.01]),
                   mass=f64([1.0, 1.0]), p_right=f64([0.99, 0.01]),
                   covariance=torch.diag_embed(torch.full((2, 7), 1e-4, dtype=torch.float64)),
                   members=torch.tensor([3, 1]), images=("body identity · inertial identity",))
    write_solutions(solutions_table(fam), path)
    return path


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    return train_tiny(ROBUST, tmp_path_factory.mktemp("runs"), "tiny_inv")


def test_estimate_starts_from_the_best_family(tmp_path, model):
    obs = simulate_file(ROBUST, tmp_path, SETS, "--rho-true", "0.7")
    truth = Table.read(tmp_path / "obs.truth.ecsv", format="ascii.ecsv")
    q0 = [float(truth[f"q{i}"][0]) for i in range(1, 5)]
    w_deg = [float(truth[f"omega_{a}"][0]) for a in "xyz"]  # deg/s, as its unit says
    sol = _solutions(tmp_path / "solutions.ecsv", q0, w_deg)
    out = tmp_path / "out"
    assert estimate.main([ROBUST, "--model", str(model), "--light-curve", str(obs), "--solutions", str(sol),
                          "--out", str(out), "--no-progress", "--estimators", "gpukf", *SETS]) == 0
    summary = json.loads((light_curve_folder(out, "tiny_inv", obs) / "summary.json").read_text())
    assert summary["initial_attitude"] == pytest.approx(q0, abs=1e-12)
    assert summary["run"]["solutions"] == str(sol)
    assert summary["run"]["config"]["scenario"]["omega0_deg_s"] == pytest.approx(w_deg, rel=1e-12)
    assert "bank" not in summary


def test_solutions_conflicts_and_bad_files_are_one_line(tmp_path, capsys, model):
    obs = simulate_file(ROBUST, tmp_path, SETS)
    sol = _solutions(tmp_path / "solutions.ecsv", [0.0, 0.0, 0.0, 1.0], [0.1, -0.1, -0.25])
    common = [ROBUST, "--model", str(model), "--light-curve", str(obs), "--out", str(tmp_path / "o"), "--no-progress",
              *SETS]
    broken = tmp_path / "broken.ecsv"
    broken.write_text("not a table\n")
    for extra, message in ((["--solutions", str(sol), "--initial-attitude=0,0,0,1"], "give --initial-attitude or"),
                           (["--solutions", str(broken)], "broken.ecsv: not a solutions ECSV file")):
        assert estimate.main(common + extra) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("error: ") and message in err
