"""The reporting layer: per-seed result rows, per-case records, one quantile summary and one table writer.

Every table the project writes (sweeps, the paper reproduction, the robust experiments) is built from these:

* :class:`SeedRow` — one estimator on one noise seed: RMSE per Euler axis (deg), light-curve RMSE (mag), mean NEES
  (:func:`seed_rows` of a :class:`~lightcurve_gp.evaluation.harness.ScenarioResult`);
* :func:`scenario_summary` — per estimator the median and IQR over the seeds (what the estimate command prints);
* :class:`CaseRecord` — one sweep case (one config, all seeds batched), stored as JSON by the sweep's case store;
* :func:`quantiles` — median and interquartile range over seeds (NaN and missing values ignored);
* :func:`markdown_table`, :func:`csv_text` and :func:`write_report_table` — a Markdown table and its full-precision
  CSV.

These tables report the NEES of estimators that use the observations: the no-update baseline's covariance is its
unchanged prior, scored by the generalisation suite's rows (:mod:`lightcurve_gp.evaluation.suite_summary`) only.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import numpy as np
import torch
from torch import Tensor

from lightcurve_gp.attitude.metrics import chi2_band
from lightcurve_gp.evaluation.harness import ScenarioResult
from lightcurve_gp.evaluation.scoring import EstimatorResult, nees_band
from lightcurve_gp.files import write_text_atomic

__all__ = ["Quantiles", "quantiles", "format_quantiles", "finite_or_none", "SeedRow", "RESULT_COLUMNS", "CaseRecord",
           "CASE_FORMAT", "seed_rows", "bound_summary", "scenario_summary", "markdown_table", "csv_text",
           "write_report_table", "format_triple", "SUMMARY_HEADER", "summary_row"]

#: version of the stored case-record layout; a record of another version is rerun (2: the scores modulo symmetry
#: are taken against the scenario's derived ambiguity group, named in the summary's ``ambiguity_images``; 3: the
#: whole-arc MAPs search with the noise continuation below 0.1 mag, which the case's config does not show)
CASE_FORMAT = 3


class Quantiles(NamedTuple):
    """Median and quartiles (numpy's linear interpolation) of a sample; NaN when it has no finite value."""

    median: float
    q25: float
    q75: float


def quantiles(values: Any) -> Quantiles:
    """:class:`Quantiles` of the finite entries of ``values`` (a sequence, array or tensor of shape ``(n,)``;
    ``None`` and NaN are ignored)."""
    if hasattr(values, "detach"):
        values = values.detach().cpu().double().numpy()
    x = np.array([np.nan if v is None else v for v in np.asarray(values, dtype=object).reshape(-1)], dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return Quantiles(math.nan, math.nan, math.nan)
    q25, med, q75 = np.quantile(x, [0.25, 0.5, 0.75])
    return Quantiles(float(med), float(q25), float(q75))


def format_quantiles(q: Quantiles, digits: int = 2) -> str:
    """``"median [q25, q75]"`` with ``digits`` decimals, ``"n/a"`` when the median is NaN."""
    if math.isnan(q.median):
        return "n/a"
    return f"{q.median:.{digits}f} [{q.q25:.{digits}f}, {q.q75:.{digits}f}]"


# ----------------------------------------------------------------------------------------------- records

@dataclass
class SeedRow:
    """One estimator on one noise seed. Metrics are ``None`` where undefined (no light curve for ``no_update``,
    a failed case) — never NaN, so that the JSON and CSV files hold no non-standard values. ``omega_rmse_deg_s``
    is the RMSE of the body-rate error's norm over the scoring window, ``omega_error_final_deg_s`` that norm at
    the last sample (deg/s), ``nees_full_mean`` the mean NEES of the whole estimated state ``[δp, ω]`` (the
    attitude NEES for filters that take ω as known). The ``…_mod_symmetry…`` fields score the estimate against the
    truth's nearest image under the scenario's exact ambiguity group (the summary's ``ambiguity_images``),
    ``symmetry`` that image's index (0: the truth itself); ``None`` in records made before they existed.
    ``crb_…_deg`` is the Cramér–Rao bound of the same problem in the RMSE's units
    (:mod:`lightcurve_gp.evaluation.bounds`), ``None`` where none was computed."""

    seed: int
    estimator: str
    rmse_yaw_deg: float | None = None
    rmse_pitch_deg: float | None = None
    rmse_roll_deg: float | None = None
    lc_rmse_noisy: float | None = None
    lc_rmse_clean: float | None = None
    nees_mean: float | None = None
    seconds_per_step: float | None = None
    status: str = "ok"
    error: str = ""
    omega_rmse_deg_s: float | None = None
    omega_error_final_deg_s: float | None = None
    nees_full_mean: float | None = None
    rmse_yaw_mod_symmetry_deg: float | None = None
    rmse_pitch_mod_symmetry_deg: float | None = None
    rmse_roll_mod_symmetry_deg: float | None = None
    symmetry: int | None = None
    omega_error_final_mod_symmetry_deg_s: float | None = None
    nees_full_mean_mod_symmetry: float | None = None
    crb_yaw_deg: float | None = None
    crb_pitch_deg: float | None = None
    crb_roll_deg: float | None = None

    def rmse_deg(self) -> tuple[float, float, float]:
        """RMSE (yaw, pitch, roll) in degrees, NaN where missing."""
        return tuple(math.nan if v is None else v  # type: ignore[return-value]
                     for v in (self.rmse_yaw_deg, self.rmse_pitch_deg, self.rmse_roll_deg))


#: the columns of a results table, in order (the fields of :class:`SeedRow`)
RESULT_COLUMNS = tuple(f.name for f in fields(SeedRow))


def finite_or_none(x: float) -> float | None:
    """``x``, or ``None`` when it is not finite (tables and JSON hold no NaN)."""
    return x if math.isfinite(x) else None


def _reported_nees(r: EstimatorResult, values: Tensor | None) -> Tensor | None:
    """``values`` of an estimator that uses the observations, ``None`` for the no-update baseline (module
    docstring)."""
    return values if r.uses_observations else None


def seed_rows(result: ScenarioResult) -> list[SeedRow]:
    """One :class:`SeedRow` per (estimator, seed) of a scenario result, estimators outermost."""
    rows = []
    for name, r in result.results.items():
        nees_mean, nees_full = _reported_nees(r, r.nees_mean), _reported_nees(r, r.nees_full_mean)
        for i, seed in enumerate(result.scenario.seeds):
            cell = lambda values: None if values is None else finite_or_none(float(values[i]))  # noqa: E731
            yaw, pitch, roll = (float(v) for v in r.rmse_deg[i])
            rows.append(SeedRow(int(seed), name, finite_or_none(yaw), finite_or_none(pitch), finite_or_none(roll),
                                cell(r.lc_rmse_noisy), cell(r.lc_rmse_clean), cell(nees_mean),
                                r.seconds / result.steps, omega_rmse_deg_s=cell(r.omega_rmse_deg_s),
                                omega_error_final_deg_s=cell(r.omega_error_final_deg_s),
                                nees_full_mean=cell(nees_full), **_symmetric_cells(r, i), **_bound_cells(r, i)))
    return rows


def _bound_cells(r: EstimatorResult, i: int) -> dict[str, float | None]:
    """The :class:`SeedRow` bound fields of seed ``i``."""
    if r.crb_deg is None:
        return {}
    yaw, pitch, roll = (finite_or_none(float(v)) for v in r.crb_deg[i])
    return {"crb_yaw_deg": yaw, "crb_pitch_deg": pitch, "crb_roll_deg": roll}


def _symmetric_cells(r: EstimatorResult, i: int) -> dict[str, Any]:
    """The :class:`SeedRow` fields modulo symmetry of seed ``i`` of an estimator result."""
    yaw, pitch, roll = (finite_or_none(float(v)) for v in r.rmse_mod_symmetry_deg[i])
    return {"rmse_yaw_mod_symmetry_deg": yaw, "rmse_pitch_mod_symmetry_deg": pitch, "rmse_roll_mod_symmetry_deg": roll,
            "symmetry": int(r.symmetry_index[i]),
            "omega_error_final_mod_symmetry_deg_s": finite_or_none(float(r.omega_error_final_mod_symmetry_deg_s[i])),
            "nees_full_mean_mod_symmetry": None if r.nees_full_mean_mod_symmetry is None
            else finite_or_none(float(r.nees_full_mean_mod_symmetry[i]))}


def _nanmean(x: Tensor | None) -> float:
    return float(torch.nanmean(x)) if x is not None and x.numel() else float("nan")


def bound_summary(rmse_deg: Tensor, crb_deg: Tensor | None, nees_mean: Tensor | None) -> dict[str, Any]:
    """Beside the RMSE: the median bound per axis, the median RMSE over the median bound per axis (same seeds) and
    the NEES's median and the share of seeds inside the one-draw band (:func:`~lightcurve_gp.evaluation.scoring.
    nees_band`); NaN where missing."""
    nan3 = [math.nan] * 3
    crb = nan3 if crb_deg is None else [quantiles(crb_deg[:, i]).median for i in range(3)]
    ratio = [quantiles(rmse_deg[:, i]).median / c if c and math.isfinite(c) else math.nan for i, c in enumerate(crb)]
    band = nees_band()
    inside = None if nees_mean is None else ((nees_mean >= band[0]) & (nees_mean <= band[1])).double().mean()
    return {"crb_deg_median": crb, "rmse_over_crb": ratio,
            "nees_median": math.nan if nees_mean is None else quantiles(nees_mean).median,
            "share_nees_in_band": math.nan if inside is None else float(inside), "nees_band_one_draw": list(band)}


def _estimator_summary(r: EstimatorResult, steps: int, seeds: int) -> dict[str, Any]:
    """One estimator's entry of :func:`scenario_summary`."""
    per_axis = [quantiles(r.rmse_deg[:, i]) for i in range(3)]
    h = r.history
    return {**bound_summary(r.rmse_deg, r.crb_deg, _reported_nees(r, r.nees_mean)),
        "rmse_deg_median": [q.median for q in per_axis],
        "rmse_deg_q25": [q.q25 for q in per_axis],
        "rmse_deg_q75": [q.q75 for q in per_axis],
        "fraction_all_axes_below_10deg": float((r.rmse_deg < 10).all(-1).double().mean()),
        "lc_rmse_noisy_median": quantiles(r.lc_rmse_noisy).median,
        "lc_rmse_clean_median": quantiles(r.lc_rmse_clean).median,
        "nees_mean": _nanmean(_reported_nees(r, r.nees_mean)),
        "nees_full_mean": _nanmean(_reported_nees(r, r.nees_full_mean)),
        "nees_full_band_95": list(chi2_band(r.nees_full_dof, seeds)),
        "omega_rmse_deg_s_median": quantiles(r.omega_rmse_deg_s).median,
        "omega_error_final_deg_s_median": quantiles(r.omega_error_final_deg_s).median,
        "seconds": r.seconds,
        "seconds_per_step": r.seconds / steps,
        "seconds_per_filter_step": r.seconds / (steps * seeds),
        "sqrt_fallbacks": int(h.fallbacks.sum()) if h is not None else 0,
        "rejected_updates": int(h.rejected.sum()) if h is not None else 0,
        "rmse_deg_median_mod_symmetry": [quantiles(r.rmse_mod_symmetry_deg[:, i]).median for i in range(3)],
        "fraction_all_axes_below_10deg_mod_symmetry": float((r.rmse_mod_symmetry_deg < 10).all(-1).double().mean()),
        "fraction_nearest_symmetric_not_truth": float((r.symmetry_index != 0).double().mean()),
        "omega_error_final_mod_symmetry_deg_s_median": quantiles(r.omega_error_final_mod_symmetry_deg_s).median,
        "nees_full_mean_mod_symmetry": _nanmean(r.nees_full_mean_mod_symmetry),
    }


def scenario_summary(result: ScenarioResult) -> dict[str, Any]:
    """Plain-python summary: per estimator the median and IQR of the RMSE per axis over the seeds
    (:func:`quantiles`, NaN ignored), the bound beside it (:func:`bound_summary`), light-curve RMSE, NEES, the
    scores modulo symmetry (``ambiguity_images``: the images they were taken against, ``AmbiguityGroup.as_dict``) and
    timing."""
    S = len(result.scenario.seeds)
    return {"rho_true": result.scenario.rho_true, "seeds": S, "window_s": list(result.window),
            "nees_band_95": list(result.nees_band()),
            "estimators": {name: _estimator_summary(r, result.steps, S) for name, r in result.results.items()},
            "omega_estimated": any(r.history is not None and r.history.omega is not None
                                   for r in result.results.values()),
            "ambiguity_images": None if result.group is None else result.group.as_dict()}


@dataclass
class CaseRecord:
    """One sweep case: its grid values, seeds and estimators, status, per-seed rows, the estimators' summary
    (:func:`scenario_summary`) and the first seed's traces for figures (``times``, ``observed``, ``clean``,
    ``errors_deg`` and ``y_pred`` per estimator)."""

    case_id: str
    values: dict[str, Any]
    seeds: list[int]
    estimators: list[str]
    status: str = "ok"
    error: str = ""
    rows: list[SeedRow] = field(default_factory=list)
    summary: dict[str, Any] = field(default_factory=dict)
    traces: dict[str, Any] = field(default_factory=dict)
    model_path: str | None = None
    traceback: str = ""
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def estimator_rows(self, estimator: str) -> list[SeedRow]:
        """The rows of one estimator, in seed order."""
        return [r for r in self.rows if r.estimator == estimator]

    def rmse_deg(self, estimator: str) -> np.ndarray:
        """Per-seed RMSE ``(S, 3)`` (deg, yaw/pitch/roll) of one estimator, NaN where a seed failed."""
        return np.array([r.rmse_deg() for r in self.estimator_rows(estimator)], dtype=float).reshape(-1, 3)

    def metric(self, estimator: str, name: str) -> np.ndarray:
        """Per-seed values ``(S,)`` of one :class:`SeedRow` metric, NaN where missing."""
        return np.array([math.nan if getattr(r, name) is None else getattr(r, name)
                         for r in self.estimator_rows(estimator)], dtype=float)

    def to_dict(self) -> dict[str, Any]:
        """The JSON layout of the case store (``format`` first)."""
        return {"format": CASE_FORMAT, **asdict(self)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CaseRecord | None:
        """The record of a stored mapping, or ``None`` when it is of another format or malformed."""
        if not isinstance(data, dict) or data.get("format") != CASE_FORMAT:
            return None
        names = {f.name for f in fields(cls)}
        try:
            values = {k: v for k, v in data.items() if k in names}
            values["rows"] = [SeedRow(**row) for row in data.get("rows", [])]
            return cls(**values)
        except TypeError:
            return None


# ----------------------------------------------------------------------------------------------- tables

def markdown_table(header: Sequence[str], rows: Sequence[Sequence[Any]], note: str = "") -> str:
    """A Markdown table (cells through ``str``) followed by an optional note paragraph."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n" + (f"\n{note}\n" if note else "")


def csv_text(rows: Sequence[dict[str, Any]], columns: Sequence[str] | None = None) -> str:
    """CSV of ``rows`` with ``columns`` (default: the first row's keys; other keys are dropped), ``None`` → empty;
    an empty string when there are no rows and no columns."""
    columns = list(columns if columns is not None else (rows[0] if rows else []))
    if not columns:
        return ""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if row.get(k) is None else row[k]) for k in columns})
    return buf.getvalue()


def write_report_table(folder: Path, stem: str, header: Sequence[str], rows: Sequence[Sequence[Any]],
                csv_rows: Sequence[dict[str, Any]], note: str = "") -> str:
    """Write ``<stem>.md`` (:func:`markdown_table`) and ``<stem>.csv`` (full-precision ``csv_rows``) atomically
    into ``folder``; returns the Markdown."""
    md = markdown_table(header, rows, note)
    write_text_atomic(md, Path(folder) / f"{stem}.md")
    write_text_atomic(csv_text(csv_rows), Path(folder) / f"{stem}.csv")
    return md


#: header of the one-line-per-estimator summary tables (:func:`summary_row`)
SUMMARY_HEADER = ("estimator", "yaw", "pitch", "roll", "CRB yaw / pitch / roll", "RMSE / CRB", "< 10 deg all axes",
                  "mean NEES", "median NEES", "NEES in band", "s (all seeds)")


def format_triple(values, digits: int = 2) -> str:
    """Three numbers as ``"a / b / c"`` (yaw / pitch / roll), ``"–"`` when missing or not finite."""
    if values is None or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
        return "–"
    return " / ".join(f"{v:.{digits}f}" for v in values)


def summary_row(name: str, entry: dict[str, Any]) -> list[str]:
    """Cells of :data:`SUMMARY_HEADER` for one estimator's entry of :func:`scenario_summary` (an entry written
    before the bound was reported shows "–" there)."""
    share = entry.get("share_nees_in_band", math.nan)
    return [name, *(f"{m:.2f}" for m in entry["rmse_deg_median"]), format_triple(entry.get("crb_deg_median")),
            format_triple(entry.get("rmse_over_crb"), 1), f"{100 * entry['fraction_all_axes_below_10deg']:.0f} %",
            f"{entry['nees_mean']:.2f}", f"{entry.get('nees_median', math.nan):.2f}",
            "–" if math.isnan(share) else f"{100 * share:.0f} %", f"{entry['seconds']:.1f}"]
