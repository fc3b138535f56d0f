"""A sweep's tables: one row per case × seed × estimator, and median/IQR per case and estimator."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from lightcurve_gp.evaluation.reporting import RESULT_COLUMNS, CaseRecord, csv_text, quantiles
from lightcurve_gp.evaluation.scoring import nees_band
from lightcurve_gp.files import write_json_atomic, write_text_atomic
from lightcurve_gp.sweep.grid import Case, value_text

__all__ = ["SUMMARY_METRICS", "SUMMARY_COLUMNS", "TEXT_COLUMNS", "column_unit", "table_units", "table_rows",
           "summarize_rows", "write_sweep_tables", "print_summary"]

#: the metrics summarised by median and quartiles
SUMMARY_METRICS = ("rmse_yaw_deg", "rmse_pitch_deg", "rmse_roll_deg", "lc_rmse_noisy", "lc_rmse_clean",
                   "crb_yaw_deg", "crb_pitch_deg", "crb_roll_deg")
_AXES = ("yaw", "pitch", "roll")
#: columns of ``summary.csv`` after ``case_id`` and the grid columns: the RMSE's median over the bound's median per
#: axis beside them, the NEES's mean, median and the share of seeds in its one-draw band
SUMMARY_COLUMNS = ("estimator", "seeds_ok", "seeds_failed",
                   *(f"{m}_{s}" for m in SUMMARY_METRICS for s in ("median", "q25", "q75")),
                   *(f"rmse_over_crb_{a}" for a in _AXES), "nees_mean", "nees_median", "share_nees_in_band",
                   "seconds_per_step")


#: text columns of the tables (no unit); the grid columns are text too (their values as written in the grid)
TEXT_COLUMNS = ("case_id", "estimator", "status", "error")
#: the unit of a numeric column by the end of its name (first match), checked in this order
_UNIT_SUFFIXES = (("_deg_s", "deg / s"), ("_deg", "deg"), ("seconds_per_step", "s"))
_DIMENSIONLESS = ("seed", "symmetry", "seeds_ok", "seeds_failed", "nees_mean", "nees_median", "nees_full_mean",
                  "nees_full_mean_mod_symmetry", "share_nees_in_band", "rmse_over_crb_yaw", "rmse_over_crb_pitch",
                  "rmse_over_crb_roll")


def column_unit(name: str) -> str:
    """The astropy unit string of a numeric column of ``results.csv`` or ``summary.csv`` (``""``: dimensionless);
    a summary column ``<metric>_{median,q25,q75}`` has its metric's. CSV has no place for units, so
    ``summary.json`` lists them (:func:`write_sweep_tables`).

    Raises:
        ValueError: a column this function does not know (a new column must be given its unit here).
    """
    metric = name
    if name not in _DIMENSIONLESS:
        for statistic in ("_median", "_q25", "_q75"):
            metric = metric.removesuffix(statistic)
    if metric in _DIMENSIONLESS:
        return ""
    if metric.startswith("lc_rmse_"):
        return "mag"
    for suffix, unit in _UNIT_SUFFIXES:
        if metric.endswith(suffix):
            return unit
    raise ValueError(f"column {name}: no unit known")


def table_units(keys: Sequence[str]) -> dict[str, dict[str, str | None]]:
    """Every column's unit of ``results.csv`` and ``summary.csv`` (``None``: text: ``keys``, the case id and the
    grid columns, and :data:`TEXT_COLUMNS`), as ``summary.json`` lists them."""
    def units(columns: Sequence[str]) -> dict[str, str | None]:
        return {c: None if c in TEXT_COLUMNS or c in keys else column_unit(c) for c in columns}
    return {"results.csv": units([*keys, *RESULT_COLUMNS]), "summary.csv": units([*keys, *SUMMARY_COLUMNS])}


def table_rows(cases: Sequence[Case], records: dict[str, CaseRecord]) -> list[dict[str, Any]]:
    """``results.csv`` rows: ``case_id``, the grid values (as text) and the :class:`SeedRow` fields, for every case
    that has a record."""
    rows = []
    for case in cases:
        record = records.get(case.case_id)
        if record is None:
            continue
        grid = {k: value_text(v) for k, v in case.values.items()}
        rows += [{"case_id": case.case_id, **grid, **vars(row)} for row in record.rows]
    return rows


def summarize_rows(rows: Sequence[dict[str, Any]], keys: Sequence[str]) -> list[dict[str, Any]]:
    """Median, 25 % and 75 % quantiles (:func:`~lightcurve_gp.evaluation.reporting.quantiles`) of each metric per
    (case, estimator) over the seeds with status ok (the bound's too), the median RMSE over the median bound per
    axis, the NEES's mean, median and share in its one-draw band, and the time per step.

    ``keys`` are the columns copied from the first row of each group (``case_id`` and the grid columns).
    """
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["case_id"], row["estimator"]), []).append(row)
    out = []
    for (_, estimator), group in groups.items():
        ok = [r for r in group if r["status"] == "ok"]
        entry = {k: group[0].get(k) for k in keys}
        entry.update(estimator=estimator, seeds_ok=len(ok), seeds_failed=len(group) - len(ok))
        for metric in SUMMARY_METRICS:
            q = quantiles([r[metric] for r in ok])
            entry.update({f"{metric}_median": q.median, f"{metric}_q25": q.q25, f"{metric}_q75": q.q75})
        for a in _AXES:
            crb = entry[f"crb_{a}_deg_median"]
            finite = crb and math.isfinite(crb)
            entry[f"rmse_over_crb_{a}"] = entry[f"rmse_{a}_deg_median"] / crb if finite else math.nan
        nees = [r["nees_mean"] for r in ok if r["nees_mean"] is not None]
        band = nees_band()
        entry["nees_mean"] = float(np.mean(nees)) if nees else math.nan
        entry["nees_median"] = quantiles(nees).median
        entry["share_nees_in_band"] = float(np.mean([band[0] <= v <= band[1] for v in nees])) if nees else math.nan
        entry["seconds_per_step"] = ok[0]["seconds_per_step"] if ok else math.nan
        out.append(entry)
    return out


def write_sweep_tables(folder: Path, sweep_id: str, keys: Sequence[str], rows: Sequence[dict[str, Any]],
                       summary: Sequence[dict[str, Any]], complete: bool, failed: Sequence[str]) -> None:
    """``results.csv``, ``summary.csv`` and ``summary.json`` (NaN → null; every CSV column's unit under ``units``,
    :func:`table_units`) of one sweep, atomically."""
    write_text_atomic(csv_text(rows, [*keys, *RESULT_COLUMNS]), folder / "results.csv")
    write_text_atomic(csv_text(summary, [*keys, *SUMMARY_COLUMNS]), folder / "summary.csv")
    write_json_atomic({"sweep_id": sweep_id, "complete": complete, "failed_cases": list(failed),
                       "units": table_units(keys),
                       "summary": [{k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in e.items()}
                                   for e in summary]}, folder / "summary.json")


def print_summary(summary: Sequence[dict[str, Any]], grid_keys: Sequence[str]) -> None:
    """Fixed-width medians per case and estimator on stdout, the RMSE over the bound and the mean NEES beside them."""
    print(" ".join(f"{k:>22}" for k in grid_keys)
          + f" {'estimator':>12} {'yaw':>8} {'pitch':>8} {'roll':>8} {'LC':>6} {'RMSE/CRB':>17} {'NEES':>7}")
    for e in summary:
        cells = " ".join(f"{str(e[k]):>22}" for k in grid_keys)
        ratio = " / ".join(f"{e.get(f'rmse_over_crb_{a}', math.nan):.1f}" for a in _AXES)  # NaN: not computed
        print(f"{cells} {e['estimator']:>12} {e['rmse_yaw_deg_median']:8.2f} {e['rmse_pitch_deg_median']:8.2f} "
              f"{e['rmse_roll_deg_median']:8.2f} {e['lc_rmse_noisy_median']:6.3f} {ratio:>17} "
              f"{e.get('nees_mean', math.nan):7.2f}")
