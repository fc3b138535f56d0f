"""Scenarios along a pass: irregular sampling on the truth's grid, per-sample rendering, unobservable samples."""

from pathlib import Path

import torch

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.rotations import quat_mul, quat_normalize
from lightcurve_gp.config.load import load_config
from lightcurve_gp.passes.geometry import pass_geometry
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario

ROOT = Path(__file__).resolve().parents[1]


def _cfg(*overrides):
    return load_config(ROOT / "configs" / "geo_pass.yaml",
                       overrides=["scenario.duration_s=300", "evaluation.rmse_window_s=[200, 300]", *overrides])


def test_pass_with_gaps_samples_the_truth_and_its_increments():
    cfg = _cfg("geometry.gap_fraction=0.3", "geometry.gap_seed=2")
    sc = simulate_scenario(cfg, seeds=[0, 1])
    steps = torch.diff(sc.times)
    assert len(sc.times) < 301 and bool((steps >= 1).all()) and float(steps.max()) > 1  # irregular
    # the truth at the samples is the grid truth, and every increment carries one sample to the next
    grid, _ = propagate(quat_normalize(torch.tensor(cfg.scenario.q0, dtype=torch.float64)),
                        torch.deg2rad(torch.tensor(cfg.scenario.omega0_deg_s, dtype=torch.float64)),
                        torch.tensor(cfg.shape.inertia_kg_m2, dtype=torch.float64), 1.0, 300)
    assert sc.q_true.shape == (2, len(sc.times), 4) and sc.increments.shape == (2, len(sc.times) - 1, 4)
    assert torch.allclose(sc.q_true, grid[sc.times.long()].expand(2, -1, -1), atol=1e-14)
    carried = quat_normalize(quat_mul(sc.increments, sc.q_true[:, :-1]))
    assert torch.allclose(carried, sc.q_true[:, 1:], atol=1e-12)


def test_pass_renders_each_sample_with_its_geometry():
    cfg = _cfg()
    sc = simulate_scenario(cfg, seeds=[0])
    geometry = pass_geometry(cfg)
    scene = Scene.from_config(cfg, rho=cfg.scenario.rho_true)
    for k in (0, 150, 300):
        assert torch.allclose(sc.m_clean[0, k], scene.sample(k).magnitude(sc.q_true[0, k]), atol=1e-12)
    assert float(geometry.phase_angle_deg[0] - geometry.phase_angle_deg[-1]) > 0.5  # the geometry moves
    assert sc.unobservable == 0 and bool(torch.isfinite(sc.observations).all())


def test_unobservable_samples_are_missing_observations():
    cfg = _cfg("geometry.min_elevation_deg=43.4434")  # the object sets below this limit during the pass
    geometry = pass_geometry(cfg)
    sc = simulate_scenario(cfg, seeds=[0, 3])
    hidden = ~geometry.observable
    assert 0 < int(hidden.sum()) < len(geometry) and sc.unobservable == int(hidden.sum())
    assert bool(torch.isnan(sc.observations[:, hidden]).all()) and bool(torch.isnan(sc.m_clean[:, hidden]).all())
    assert bool(torch.isfinite(sc.observations[:, ~hidden]).all())
