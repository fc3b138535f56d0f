"""Per-seed rows and grouped summaries of the generalisation suite: the estimators on random truths
(:func:`~lightcurve_gp.simulation.scenario.simulate_truths`, :func:`~lightcurve_gp.evaluation.harness.run_estimators`).

A row is one (seed, estimator): its truth (surface, specular share and class, |ω0|, initial error) and its metrics.
A summary groups rows by estimator and by one of :data:`GROUPINGS` — all seeds, the surface class (specular share of
the flux along the truth), the |ω0| bin, the initial-error bin — and gives per group: the seed count, the share of
seeds below 10° on all axes, the median RMSE per axis, the share of seeds whose time-averaged NEES lies in the
single-run band (:func:`~lightcurve_gp.evaluation.scoring.nees_band`) and the mean and median NEES, and beside the
RMSE the median Cramér–Rao bound per axis and the median RMSE over it (:mod:`lightcurve_gp.evaluation.bounds`; NaN
for rows stored before the bound was computed).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
import torch

from lightcurve_gp.evaluation.harness import ScenarioResult
from lightcurve_gp.evaluation.reporting import finite_or_none
from lightcurve_gp.simulation.truths import SPECULAR_CLASSES, specular_class

__all__ = ["OMEGA_BINS", "ERROR_BINS", "GROUPINGS", "SUMMARY_COLUMNS", "suite_rows", "bin_label", "summarize",
           "whitened_correlation"]

#: |ω0| bins (deg/s): (label, lower, upper)
OMEGA_BINS = (("<0.15", 0.0, 0.15), ("0.15-0.5", 0.15, 0.5), (">0.5", 0.5, math.inf))
#: initial-error angle bins (deg)
ERROR_BINS = (("<10", 0.0, 10.0), ("10-20", 10.0, 20.0), (">20", 20.0, math.inf))
#: grouping name -> row column holding the group label
GROUPINGS = {"all": None, "surface class": "surface_class", "|omega0| (deg/s)": "omega_bin",
             "initial error (deg)": "error_bin"}
_AXES = ("yaw", "pitch", "roll")
SUMMARY_COLUMNS = ("estimator", "grouping", "group", "seeds", "share_below_10deg", "rmse_yaw_median",
                   "rmse_pitch_median", "rmse_roll_median", "share_nees_in_band", "nees_mean", "nees_median",
                   *(f"crb_{a}_median" for a in _AXES), *(f"rmse_over_crb_{a}" for a in _AXES))


def bin_label(value: float, bins: Sequence[tuple[str, float, float]]) -> str:
    """The label of the bin ``[lower, upper)`` holding ``value``."""
    for label, lo, hi in bins:
        if lo <= value < hi:
            return label
    raise ValueError(f"{value!r} lies in no bin of {[b[0] for b in bins]}")


def suite_rows(result: ScenarioResult, band: tuple[float, float], *, error_mode: str) -> list[dict[str, Any]]:
    """One plain-python row per (seed, estimator) of a result on drawn truths (their ``specular_share`` known);
    ``error_mode`` is ``"random"`` or the fixed angle as text."""
    sc = result.scenario
    if sc.specular_share is None:
        raise ValueError("suite_rows: the scenario's truths were not drawn (simulate_truths); no specular share")
    classes = specular_class(sc.specular_share).tolist()
    omega = torch.rad2deg(torch.linalg.vector_norm(sc.omega_true[:, 0], dim=-1)).tolist()
    error = torch.rad2deg(torch.linalg.vector_norm(sc.error, dim=-1)).tolist()
    rows = []
    for name, r in result.results.items():
        for i, seed in enumerate(sc.seeds):
            rmse = [float(v) for v in r.rmse_deg[i]]
            crb = [math.nan] * 3 if r.crb_deg is None else [float(v) for v in r.crb_deg[i]]
            nees = float(r.nees_mean[i])
            rows.append({
                "seed": seed, "estimator": name, "error_mode": error_mode,
                "rmse_yaw_deg": finite_or_none(rmse[0]), "rmse_pitch_deg": finite_or_none(rmse[1]),
                "rmse_roll_deg": finite_or_none(rmse[2]), "below_10deg": bool(all(v < 10.0 for v in rmse)),
                **{f"crb_{a}_deg": finite_or_none(c) for a, c in zip(_AXES, crb)},
                "nees_mean": finite_or_none(nees), "nees_in_band": bool(band[0] <= nees <= band[1]),
                "specular_share": float(sc.specular_share[i]), "surface_class": SPECULAR_CLASSES[classes[i]][0],
                "omega_deg_s": omega[i], "omega_bin": bin_label(omega[i], OMEGA_BINS),
                "initial_error_deg": error[i], "error_bin": bin_label(error[i], ERROR_BINS),
                "sigma0_deg": math.degrees(float(sc.sigma0[i])),
                "rho": float(sc.surface.rho[i]), "f0": float(sc.surface.f0[i]), "n_u": float(sc.surface.n_u[i]),
                "n_v": float(sc.surface.n_v[i]),
                "offset_final": None if r.offset_final is None else finite_or_none(float(r.offset_final[i])),
                "white_first": [finite_or_none(float(v)) for v in r.white_first[i]],
                "white_last": [finite_or_none(float(v)) for v in r.white_last[i]],
                "seconds_batch": r.seconds,
            })
    return rows


def _group_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    rmse = np.array([[np.nan if r[k] is None else r[k] for k in ("rmse_yaw_deg", "rmse_pitch_deg", "rmse_roll_deg")]
                     for r in rows], dtype=float)
    nees = np.array([np.nan if r["nees_mean"] is None else r["nees_mean"] for r in rows], dtype=float)
    med = np.nanmedian(rmse, axis=0) if len(rows) else [math.nan] * 3
    crb = np.array([[np.nan if r.get(f"crb_{a}_deg") is None else r[f"crb_{a}_deg"] for a in _AXES] for r in rows],
                   dtype=float).reshape(-1, 3)
    crb_med = [float(np.nanmedian(c)) if np.isfinite(c).any() else math.nan for c in crb.T]
    return {"seeds": len(rows), "share_below_10deg": float(np.mean([r["below_10deg"] for r in rows])),
            "rmse_yaw_median": float(med[0]), "rmse_pitch_median": float(med[1]), "rmse_roll_median": float(med[2]),
            "share_nees_in_band": float(np.mean([r["nees_in_band"] for r in rows])),
            "nees_mean": float(np.nanmean(nees)) if np.isfinite(nees).any() else math.nan,
            "nees_median": float(np.nanmedian(nees)) if np.isfinite(nees).any() else math.nan,
            **{f"crb_{a}_median": c for a, c in zip(_AXES, crb_med)},
            **{f"rmse_over_crb_{a}": float(m) / c if c > 0 else math.nan for a, m, c in zip(_AXES, med, crb_med)}}


def summarize(rows: Sequence[dict[str, Any]], groupings: dict[str, str | None] = GROUPINGS) -> list[dict[str, Any]]:
    """:data:`SUMMARY_COLUMNS` per estimator, grouping and group (groups in the order of the bin tables)."""
    order = {"surface_class": [c[0] for c in SPECULAR_CLASSES], "omega_bin": [b[0] for b in OMEGA_BINS],
             "error_bin": [b[0] for b in ERROR_BINS]}
    estimators = list(dict.fromkeys(r["estimator"] for r in rows))
    out = []
    for name in estimators:
        mine = [r for r in rows if r["estimator"] == name]
        for grouping, column in groupings.items():
            labels = ["all"] if column is None else order.get(column) or sorted({str(r[column]) for r in mine})
            for label in labels:
                members = mine if column is None else [r for r in mine if str(r[column]) == label]
                if members:
                    out.append({"estimator": name, "grouping": grouping, "group": label, **_group_summary(members)})
    return out


def whitened_correlation(rows: Sequence[dict[str, Any]], estimator: str) -> float:
    """Spearman correlation of the whitened error components at the window's first and last scored sample.

    Pooled over seeds and axes; near 1 means the time-averaged NEES holds about one independent sample.
    """
    pairs = [(a, b) for r in rows if r["estimator"] == estimator
             for a, b in zip(r["white_first"], r["white_last"]) if a is not None and b is not None]
    if len(pairs) < 3:
        return math.nan
    ranks = np.argsort(np.argsort(np.array(pairs, dtype=float), axis=0), axis=0).astype(float)
    return float(np.corrcoef(ranks[:, 0], ranks[:, 1])[0, 1])
