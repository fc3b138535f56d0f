"""The figure of one seed's filter errors with their ±3σ bands, drawn from a sweep case record's traces."""

from pathlib import Path

import numpy as np

from lightcurve_gp.evaluation import plots


def test_error_bands_draw_each_filter_with_its_three_sigma_band(tmp_path, monkeypatch):
    figures = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: figures.append(fig) or Path(path))
    t = [0.0, 1.0, 2.0]
    traces = {"seed": 7, "times": t,
              "attitude_error_deg": {"gpukf": [[1.0, 2.0, 3.0]] * 3, "matched_ukf": [[0.5, 0.5, 0.5]] * 3},
              "attitude_sigma_deg": {"gpukf": [[2.0, 2.0, 2.0]] * 3, "matched_ukf": [[1.0, 1.0, 1.0]] * 3},
              "omega_error_deg_s": {"gpukf": [[0.01, 0.0, 0.0]] * 3, "matched_ukf": [[0.0, 0.0, 0.0]] * 3},
              "omega_sigma_deg_s": {"gpukf": [[0.02, 0.02, 0.02]] * 3}}  # the matched UKF knows ω
    assert plots.error_bands(traces, ["gpukf", "matched_ukf"], tmp_path / "e.png") == tmp_path / "e.png"
    (fig,) = figures
    axes = fig.axes
    assert [len(ax.lines) for ax in axes] == [2, 2, 2, 1, 1, 1]
    band = axes[0].collections[0].get_paths()[0].vertices[:, 1]  # gpukf's band about the yaw error, ±3 × 2°
    assert np.isclose(band.max(), 6.0) and np.isclose(band.min(), -6.0)
    assert [t.get_text() for t in axes[0].get_legend().get_texts()] == ["gpukf", "matched_ukf"]
    assert axes[3].get_ylabel() == "rate error x (deg/s)" and fig.get_suptitle() == "seed 7: errors and ±3σ bands"
