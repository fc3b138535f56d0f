"""The files of a convex inversion: the pole/period families (``solutions.ecsv``) and the areas per normal
(``areas.ecsv``).

``solutions.ecsv`` — one row per family, best first: ``rank``, ``pole_lambda_deg``, ``pole_beta_deg`` (ecliptic
J2000, deg, ``λ`` in [0°, 360°), ``β`` in [−90°, 90°]), ``phase0_deg`` (the rotation phase ``φ0`` at the epoch whose
body frame the areas belong to: 0°, or 180° where the polish crossed the ecliptic's pole and the pole is written
folded, :func:`~lightcurve_gp.photometry.convex.folded_pole`), ``period_h`` and ``period_sigma_h``
(sidereal period and its Laplace 1σ, h), ``rms`` (convexinv's: the relative-intensity residuals, each curve
normalised by its mean), ``chi2_per_sample`` (with the 1σ the observations carry, converted to relative intensity),
``log_ratio`` (nats below the best), ``weight`` (the rows sum to 1) and ``within_ratio`` (false for the one extra
row: the best solution at the best family's mirror pole λ + 180° when it lies beyond the likelihood ratio; weight
0); astropy units on the columns. Metadata: ``light_curve``, ``config``, ``samples``, ``light_curves``,
``effective_samples``, ``residual_correlation``.

``areas.ecsv`` — one row per facet normal: ``n_x, n_y, n_z`` (body frame: ``z`` the spin axis) and ``area_1``,
``area_2``, … (each family's Gaussian image, relative areas summing to 1); under a law of several bases
(:class:`~lightcurve_gp.photometry.convex.SatelliteScattering`) one column per family and basis,
``area_1_diffuse``, ``area_1_lobe_800``, … (all of a family's areas sum to 1).
"""

from __future__ import annotations

import math
from pathlib import Path

import astropy.units as u
import numpy as np
from astropy.table import Table

from lightcurve_gp.files import atomic_path
from lightcurve_gp.inference.convex_search import ConvexSearch
from lightcurve_gp.observed.table_write import write_table
from lightcurve_gp.photometry.convex import folded_pole

__all__ = ["convex_solutions_table", "areas_table", "write_convex_tables"]

MAG_TO_RELATIVE = 0.4 * math.log(10.0)


def convex_solutions_table(search: ConvexSearch, *, sigma_mag: float, samples: int, light_curves: int,
                           meta: dict | None = None) -> Table:
    """The families as ``solutions.ecsv``'s table (module docstring)."""
    fam = search.families
    sigma_rel = MAG_TO_RELATIVE * sigma_mag
    table = Table()
    table["rank"] = np.arange(1, len(fam) + 1)
    lam, beta, phase0 = folded_pole(fam.lam_deg, fam.beta_deg)
    table["pole_lambda_deg"] = lam * u.deg
    table["pole_beta_deg"] = beta * u.deg
    table["phase0_deg"] = phase0 * u.deg
    table["period_h"] = fam.period_h * u.h
    table["period_sigma_h"] = fam.period_sigma_h * u.h
    table["rms"] = fam.rms * u.dimensionless_unscaled
    table["chi2_per_sample"] = (fam.rms / sigma_rel) ** 2
    table["log_ratio"] = fam.log_ratio
    table["weight"] = fam.weight
    table["within_ratio"] = fam.within_ratio
    table["period_h"].info.format = ".9f"
    table.meta.update({"samples": samples, "light_curves": light_curves, "sigma_mag": sigma_mag,
                       "effective_samples": round(float(search.effective_samples), 1),
                       "residual_correlation": round(float(search.residual_correlation), 4), **(meta or {})})
    return table


def areas_table(search: ConvexSearch) -> Table:
    """The Gaussian images of the families on the polish normals (module docstring)."""
    n = search.normals.cpu().numpy()
    table = Table({"n_x": n[:, 0], "n_y": n[:, 1], "n_z": n[:, 2]})
    names = search.basis_names
    for k, areas in enumerate(search.families.areas):
        for m, part in enumerate(areas.reshape(len(names), n.shape[0])):
            table[f"area_{k + 1}" + (f"_{names[m]}" if len(names) > 1 else "")] = part
    return table


def write_convex_tables(folder: Path, solutions: Table, areas: Table) -> None:
    """``solutions.ecsv`` and ``areas.ecsv`` in ``folder``, each written atomically."""
    for table, name in ((solutions, "solutions.ecsv"), (areas, "areas.ecsv")):
        with atomic_path(Path(folder) / name) as tmp:
            write_table(table, tmp, fmt="ascii.ecsv")
