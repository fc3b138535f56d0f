"""Matplotlib figures in the paper's style; every function writes one PNG atomically and returns its path.

Figures are built with matplotlib's object-oriented API (``matplotlib.figure.Figure``, rendered by the Agg canvas
when saved): pyplot is never imported and the user's backend is never switched. Magnitude axes point brighter
(smaller magnitude) up or right, as astronomers plot them, and say so in their labels; legends sit outside the
axes so that they never hide data, and name the estimators in words (:data:`ESTIMATOR_LABELS`). Log axes read in
plain numbers (``4``, ``0.5``), never ``4×10⁰``.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from matplotlib.axis import Axis
from matplotlib.figure import Figure
from matplotlib.ticker import LogFormatter

from lightcurve_gp.files import atomic_path

__all__ = ["save_figure", "prediction_scatter", "residual_histogram", "euler_errors", "light_curves", "rmse_boxplot",
           "ESTIMATOR_COLORS", "ESTIMATOR_LABELS", "SUCCESS_DEG", "estimator_label", "plain_log_ticks",
           "target_quantity", "error_bands"]

#: paper colours: GPUKF blue, conventional UKF red, truth black; the extra baselines get their own
ESTIMATOR_COLORS = {"gpukf": "tab:blue", "ukf": "tab:red", "truth": "black", "matched_ukf": "tab:green",
                    "no_update": "tab:gray", "joint_ukf": "tab:purple"}
#: the reference estimators are dashed so that an estimator they coincide with stays visible
ESTIMATOR_STYLES = {"matched_ukf": "--", "no_update": ":"}
#: the estimators' names in figures
ESTIMATOR_LABELS = {"gpukf": "GPUKF (trained GP)", "ukf": "UKF (assumed ρ)", "matched_ukf": "matched UKF (knows ρ)",
                    "joint_ukf": "joint UKF (ρ as offset)", "surface_ukf": "surface UKF (BRDF states)",
                    "surface_ukf_select": "surface UKF (selected)", "no_update": "no update (propagation only)"}
#: the RMSE below which an estimate counts as a success (the "<10deg" column of the estimate table), deg
SUCCESS_DEG = 10.0
#: standardised residuals beyond this are counted, not drawn, in the residual histogram
Z_RANGE = 5.0
AXES = ("yaw", "pitch", "roll")


def estimator_label(name: str) -> str:
    """The readable name of estimator ``name`` (:data:`ESTIMATOR_LABELS`; other names as they are)."""
    return ESTIMATOR_LABELS.get(name, name)


def target_quantity(target: str, rho_reference: float) -> str:
    """What a GP of ``model.target`` predicts, for axis labels: the apparent magnitude, or the magnitude normalised
    to the reference reflectance ``rho_reference`` (what a robust model learns, not the observed ``m_app``)."""
    if target == "rho_normalised":
        return f"$m_{{app}}$ normalised to ρ = {rho_reference:g}"
    if target == "surface_normalised":
        return f"$m_{{app}}$ normalised to ρ(1 − F0) at ρ = {rho_reference:g}"
    return "$m_{app}$"


def plain_log_ticks(axis: Axis) -> None:
    """Label a log-scaled ``axis`` in plain numbers (``2``, ``0.5``, ``10``) instead of ``2×10⁰``; minor ticks get
    labels only when the axis spans less than about two decades (matplotlib's rule)."""
    axis.set_major_formatter(LogFormatter(labelOnlyBase=False))
    axis.set_minor_formatter(LogFormatter(labelOnlyBase=False, minor_thresholds=(2, 0.5)))


def save_figure(fig: Figure, path: str | Path) -> Path:
    """Write ``fig`` as a PNG at ``path`` atomically (the folder must exist); returns ``path``."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=130, bbox_inches="tight", format="png")
    return path


def _np(x) -> np.ndarray:
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


def prediction_scatter(y_true, y_pred, path: str | Path, title: str = "held-out predictions",
                       quantity: str = "$m_{app}$") -> Path:
    """Predicted vs true magnitude with the identity line; ``y_true``, ``y_pred`` ``(N,)`` in mag; ``quantity``
    names what they are (e.g. the ρ-normalised magnitude a robust model learns)."""
    t, p = _np(y_true), _np(y_pred)
    fig = Figure(figsize=(4.8, 5.0), layout="constrained")
    ax = fig.subplots()
    ax.scatter(t, p, s=4, alpha=0.4, color="tab:blue", linewidths=0, label=f"held-out point ({t.size})")
    lo, hi = float(min(t.min(), p.min())), float(max(t.max(), p.max()))
    ax.plot([lo, hi], [lo, hi], color="black", lw=1, label="y = x: perfect prediction")
    ax.set_xlabel(f"true {quantity} [mag] (brighter →)")
    ax.set_ylabel(f"predicted {quantity} [mag] (brighter ↑)")
    ax.set_title(title, fontsize=9)
    ax.invert_xaxis()
    ax.invert_yaxis()
    fig.legend(loc="outside lower center", ncols=2, frameon=False, fontsize=8)
    return save_figure(fig, path)


def residual_histogram(residual, std, path: str | Path) -> Path:
    """Histograms of residuals (mag) and of residuals standardised by the predictive std, with N(0, 1); the
    standardised residuals beyond ±:data:`Z_RANGE` are counted in the legend (the heavy tail stays visible)."""
    r, s = _np(residual), _np(std)
    fig = Figure(figsize=(8.5, 3.5), layout="constrained")
    a, b = fig.subplots(1, 2)
    a.hist(r, bins=60, color="tab:blue", alpha=0.8)
    a.set_xlabel("predicted − true [mag]")
    a.set_ylabel("count")
    z = r / s
    beyond = int(np.sum(np.abs(z) > Z_RANGE))
    b.hist(z, bins=np.linspace(-Z_RANGE, Z_RANGE, 61), density=True, color="tab:blue", alpha=0.8,
           label=f"held-out ({z.size})")
    grid = np.linspace(-Z_RANGE, Z_RANGE, 200)
    b.plot(grid, np.exp(-0.5 * grid**2) / np.sqrt(2 * np.pi), color="black", lw=1, label="N(0, 1)")
    normal = 100 * math.erfc(Z_RANGE / math.sqrt(2))
    b.plot([], [], " ", label=f"beyond ±{Z_RANGE:g} (not drawn): {beyond} of {z.size}, "
                              f"{100 * beyond / max(z.size, 1):.1f} % (N(0, 1): {normal:.5f} %)")
    b.set_xlabel("residual / predictive std")
    b.set_ylabel("probability density")
    fig.legend(*b.get_legend_handles_labels(), loc="outside lower center", ncols=3, frameon=False, fontsize=8)
    return save_figure(fig, path)


def euler_errors(times, errors: Mapping[str, object], path: str | Path, title: str = "",
                 window: Sequence[float] | None = None) -> Path:
    """Euler-angle errors (deg) against time, one panel per axis; ``errors[name]`` is ``(T+1, 3)``."""
    t = _np(times)
    fig = Figure(figsize=(6.4, 6.4), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    for name, err in errors.items():
        e = _np(err)
        for i, ax in enumerate(axes):
            ax.plot(t, e[:, i], color=ESTIMATOR_COLORS.get(name), ls=ESTIMATOR_STYLES.get(name, "-"), lw=1,
                    label=estimator_label(name))
    for i, ax in enumerate(axes):
        ax.set_ylabel(f"{AXES[i]} error [deg]")
        ax.axhline(0, color="black", lw=0.5)
        if window is not None:
            ax.axvspan(window[0], window[1], color="0.9", zorder=0,
                       label=f"RMSE scoring window ({window[0]:g}-{window[1]:g} s)" if i == 0 else None)
    axes[-1].set_xlabel("time [s]")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=3, frameon=False,
               fontsize=8)
    return save_figure(fig, path)


def light_curves(times, observed, predictions: Mapping[str, object], path: str | Path, title: str = "") -> Path:
    """Noisy observed light curve (black) and each estimator's predicted magnitude, in mag (brighter up)."""
    t = _np(times)
    fig = Figure(figsize=(6.4, 4.0), layout="constrained")
    ax = fig.subplots()
    ax.plot(t, _np(observed), color="black", lw=0.6, label="observed (simulated, noisy)")
    for name, pred in predictions.items():
        ax.plot(t, _np(pred), color=ESTIMATOR_COLORS.get(name), ls=ESTIMATOR_STYLES.get(name, "-"), lw=1,
                label=estimator_label(name))
    ax.invert_yaxis()
    ax.set_xlabel("time [s]")
    ax.set_ylabel("$m_{app}$ [mag] (brighter ↑)")
    fig.legend(loc="outside lower center", ncols=3, frameon=False, fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    return save_figure(fig, path)


def rmse_boxplot(rmse: Mapping[str, object], path: str | Path, title: str = "") -> Path:
    """Box plots of per-seed RMSE (deg), one panel per axis, with the :data:`SUCCESS_DEG` line; ``rmse[name]`` is
    ``(S, 3)``."""
    names = list(rmse)
    fig = Figure(figsize=(max(10.0, 1.2 * 3 * len(names)), 4.2), layout="constrained")
    axes = fig.subplots(1, 3, sharey=True)
    labels = [textwrap.fill(estimator_label(n), 12) for n in names]
    for i, ax in enumerate(axes):
        data = [_np(rmse[n])[:, i] for n in names]
        box = ax.boxplot(data, patch_artist=True, showfliers=True)
        for patch, n in zip(box["boxes"], names):
            patch.set_facecolor(ESTIMATOR_COLORS.get(n, "white"))
            patch.set_alpha(0.6)
        ax.axhline(SUCCESS_DEG, color="black", lw=0.8, ls="--",
                   label=f"{SUCCESS_DEG:g}° (the <10deg success threshold)" if i == 0 else None)
        ax.set_xticks(range(1, len(names) + 1), labels, fontsize=8)
        ax.set_title(AXES[i])
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
    axes[0].set_ylabel("RMSE over the scoring window [deg]\n(one value per seed)")
    fig.legend(loc="outside lower center", frameon=False, fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def error_bands(traces: Mapping[str, object], estimators: Sequence[str], path: str | Path) -> Path:
    """One seed's filter errors with their ±3σ bands: top row the GRP attitude error per body axis (deg, ≈ rotation
    vector), bottom row the body-rate error (deg/s); each estimator's error a line, its ±3σ a band.

    ``traces`` is a sweep case record's (:attr:`lightcurve_gp.evaluation.reporting.CaseRecord.traces`: ``seed``,
    ``times`` and per estimator ``attitude_error_deg``, ``attitude_sigma_deg``, ``omega_error_deg_s`` and, where
    the filter estimates ω, ``omega_sigma_deg_s``, each ``(T, 3)``); an estimator without a row's σ is left out
    of that row.
    """
    t = _np(traces["times"])
    fig = Figure(figsize=(12, 5.5), layout="constrained")
    axes = fig.subplots(2, 3, sharex=True)
    rows = (("attitude_error_deg", "attitude_sigma_deg", "attitude error {} (deg)"),
            ("omega_error_deg_s", "omega_sigma_deg_s", "rate error {} (deg/s)"))
    for r, (err_key, sig_key, label) in enumerate(rows):
        for name in estimators:
            if name not in traces.get(sig_key, {}):
                continue
            err, sig = _np(traces[err_key][name]), _np(traces[sig_key][name])
            color = ESTIMATOR_COLORS.get(name, "gray")
            for i, ax in enumerate(axes[r]):
                ax.fill_between(t, -3 * sig[:, i], 3 * sig[:, i], color=color, alpha=0.15, linewidth=0)
                ax.plot(t, err[:, i], color=color, linewidth=0.9, label=name if i == 0 else None)
                ax.set_ylabel(label.format("xyz"[i]))
        axes[r][0].legend(fontsize=8)
    for ax in axes[1]:
        ax.set_xlabel("time (s)")
    fig.suptitle(f"seed {traces['seed']}: errors and ±3σ bands")
    return save_figure(fig, path)
