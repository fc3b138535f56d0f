"""Generalisation suite: per-seed batching, the no-update baseline's score, the MAP reference, summaries, resume."""

import dataclasses
import math
from pathlib import Path

import pytest
import torch
import yaml

from lightcurve_gp.attitude.dynamics import propagate_only
from lightcurve_gp.attitude.metrics import total_angle_deg
from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation.harness import run_estimators
from lightcurve_gp.evaluation.scoring import nees_band
from lightcurve_gp.evaluation.suite_summary import ERROR_BINS, bin_label, suite_rows, summarize, whitened_correlation
from lightcurve_gp.inference.surface import batch_map
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_truths
from lightcurve_gp.simulation.truths import TruthDraw, draw_truths

DT = torch.float64
CONFIG = Path(__file__).resolve().parents[1] / "configs" / "boxwing_robust.yaml"
SHORT = ["scenario.duration_s=30.0", "evaluation.rmse_window_s=[20.0, 30.0]"]


@pytest.fixture(scope="module")
def cfg():
    return load_config(CONFIG, SHORT)


@pytest.fixture(scope="module")
def scene(cfg):
    return Scene.from_config(cfg, dtype=DT)


@pytest.fixture(scope="module")
def truths(cfg, scene):
    return simulate_truths(cfg, draw_truths([21, 22, 23]), scene)


def run_suite(cfg, truths, *, estimators, scene):
    return run_estimators(cfg, truths, estimators=estimators, scene=scene).results


def _subset(truths, i):
    per_seed = {f.name: getattr(truths, f.name)[i:i + 1] for f in dataclasses.fields(truths)
                if f.name not in ("times", "noise_var", "rho_true", "geometry", "unobservable", "surface")}
    return dataclasses.replace(truths, **per_seed, surface=truths.surface.index(slice(i, i + 1)))


def test_filters_with_per_seed_increments_and_surfaces_equal_one_seed_at_a_time(cfg, scene, truths):
    estimators = ("matched_ukf", "joint_ukf", "surface_ukf")
    batched = run_suite(cfg, truths, estimators=estimators, scene=scene)
    assert not torch.equal(truths.increments[0], truths.increments[1])
    for i in range(3):
        alone = run_suite(cfg, _subset(truths, i), estimators=estimators, scene=scene)
        assert alone[estimators[0]].rmse_deg.shape == (1, 3)
        for name in estimators:
            assert torch.allclose(batched[name].rmse_deg[i], alone[name].rmse_deg[0], rtol=1e-9, atol=1e-10)
            assert torch.allclose(batched[name].nees_mean[i], alone[name].nees_mean[0], rtol=1e-9)


def test_no_update_nees_is_the_initial_error_against_p0(cfg, scene, truths):
    # the error keeps its angle while both turn with the known spin; P0 is isotropic, so the NEES of the GRP error
    # (a = 1, f = 4: |p| = 4 tan(angle / 4)) is constant in time
    r = run_suite(cfg, truths, estimators=("no_update",), scene=scene)["no_update"]
    angle = truths.error.norm(dim=-1)
    expected = (4.0 * torch.tan(angle / 4.0)) ** 2 / truths.sigma0 ** 2
    assert torch.allclose(r.nees_mean, expected, rtol=1e-9)
    assert torch.allclose(r.white_first.norm(dim=-1), r.white_last.norm(dim=-1), rtol=1e-9)


def test_map_recovers_the_attitude_from_a_noise_free_curve_of_a_known_surface():
    # the paper's trajectory and surface with a 9 deg initial error; the reference surface is the truth's, so the
    # offset model is exact and, with a negligible prior, the MAP lands on the truth (offset 0)
    cfg = load_config(CONFIG)
    scene = Scene.from_config(cfg, dtype=DT)
    t64 = lambda v: torch.tensor(v, dtype=DT)  # noqa: E731
    surface = Surface(t64([0.5]), t64([cfg.surface.f0]), t64([cfg.surface.n_u]), t64([cfg.surface.n_v]))
    draw = TruthDraw([0], t64([[0.0, 0.0, 0.0, 1.0]]), torch.deg2rad(t64([cfg.scenario.omega0_deg_s])), surface,
                     torch.deg2rad(t64([[5.0, -4.0, 6.0]])), t64([math.radians(10.0)]))
    truths = simulate_truths(cfg, draw, scene)
    est = batch_map(scene, q_est0=draw.q_est0, sigma0=draw.sigma0 * 100, observations=truths.m_clean,
                    increments=truths.increments, checkpoints=[400, 600], measurement_noise=0.5, reference=surface,
                    offset_std=1.0, surface=False, iterations=30, warm_iterations=10)
    start = propagate_only(draw.q_est0, truths.increments[0])[0, [400, 600]]
    assert float(total_angle_deg(truths.q_true[0, [400, 600]], start).min()) > 8.0
    assert float(total_angle_deg(truths.q_true[0, [400, 600]], est.q_est[0]).max()) < 0.5
    assert abs(float(est.x[0, -1, 3])) < 1e-2


def test_nees_band_of_one_sample_holds_95_percent_of_chi_square_3():
    lo, hi = nees_band()
    samples = torch.randn(50_000, 3, generator=torch.Generator().manual_seed(0), dtype=DT).pow(2).sum(-1)
    assert float(((samples >= lo) & (samples <= hi)).double().mean()) == pytest.approx(0.95, abs=0.006)
    assert nees_band(200)[1] - nees_band(200)[0] < 1.0 < hi - lo


def test_bins_are_half_open_and_complete():
    assert [bin_label(v, ERROR_BINS) for v in (0.0, 9.999, 10.0, 20.0, 45.0)] == ["<10", "<10", "10-20", ">20", ">20"]
    with pytest.raises(ValueError, match="no bin"):
        bin_label(-1.0, ERROR_BINS)


def test_summaries_count_every_seed_once_per_grouping(cfg, scene, truths):
    result = run_estimators(cfg, truths, estimators=("no_update",), scene=scene)
    results = result.results
    rows = suite_rows(result, nees_band(), error_mode="random")
    summary = summarize(rows)
    for grouping in ("all", "surface class", "|omega0| (deg/s)", "initial error (deg)"):
        assert sum(e["seeds"] for e in summary if e["grouping"] == grouping) == 3
    overall = next(e for e in summary if e["grouping"] == "all")
    assert overall["share_below_10deg"] == pytest.approx(sum(r["below_10deg"] for r in rows) / 3)
    assert overall["nees_mean"] == pytest.approx(float(results["no_update"].nees_mean.mean()))
    # the no-update error is a constant vector in the turning frame: first and last whitened errors agree
    assert whitened_correlation(rows, "no_update") == pytest.approx(1.0)


def test_experiment_resumes_from_its_stored_blocks(tmp_path, monkeypatch):
    import experiments.generalization as gen

    raw = yaml.safe_load(CONFIG.read_text())
    raw["name"] = "tiny_suite"
    raw["scenario"]["duration_s"], raw["evaluation"]["rmse_window_s"] = 60.0, [40.0, 60.0]
    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump(raw))
    argv = ["--model-config", str(config), "--blocks", "", "--error-angles", "10", "--error-seeds", "5:7",
            "--block-size", "1", "--error-estimators", "no_update", "--out", str(tmp_path / "out"),
            "--runs", str(tmp_path / "runs")]
    assert gen.main(argv) == 0
    first = (tmp_path / "out" / "initial_error.csv").read_text()
    assert len(list((tmp_path / "runs" / "generalization" / "cases").glob("*.json"))) == 2

    def refuse(*args, **kwargs):
        raise AssertionError("a stored block was run again")

    monkeypatch.setattr(gen, "run_estimators", refuse)
    assert gen.main(argv) == 0
    assert (tmp_path / "out" / "initial_error.csv").read_text() == first
    assert gen.main(["--model-config", str(config), "--estimators", "nope"]) == 2
    # a fixed 10 deg error against P0 = (10 deg / sqrt 3)^2 I: the no-update NEES is 16 tan^2(2.5 deg) / sigma0^2
    nees = float(first.splitlines()[1].split(",")[10])
    assert nees == pytest.approx(16 * math.tan(math.radians(2.5)) ** 2 / (math.radians(10) / math.sqrt(3)) ** 2)
