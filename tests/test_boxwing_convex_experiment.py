"""experiments/boxwing_convex.py's smallest case: the simulated truth is the convex model of the box-wing's facets
(same pole, period and frame conventions as the search), and one seed runs end to end into a row and a summary."""

import json
import math

import numpy as np
import pytest
import torch

from experiments import boxwing_convex
from lightcurve_gp.photometry.convex import SatelliteScattering, body_vectors, brightness, phase_angle


def test_truth_is_the_convex_model_of_the_box_wing():
    obs, truth, extra = boxwing_convex.simulate(5, nights=1, hours=0.5, cadence=20.0)
    assert truth["curves"] == 1 and truth["samples"] == len(obs) > 60
    spin = dict(lam=torch.tensor([math.radians(truth["lam_deg"])], dtype=torch.float64),
                beta=torch.tensor([math.radians(truth["beta_deg"])], dtype=torch.float64),
                period_s=torch.tensor([extra["period_s"]], dtype=torch.float64),
                phi0=torch.zeros(1, dtype=torch.float64), t_s=obs.t)
    law = SatelliteScattering(f0=0.5, exponents=(800.0,))
    L = brightness(extra["areas"][None], extra["normals"], body_vectors(obs.sun, **spin),
                   body_vectors(obs.observer, **spin), phase_angle(obs.sun, obs.observer), law)[0]
    # the renderer's magnitudes less the convex model's: the range term 5 log10(r) - 26.7 alone
    offset = extra["clean_mag"] + 2.5 * np.log10(L.numpy()) - 5.0 * np.log10(obs.range_m.numpy())
    assert np.ptp(offset) < 1e-9
    # a wrong sense of rotation (the pole reversed) does not reproduce them
    flipped = dict(spin, lam=spin["lam"] + math.pi, beta=-spin["beta"])
    L2 = brightness(extra["areas"][None], extra["normals"], body_vectors(obs.sun, **flipped),
                    body_vectors(obs.observer, **flipped), phase_angle(obs.sun, obs.observer), law)[0]
    assert np.abs(2.5 * np.log10(L2.numpy() / L.numpy())).max() > 0.01
    noise = obs.mag.numpy() - extra["clean_mag"]
    assert 0.03 < noise.std() < 0.07


@pytest.mark.slow  # ~10 s on one loaded core
def test_one_seed_runs_into_a_row_and_a_summary(tmp_path, capsys):
    args = ["--seed", "7", "--count", "1", "--nights", "1", "--hours", "1", "--cadence", "20", "--out", str(tmp_path),
            "--setting", "fine_poles=40", "--setting", "polish_iterations=10"]
    assert boxwing_convex.main(args) == 0
    row = json.loads((tmp_path / "rows.jsonl").read_text())
    assert row["seed"] == 7 and row["kind"] in boxwing_convex.KINDS
    assert row["best_ok"] == (row["best_image"] is not None) == (row["kind"] == "right")
    # the box-wing is itself turned 180 deg about either stable axis: the half turn is derived exact, period P/2
    assert row["half_turn_nats"] < 1e-9 and [im["name"] for im in row["images"]][:2] == ["identity", "half turn"]
    assert row["images"][1]["period_min"] == pytest.approx(row["period_min"] / 2, rel=1e-12)
    assert row["basin_rss_mag"] == min(row["start_rss_mag"].values())
    assert row["dnats"] == pytest.approx((row["best_rss_mag"] - row["basin_rss_mag"]) / (2 * 0.05 ** 2))
    summary = json.loads((tmp_path / "rows.summary.json").read_text())
    assert summary["seeds"] == 1 and summary["best_ok"] == int(row["best_ok"])
    assert "seed 7:" in capsys.readouterr().out
    assert boxwing_convex.main(args) == 0                       # resumes: the seed is not run again
    assert len((tmp_path / "rows.jsonl").read_text().splitlines()) == 1


def test_diagnose_refuses_held_out_seeds(capsys):
    with pytest.raises(SystemExit) as exit_info:
        boxwing_convex.main(["--seed", "200", "--diagnose"])
    assert exit_info.value.code == 2
    assert "--diagnose: held-out seeds (>= 200) are not diagnosed; use a tuning seed" in capsys.readouterr().err
