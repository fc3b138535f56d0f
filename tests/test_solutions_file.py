"""The solutions file: ``mass`` and ``p_right`` written beside the weights, read back, checked as probabilities, and
optional for files written before them."""

import math

import numpy as np
import pytest
import torch

from lightcurve_gp.inference.families import Families
from lightcurve_gp.observed.solutions import SolutionsFileError, read_solutions, solutions_table, write_solutions


def _families(mass: list[float]) -> Families:
    f64 = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    weight = f64([0.7, 0.3])
    return Families(q0=f64([[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 1.0, 0.0]]),
                    omega0=torch.deg2rad(f64([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])),
                    log_rho=f64([math.log(0.7), math.log(0.3)]), log_likelihood=f64([10.0, 9.0]),
                    log_evidence=f64([1.0, 1.0 + math.log(3 / 7)]), weight=weight, mass=f64(mass),
                    p_right=weight * f64(mass),
                    covariance=torch.diag_embed(torch.full((2, 7), 1e-4, dtype=torch.float64)),
                    members=torch.tensor([3, 1]), images=("body identity · inertial identity",))


def test_p_right_is_written_and_read_back(tmp_path):
    path = tmp_path / "solutions.ecsv"
    write_solutions(solutions_table(_families([0.9, 0.2])), path)
    table = read_solutions(path)
    np.testing.assert_allclose(np.asarray(table["p_right"]), [0.63, 0.06], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(table["mass"]), [0.9, 0.2], rtol=1e-12)


def test_files_without_p_right_still_read(tmp_path):
    path = tmp_path / "old.ecsv"
    table = solutions_table(_families([0.9, 0.2]))
    table.remove_columns(["mass", "p_right"])
    write_solutions(table, path)
    assert "p_right" not in read_solutions(path).colnames


def test_a_p_right_outside_0_1_is_one_line(tmp_path):
    path = tmp_path / "bad.ecsv"
    table = solutions_table(_families([0.9, 0.2]))
    table["p_right"][1] = 1.5
    write_solutions(table, path)
    with pytest.raises(SolutionsFileError, match=r"^.*bad\.ecsv: column p_right, row 2: 1\.5 is not a probability "
                                                 r"in \[0, 1\]$"):
        read_solutions(path)
