"""Training data: window definition, attitude options, cache behaviour."""

from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.rotations import attitude_matrix, quat_canonical
from lightcurve_gp.config.load import load_config
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.training.sets import generate_heldout_set, generate_training_set, load_or_generate
from lightcurve_gp.training.windows import drop_duplicate_attitudes, initial_attitudes

BOXWING = Path(__file__).resolve().parents[1] / "configs" / "boxwing.yaml"
SMALL = ["data.icosphere_subdivisions=0", "data.phi_step_deg=120", "data.rho_grid=[0.2, 0.6]",
         "data.t_span_past=5", "data.heldout_size=16"]


def small_config(*extra):
    return load_config(BOXWING, overrides=SMALL + list(extra))


def test_paper_grid_has_3852_attitudes_of_which_1606_distinct():
    cfg = load_config(BOXWING)
    q = initial_attitudes(cfg.data)
    assert q.shape == (3852, 4)
    distinct = drop_duplicate_attitudes(q)
    assert distinct.shape == (1606, 4)
    # every dropped attitude has a kept one with the same attitude matrix
    a_all, a_kept = attitude_matrix(q), attitude_matrix(distinct)
    gap = (a_all[:, None] - a_kept[None]).flatten(2).norm(dim=-1).min(dim=1).values
    assert float(gap.max()) < 1e-9


def test_training_points_follow_the_documented_window():
    cfg = small_config()
    ts = generate_training_set(cfg, progress=False)
    q0 = initial_attitudes(cfg.data)
    assert len(ts) == 2 * q0.shape[0] and ts.dropped == 0
    # recompute one point independently: ρ-major order, window samples 0..T-1 averaged, y at T
    i, r = 7, 1
    omega0 = torch.deg2rad(torch.tensor(cfg.data.omega0_deg_s, dtype=torch.float64))
    q_hist, _ = propagate(q0[i], omega0, torch.tensor(cfg.shape.inertia_kg_m2, dtype=torch.float64), 1.0, 5)
    m = Scene.from_config(cfg).magnitude(q_hist, rho=cfg.data.rho_grid[r])
    k = r * q0.shape[0] + i
    assert torch.allclose(ts.q[k], q_hist[-1], atol=1e-14)
    assert float(ts.m_past[k]) == pytest.approx(float(m[:5].mean()), abs=1e-12)
    assert float(ts.y[k]) == pytest.approx(float(m[5]), abs=1e-12)
    assert float(ts.rho[k]) == pytest.approx(0.6)


def test_sign_policies():
    canon = generate_training_set(small_config("data.quaternion_sign=canonical"), progress=False)
    assert bool((canon.q[:, 3] >= 0).all())
    both = generate_training_set(small_config("data.quaternion_sign=both"), progress=False)
    assert len(both) == 2 * len(canon)
    assert torch.equal(both.q[len(canon):], -both.q[: len(canon)])
    assert torch.equal(both.y[len(canon):], both.y[: len(canon)])
    assert torch.allclose(quat_canonical(both.q[: len(canon)]), canon.q)


def test_random_sampling_is_seeded():
    a = initial_attitudes(small_config("data.sampling=random", "data.num_random=50").data)
    b = initial_attitudes(small_config("data.sampling=random", "data.num_random=50").data)
    c = initial_attitudes(small_config("data.sampling=sobol", "data.num_random=50", "data.seed=3").data)
    assert a.shape == (50, 4) and torch.equal(a, b) and not torch.allclose(a, c[:50])


def test_heldout_rho_is_off_the_grid():
    cfg = small_config()
    held = generate_heldout_set(cfg)
    assert len(held) == 16
    assert bool((held.rho > 0.2).all() and (held.rho < 0.6).all())
    grid = torch.tensor(cfg.data.rho_grid, dtype=torch.float64)
    assert float((held.rho[:, None] - grid).abs().min()) > 1e-6


def test_cache_regenerates_only_when_a_data_key_changes(tmp_path):
    cfg = small_config()
    first, path, loaded = load_or_generate(cfg, tmp_path, progress=False)
    assert not loaded and path.exists()
    again, path2, loaded2 = load_or_generate(load_config(BOXWING, SMALL + ["filter.process_noise=0.3"]), tmp_path,
                                             progress=False)
    assert loaded2 and path2 == path and torch.equal(again.y, first.y)
    changed, path3, loaded3 = load_or_generate(small_config("data.t_span_past=4"), tmp_path, progress=False)
    assert not loaded3 and path3 != path and not torch.equal(changed.m_past, first.m_past)


def test_corrupted_cache_is_regenerated_not_trusted(tmp_path):
    cfg = small_config()
    first, path, _ = load_or_generate(cfg, tmp_path, progress=False)
    path.write_bytes(b"not a torch file")
    again, _, loaded = load_or_generate(cfg, tmp_path, progress=False)
    assert not loaded and torch.equal(again.y, first.y)
    assert not list(Path(tmp_path).glob(".*.tmp"))  # atomic writes leave no temporary files


def test_window_must_be_a_multiple_of_the_step():
    with pytest.raises(ValueError, match="multiple of data.dt_s"):
        generate_training_set(small_config("data.t_span_past=2.5"), progress=False)
