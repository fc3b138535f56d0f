"""The spin experiment's figure: one seed's attitude and body-rate errors with the filters' ±3σ bands."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.figure import Figure

from lightcurve_gp.evaluation.plots import ESTIMATOR_COLORS
from lightcurve_gp.files import atomic_path

__all__ = ["error_traces_figure"]


def error_traces_figure(traces: dict, estimators: Sequence[str], path: Path) -> Path:
    """Top row: GRP attitude error per body axis (deg, ≈ rotation vector); bottom row: body-rate error (deg/s);
    each estimator's error as a line and its ±3σ as a band (``traces`` of a sweep case record, seed 0)."""
    t = np.asarray(traces["times"])
    fig = Figure(figsize=(12, 5.5), layout="constrained")
    axes = fig.subplots(2, 3, sharex=True)
    rows = (("attitude_error_deg", "attitude_sigma_deg", "attitude error {} (deg)"),
            ("omega_error_deg_s", "omega_sigma_deg_s", "rate error {} (deg/s)"))
    for r, (err_key, sig_key, label) in enumerate(rows):
        for name in estimators:
            if name not in traces.get(sig_key, {}):
                continue
            err, sig = np.asarray(traces[err_key][name]), np.asarray(traces[sig_key][name])
            color = ESTIMATOR_COLORS.get(name, "gray")
            for i, ax in enumerate(axes[r]):
                ax.fill_between(t, -3 * sig[:, i], 3 * sig[:, i], color=color, alpha=0.15, linewidth=0)
                ax.plot(t, err[:, i], color=color, linewidth=0.9, label=name if i == 0 else None)
                ax.set_ylabel(label.format("xyz"[i]))
        axes[r][0].legend(fontsize=8)
    for ax in axes[1]:
        ax.set_xlabel("time (s)")
    fig.suptitle(f"seed {traces['seed']}: errors and ±3σ bands")
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
    return Path(path)
