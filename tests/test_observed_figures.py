"""The figures a user reads first (issue 30, item 12): what each one shows, checked on the drawn figure."""

import math

import numpy as np
import pytest
import torch
from astropy.table import Table
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PolyCollection, QuadMesh

from lightcurve_gp.attitude.rotations import euler321_to_quat, quat_mul, quat_to_euler321, rotvec_to_quat
from lightcurve_gp.evaluation import plots
from lightcurve_gp.observed import plots as observed_plots
from lightcurve_gp.observed.run import euler321_jacobian


@pytest.fixture
def figures(monkeypatch):
    """The figures the plot functions would write, drawn (so tick labels exist) instead of saved."""
    drawn = []

    def keep(fig, path):
        FigureCanvasAgg(fig).draw()
        drawn.append(fig)
        return path

    monkeypatch.setattr(plots, "save_figure", keep)
    monkeypatch.setattr(observed_plots, "save_figure", keep)
    return drawn


def legend_texts(fig):
    return [t.get_text() for legend in fig.legends for t in legend.get_texts()] + \
        [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]


def tick_texts(axis):
    return [t.get_text() for t in axis.get_majorticklabels() + axis.get_minorticklabels() if t.get_text()]


def test_residual_histogram_counts_the_tail_it_does_not_draw(figures, tmp_path):
    z = np.r_[np.linspace(-2, 2, 95), [-40.0, -6.0, 5.5, 7.0, 300.0]]
    plots.residual_histogram(torch.tensor(0.3 * z), torch.full((100,), 0.3), tmp_path / "r.png")
    fig = figures[0]
    assert "beyond ±5 (not drawn): 5 of 100, 5.0 % (N(0, 1): 0.00006 %)" in legend_texts(fig)
    assert fig.axes[1].get_ylabel() == "probability density" and fig.axes[0].get_ylabel() == "count"


def test_a_normalised_target_is_labelled_as_such(figures, tmp_path):
    quantity = plots.target_quantity("rho_normalised", 0.5)
    plots.prediction_scatter(torch.tensor([13.0, 14.0]), torch.tensor([13.1, 13.9]), tmp_path / "s.png",
                             quantity=quantity)
    ax = figures[0].axes[0]
    assert ax.get_xlabel() == "true $m_{app}$ normalised to ρ = 0.5 [mag] (brighter →)"
    assert ax.get_ylabel() == "predicted $m_{app}$ normalised to ρ = 0.5 [mag] (brighter ↑)"
    assert plots.target_quantity("magnitude", 0.5) == "$m_{app}$"


def test_box_plot_has_the_success_line_and_readable_labels(figures, tmp_path):
    rmse = {n: torch.rand(5, 3, generator=torch.Generator().manual_seed(1)) * 20 + 1
            for n in ("gpukf", "ukf", "matched_ukf", "no_update")}
    plots.rmse_boxplot(rmse, tmp_path / "b.png")
    fig = figures[0]
    for ax in fig.axes:
        assert any(list(line.get_ydata()) == [10.0, 10.0] for line in ax.get_lines())
        labels = [t.get_text() for t in ax.get_xticklabels()]
        assert labels == ["GPUKF\n(trained GP)", "UKF (assumed\nρ)", "matched UKF\n(knows ρ)",
                          "no update\n(propagation\nonly)"]
        assert all(t.get_rotation() == 0 for t in ax.get_xticklabels())
        assert not any("×" in t or "10^" in t for t in tick_texts(ax.yaxis))
    assert "10° (the <10deg success threshold)" in legend_texts(fig)


def test_legends_use_readable_names(figures, tmp_path):
    t = torch.arange(4.0)
    plots.euler_errors(t, {"gpukf": torch.zeros(4, 3), "matched_ukf": torch.ones(4, 3)}, tmp_path / "e.png")
    plots.light_curves(t, torch.zeros(4), {"no_update": torch.zeros(4)}, tmp_path / "l.png")
    texts = legend_texts(figures[0]) + legend_texts(figures[1])
    assert "matched UKF (knows ρ)" in texts and "GPUKF (trained GP)" in texts
    assert "no update (propagation only)" in texts
    assert not {"matched_ukf", "gpukf", "no_update"} & set(texts)


def history(n: int, yaw_deg: np.ndarray) -> Table:
    t = np.arange(n, dtype=float)
    sigma = np.linspace(5.0, 3.0, n)
    return Table({"t_s": t, "mag_obs": 13 + np.sin(t / 7), "mag_pred": 13 + np.sin(t / 7), "mag_pred_sigma": sigma / 10,
                  "yaw_deg": yaw_deg, "pitch_deg": np.zeros(n), "roll_deg": np.full(n, 179.5),
                  **{f"sigma_{a}_deg": sigma for a in ("x", "y", "z", "yaw", "pitch", "roll")}})


def test_attitude_figure_unwraps_shows_bands_names_the_axes_and_reads_plain_ticks(figures, tmp_path):
    yaw = (170.0 + 2.0 * np.arange(20) + 180.0) % 360.0 - 180.0  # crosses +180 deg at sample 5
    observed_plots.attitude_with_uncertainty(history(20, yaw), tmp_path / "a.png")
    fig = figures[0]
    drawn = fig.axes[0].get_lines()[0].get_ydata()
    np.testing.assert_allclose(np.diff(drawn), 2.0)  # unwrapped: no 360 deg jump
    assert any(isinstance(c, PolyCollection) for c in fig.axes[0].collections)  # the ±1σ band
    texts = legend_texts(fig)
    assert {"about body z (≈ yaw)", "about body y (≈ pitch)", "about body x (≈ roll)", "±1σ"} <= set(texts)
    assert fig.axes[3].get_yscale() == "log"
    ticks = tick_texts(fig.axes[3].yaxis)
    assert ticks and not any("×" in t or "10^" in t for t in ticks)


def test_a_long_light_curve_is_drawn_as_a_density_with_a_zoom(figures, tmp_path):
    n = 100_000
    observed_plots.light_curve_band(history(n, np.zeros(n)), tmp_path / "l.png")
    density, zoom = figures[0].axes[:2]
    assert any(isinstance(c, QuadMesh) for c in density.collections)
    assert all(len(line.get_xdata()) <= observed_plots.TIME_BINS + 1 for line in density.get_lines())
    assert all(len(line.get_xdata()) <= observed_plots.ZOOM_SAMPLES for line in zoom.get_lines())
    assert density.get_title() == f"all {n} samples: density of the observed magnitudes"


def test_euler_jacobian_matches_finite_differences_of_a_body_rotation():
    g = torch.Generator().manual_seed(3)
    for _ in range(5):
        euler = (torch.rand(3, generator=g, dtype=torch.float64) - 0.5) * torch.tensor([6.0, 2.8, 6.0],
                                                                                      dtype=torch.float64)
        q = euler321_to_quat(euler)
        h = 1e-6
        columns = []
        for i in range(3):
            step = h * torch.eye(3, dtype=torch.float64)[i]
            plus = quat_to_euler321(quat_mul(rotvec_to_quat(step), q))
            minus = quat_to_euler321(quat_mul(rotvec_to_quat(-step), q))
            columns.append((plus - minus) / (2 * h))
        numeric = torch.stack(columns, -1)
        assert torch.allclose(euler321_jacobian(quat_to_euler321(q)), numeric, atol=1e-8)
    # at pitch 0 and roll 0 the angles are the body rotations themselves: z -> yaw, y -> pitch, x -> roll
    J = euler321_jacobian(torch.zeros(3, dtype=torch.float64))
    assert torch.equal(J, torch.tensor([[0.0, 0, 1], [0, 1, 0], [1, 0, 0]], dtype=torch.float64))
    assert math.isclose(float(euler321_jacobian(torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))[0, 2]),
                        1 / math.cos(1.0), rel_tol=1e-15)
