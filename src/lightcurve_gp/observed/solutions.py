"""The solutions file of an inversion (``solutions.ecsv``): one row per family of the light curve, ranked by weight.

Columns: ``rank`` (1 = the heaviest), ``weight`` (Laplace-evidence weight, the rows sum to 1), ``log_likelihood`` and
``log_evidence`` (nats), ``q_x, q_y, q_z, q_w`` (the attitude at the first sample, scalar last, inertial → body),
``omega_x, omega_y, omega_z`` (body rate at the first sample, deg/s), ``rho`` (ρ̂), ``members`` (converged starts in
the family), and the 1σ of the Laplace covariance: ``sigma_att_x, sigma_att_y, sigma_att_z`` (deg, body-side rotation
of the first attitude), ``sigma_omega_x, …`` (deg/s), ``sigma_rho``; then ``mass`` (the Gaussian mass of the region
of "right" states about the family's mode: every Euler axis within 10° and the rate within 2 %,
:func:`~lightcurve_gp.inference.families.tolerance_mass`) and ``p_right``, the probability that the family's state is
the right answer: ``weight · mass`` and the mass the other families put within its tolerance
(:func:`~lightcurve_gp.inference.families.mixture_p_right`) (these two are optional on reading: files written before
them lack them). Metadata: ``images`` (the exact ambiguity images the families were taken modulo; every row stands
for all of them), ``light_curve``, ``config`` and, from ``invert``, ``verdict`` (``unique``, ``ambiguous`` or
``no_fit``: then no row is an answer), ``chi2_per_dof`` and ``p_value`` of the best fit.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from astropy.table import Table

from lightcurve_gp.inference.families import Families
from lightcurve_gp.observed.table_units import set_units
from lightcurve_gp.observed.table_write import write_table

__all__ = ["SolutionsFileError", "solutions_table", "write_solutions", "read_solutions", "best_solution", "rate_sigma"]

COLUMNS = ("rank", "weight", "log_likelihood", "log_evidence", "q_x", "q_y", "q_z", "q_w", "omega_x", "omega_y",
           "omega_z", "rho", "members", "sigma_att_x", "sigma_att_y", "sigma_att_z", "sigma_omega_x", "sigma_omega_y",
           "sigma_omega_z", "sigma_rho")
#: columns written since the families carry ``p_right``; checked when present, not required
OPTIONAL_COLUMNS = ("mass", "p_right")

#: every column's unit (:mod:`~lightcurve_gp.observed.table_units`): rates deg/s, the attitude's 1σ deg, the rest
#: dimensionless (the log-likelihood and evidence in nats, said in their descriptions)
UNITS = {**{c: "" for c in COLUMNS + OPTIONAL_COLUMNS}, **{f"omega_{a}": "deg / s" for a in "xyz"},
         **{f"sigma_att_{a}": "deg" for a in "xyz"}, **{f"sigma_omega_{a}": "deg / s" for a in "xyz"}}


class SolutionsFileError(ValueError):
    """A solutions file that cannot be used: one line naming the file and the problem."""


def solutions_table(fam: Families, meta: dict | None = None) -> Table:
    """The families as the file's table (module docstring)."""
    sd = torch.sqrt(torch.diagonal(fam.covariance, dim1=-2, dim2=-1).clamp_min(0.0)).cpu().numpy()  # (F, 7)
    q, w = fam.q0.cpu().numpy(), np.degrees(fam.omega0.cpu().numpy())
    rho = np.exp(fam.log_rho.cpu().numpy())
    cols = {"rank": np.arange(1, len(fam) + 1), "weight": fam.weight.cpu().numpy(),
            "log_likelihood": fam.log_likelihood.cpu().numpy(), "log_evidence": fam.log_evidence.cpu().numpy(),
            **{f"q_{a}": q[:, i] for i, a in enumerate("xyzw")},
            **{f"omega_{a}": w[:, i] for i, a in enumerate("xyz")}, "rho": rho,
            "members": fam.members.cpu().numpy(),
            **{f"sigma_att_{a}": np.degrees(sd[:, i]) for i, a in enumerate("xyz")},
            **{f"sigma_omega_{a}": np.degrees(sd[:, 3 + i]) for i, a in enumerate("xyz")},
            "sigma_rho": rho * sd[:, 6], "mass": fam.mass.cpu().numpy(), "p_right": fam.p_right.cpu().numpy()}
    table = set_units(Table(cols), UNITS, {"log_likelihood": "nats", "log_evidence": "nats"})
    table.meta.update({"images": list(fam.images), **(meta or {})})
    return table


def write_solutions(table: Table, path: str | Path) -> None:
    """Write the table as ECSV (:func:`~.table_write.write_table`; not atomic by itself: `invert` writes it inside
    its run folder, renamed into place when the run ends)."""
    write_table(table, path, fmt="ascii.ecsv")


def read_solutions(path: str | Path) -> Table:
    """Read and check a solutions file: every column present, finite, unit quaternions, weights summing to 1."""
    path = Path(path)
    try:
        table = Table.read(path, format="ascii.ecsv")
    except FileNotFoundError:
        raise SolutionsFileError(f"{path}: no such file") from None
    except Exception as exc:  # astropy raises many kinds for a malformed file
        raise SolutionsFileError(f"{path}: not a solutions ECSV file ({type(exc).__name__}: {exc})") from None
    missing = [c for c in COLUMNS if c not in table.colnames]
    if missing:
        raise SolutionsFileError(f"{path}: column {missing[0]}: missing (a solutions file from "
                                 f"python -m lightcurve_gp.invert has {', '.join(COLUMNS)})")
    if len(table) == 0:
        raise SolutionsFileError(f"{path}: no rows")
    for name in COLUMNS + tuple(c for c in OPTIONAL_COLUMNS if c in table.colnames):
        values = np.asarray(table[name], dtype=np.float64)
        if not np.all(np.isfinite(values)) and not name.startswith("sigma"):
            row = int(np.flatnonzero(~np.isfinite(values))[0])
            raise SolutionsFileError(f"{path}: column {name}, row {row + 1}: not a finite number")
    q = np.stack([np.asarray(table[f"q_{a}"], dtype=np.float64) for a in "xyzw"], -1)
    bad = np.flatnonzero(np.abs(np.linalg.norm(q, axis=-1) - 1.0) > 1e-6)
    if bad.size:
        raise SolutionsFileError(f"{path}: row {int(bad[0]) + 1}: q_x, q_y, q_z, q_w is not a unit quaternion")
    if abs(float(np.sum(table["weight"])) - 1.0) > 1e-6:
        raise SolutionsFileError(f"{path}: column weight: the weights sum to {float(np.sum(table['weight'])):.6g}, "
                                 "not 1")
    for name in (c for c in OPTIONAL_COLUMNS if c in table.colnames):
        values = np.asarray(table[name], dtype=np.float64)
        if np.any((values < 0.0) | (values > 1.0 + 1e-9)):
            row = int(np.flatnonzero((values < 0.0) | (values > 1.0 + 1e-9))[0])
            raise SolutionsFileError(f"{path}: column {name}, row {row + 1}: {float(values[row]):.6g} is not a "
                                     "probability in [0, 1]")
    return table


def rate_sigma(table: Table, rank: int = 1) -> torch.Tensor | None:
    """The 1σ ``(3,)`` (rad/s) of the body rate of the family of ``rank`` (``None`` when the file has no
    ``sigma_omega_*`` columns)."""
    if not all(f"sigma_omega_{a}" in table.colnames for a in "xyz"):
        return None
    row = table[int(np.flatnonzero(np.asarray(table["rank"]) == rank)[0])]
    return torch.tensor([math.radians(float(row[f"sigma_omega_{a}"])) for a in "xyz"], dtype=torch.float64)


def best_solution(table: Table, rank: int = 1) -> tuple[torch.Tensor, torch.Tensor, float]:
    """The attitude ``(4,)``, the body rate ``(3,)`` (rad/s) and ρ̂ of the family of ``rank``."""
    rows = np.flatnonzero(np.asarray(table["rank"]) == rank)
    if not rows.size:
        raise SolutionsFileError(f"rank {rank}: no such family (the file has {len(table)})")
    row = table[int(rows[0])]
    q = torch.tensor([float(row[f"q_{a}"]) for a in "xyzw"], dtype=torch.float64)
    w = torch.tensor([math.radians(float(row[f"omega_{a}"])) for a in "xyz"], dtype=torch.float64)
    return q, w, float(row["rho"])
