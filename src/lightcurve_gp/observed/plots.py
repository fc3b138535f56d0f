"""Figures of a run on an observed light curve: the light curve with the prediction's ±2σ band, and the attitude
with its uncertainty (object-oriented matplotlib, written atomically, as :mod:`lightcurve_gp.evaluation.plots`).

A light curve of more than :data:`DENSE_SAMPLES` samples would draw as a solid band of dots: it is drawn as a
density of the observed magnitudes over time (counts per time and magnitude bin, log colour scale) with the
prediction's ±2σ envelope per time bin, above a zoom on its first :data:`ZOOM_SAMPLES` samples drawn sample by
sample.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from astropy.table import Table
from matplotlib.axes import Axes
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

from lightcurve_gp.evaluation.plots import AXES, plain_log_ticks, save_figure

__all__ = ["DENSE_SAMPLES", "ZOOM_SAMPLES", "light_curve_band", "attitude_with_uncertainty", "fit_with_residuals"]

#: above this many samples a light curve is drawn as a density (module docstring)
DENSE_SAMPLES = 5000
#: samples drawn one by one in the zoom panel of a dense light curve
ZOOM_SAMPLES = 600
#: time bins of the density panel
TIME_BINS = 400
MAG_LABEL = "$m_{app}$ [mag] (brighter ↑)"
TIME_LABEL = "time from the first sample [s]"
ANGLE_COLOR = {"yaw": "tab:purple", "pitch": "tab:green", "roll": "tab:red"}
#: the body axis whose error moves each angle to first order (pitch away from ±90°)
ANGLE_AXIS = {"yaw": "z", "pitch": "y", "roll": "x"}


def _samples(ax: Axes, t, obs, pred, sigma) -> None:
    """Observed magnitudes (dots), the prediction and its ±2σ band, sample by sample."""
    ax.fill_between(t, pred - 2 * sigma, pred + 2 * sigma, color="tab:blue", alpha=0.25, lw=0,
                    label="prediction ±2σ (√Pyy)")
    ax.plot(t, obs, ".", color="black", ms=2, label="observed")
    ax.plot(t, pred, color="tab:blue", lw=1, label="predicted")


def _density(ax: Axes, t, obs, pred, sigma) -> None:
    """The observed magnitudes as counts per (time, magnitude) bin and the prediction's ±2σ envelope per time bin."""
    edges = np.linspace(t[0], t[-1], TIME_BINS + 1)
    finite = np.isfinite(pred) & np.isfinite(sigma)
    lo, hi = np.nanpercentile(obs, [0.1, 99.9])
    pad = 0.05 * (hi - lo) + 1e-3
    image = ax.hist2d(t, obs, bins=(edges, np.linspace(lo - pad, hi + pad, 120)), cmap="Greys", norm=LogNorm(),
                      cmin=1, rasterized=True)[3]
    which = np.clip(np.searchsorted(edges, t[finite], side="right") - 1, 0, TIME_BINS - 1)
    low, high = np.full(TIME_BINS, np.inf), np.full(TIME_BINS, -np.inf)
    np.minimum.at(low, which, (pred - 2 * sigma)[finite])
    np.maximum.at(high, which, (pred + 2 * sigma)[finite])
    seen = np.isfinite(low)
    centres = 0.5 * (edges[:-1] + edges[1:])
    ax.fill_between(centres[seen], low[seen], high[seen], color="tab:blue", alpha=0.2, lw=0,
                    label="prediction ±2σ, range per time bin")
    ax.figure.colorbar(image, ax=ax, label="observed samples per bin", pad=0.01)


def light_curve_band(history: Table, path: str | Path, title: str = "") -> Path:
    """Observed magnitudes, the filter's prediction and its ±2σ band (``√Pyy``), brighter up; a long light curve
    as a density above a zoom on its start (module docstring)."""
    t = np.asarray(history["t_s"], dtype=float)
    obs = np.asarray(history["mag_obs"], dtype=float)
    pred, sigma = np.asarray(history["mag_pred"], dtype=float), np.asarray(history["mag_pred_sigma"], dtype=float)
    if t.size <= DENSE_SAMPLES:
        fig = Figure(figsize=(7.0, 4.0), layout="constrained")
        ax = fig.subplots()
        _samples(ax, t, obs, pred, sigma)
        axes = [ax]
    else:
        fig = Figure(figsize=(7.5, 7.0), layout="constrained")
        axes = fig.subplots(2, 1)
        _density(axes[0], t, obs, pred, sigma)
        axes[0].set_title(f"all {t.size} samples: density of the observed magnitudes", fontsize=9)
        z = slice(0, ZOOM_SAMPLES)
        _samples(axes[1], t[z], obs[z], pred[z], sigma[z])
        axes[1].set_title(f"zoom: the first {ZOOM_SAMPLES} samples", fontsize=9)
    for ax in axes:
        ax.invert_yaxis()
        ax.set_xlabel(TIME_LABEL)
        ax.set_ylabel(MAG_LABEL)
    handles = {label: h for ax in axes for h, label in zip(*ax.get_legend_handles_labels())}
    fig.legend(handles.values(), handles.keys(), loc="outside lower center", ncols=2, frameon=False, fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def _unwrapped_deg(angle_deg: np.ndarray) -> np.ndarray:
    """An angle history (deg) without its ±180° jumps."""
    return np.rad2deg(np.unwrap(np.deg2rad(angle_deg)))


def attitude_with_uncertainty(history: Table, path: str | Path, title: str = "") -> Path:
    """3-2-1 Euler angles of the estimate (deg, yaw and roll unwrapped) with their ±1σ bands, one panel per angle,
    and the 1σ of the attitude error about the body x, y and z axes (deg, log scale) in a fourth panel."""
    t = np.asarray(history["t_s"], dtype=float)
    dense = t.size > DENSE_SAMPLES
    fig = Figure(figsize=(7.0, 8.0), layout="constrained")
    axes = fig.subplots(4, 1, sharex=True)
    for ax, name in zip(axes[:3], AXES):
        angle = np.asarray(history[f"{name}_deg"], dtype=float)
        angle = angle if name == "pitch" else _unwrapped_deg(angle)
        color = ANGLE_COLOR[name]
        if f"sigma_{name}_deg" in history.colnames:
            # capped: near pitch ±90° the first-order σ of yaw and roll diverges
            sigma = np.minimum(np.asarray(history[f"sigma_{name}_deg"], dtype=float), 180.0)
            ax.fill_between(t, angle - sigma, angle + sigma, color=color, alpha=0.25, lw=0, rasterized=dense,
                            label="±1σ" if name == "yaw" else None)
        ax.plot(t, angle, "-" if dense else ".", lw=0.6, ms=1.5, color=color, rasterized=dense,
                label="estimate" if name == "yaw" else None)
        ax.set_ylabel(f"{name} [deg]" + ("" if name == "pitch" else "\n(unwrapped)"), fontsize=9)
    for name in AXES:
        axis = ANGLE_AXIS[name]
        axes[3].plot(t, np.asarray(history[f"sigma_{axis}_deg"], dtype=float), color=ANGLE_COLOR[name], lw=1,
                     label=f"about body {axis} (≈ {name})")
    axes[3].set_yscale("log")
    plain_log_ticks(axes[3].yaxis)
    axes[3].set_ylabel("1σ of the attitude\nerror [deg]", fontsize=9)
    axes[3].legend(fontsize=8, frameon=False, ncols=3)
    axes[3].set_xlabel(TIME_LABEL)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=2, frameon=False, fontsize=8,
               title="3-2-1 angles of A(q); to first order a small error about body z moves yaw, y pitch and x "
                     "roll (pitch away from ±90°)", title_fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def fit_with_residuals(history: Table, path: str | Path, title: str = "") -> Path:
    """The observed magnitudes and the whole-arc fit (brighter up), one colour per light curve, above the
    residuals in units of each sample's 1σ (the ±2σ lines dashed): what a fit's χ² summarises, sample by sample."""
    t = np.asarray(history["t_s"], dtype=float)
    obs, fit = np.asarray(history["mag_obs"], dtype=float), np.asarray(history["mag_fit"], dtype=float)
    z = np.asarray(history["residual_sigmas"], dtype=float)
    curve = np.asarray(history["curve"], dtype=int)
    fig = Figure(figsize=(7.5, 5.5), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=(2.2, 1.0))
    dense = t.size > DENSE_SAMPLES
    for c in np.unique(curve):
        on = curve == c
        line = top.plot(t[on], fit[on], lw=1, label=f"fit, light curve {c + 1}" if c < 8 else None)[0]
        top.plot(t[on], obs[on], ".", ms=1.5 if dense else 2.5, color="black", alpha=0.6, rasterized=dense,
                 label="observed" if c == curve[0] else None)
        bottom.plot(t[on], z[on], ".", ms=1.5 if dense else 2.5, color=line.get_color(), rasterized=dense)
    top.invert_yaxis()
    top.set_ylabel(MAG_LABEL)
    for level in (-2.0, 2.0):
        bottom.axhline(level, color="grey", lw=0.8, ls="--")
    bottom.axhline(0.0, color="grey", lw=0.6)
    bottom.set_ylabel("residual / 1σ")
    bottom.set_xlabel(TIME_LABEL)
    top.legend(fontsize=8, frameon=False, ncols=3)
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)
