"""Figures of a run on an observed light curve: the light curve with the prediction's ±2σ band, and the attitude
with its uncertainty (object-oriented matplotlib, written atomically, as :mod:`lightcurve_gp.evaluation.plots`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from astropy.table import Table
from matplotlib.figure import Figure

from lightcurve_gp.evaluation.plots import AXES, save_figure

__all__ = ["light_curve_band", "attitude_with_uncertainty"]


def light_curve_band(history: Table, path: str | Path, title: str = "") -> Path:
    """Observed magnitudes (dots), the filter's prediction and its ±2σ band (``√Pyy``), brighter up."""
    t = np.asarray(history["t_s"])
    pred, sigma = np.asarray(history["mag_pred"]), np.asarray(history["mag_pred_sigma"])
    fig = Figure(figsize=(7.0, 4.0), layout="constrained")
    ax = fig.subplots()
    ax.fill_between(t, pred - 2 * sigma, pred + 2 * sigma, color="tab:blue", alpha=0.25, lw=0,
                    label="prediction ±2σ (√Pyy)")
    ax.plot(t, np.asarray(history["mag_obs"]), ".", color="black", ms=2, label="observed")
    ax.plot(t, pred, color="tab:blue", lw=1, label="predicted")
    ax.invert_yaxis()
    ax.set_xlabel("time from the first sample [s]")
    ax.set_ylabel("$m_{app}$ [mag] (brighter ↑)")
    fig.legend(loc="outside lower center", ncols=3, frameon=False, fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    return save_figure(fig, path)


def attitude_with_uncertainty(history: Table, path: str | Path, title: str = "") -> Path:
    """3-2-1 Euler angles of the estimate (deg), one panel per angle, and the 1σ of the attitude error about the
    x, y and z axes (deg, log scale) in a fourth panel."""
    t = np.asarray(history["t_s"])
    fig = Figure(figsize=(7.0, 7.5), layout="constrained")
    axes = fig.subplots(4, 1, sharex=True)
    for ax, name in zip(axes[:3], AXES):
        ax.plot(t, np.asarray(history[f"{name}_deg"]), ".", ms=1.5, color="tab:blue")
        ax.set_ylabel(f"{name} [deg]")
    for axis, color in zip("xyz", ("tab:red", "tab:green", "tab:purple")):
        axes[3].plot(t, np.asarray(history[f"sigma_{axis}_deg"]), color=color, lw=1, label=f"1σ about {axis}")
    axes[3].set_yscale("log")
    axes[3].set_ylabel("1σ [deg]")
    axes[3].legend(fontsize=8, frameon=False, ncols=3)
    axes[3].set_xlabel("time from the first sample [s]")
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)
