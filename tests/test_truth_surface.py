"""The truth's surface is a scenario key of its own, and a noise level that is not a positive number is refused
with one line naming its key."""

from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from lightcurve_gp.commands import estimate
from lightcurve_gp.config.load import ConfigError, config_hash, load_config
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario
from lightcurve_gp.simulation.truths import paper_case_draw, truth_is_model_surface, truth_material
from lightcurve_gp.training.keys import model_key, model_record
from lightcurve_gp.training.store import training_mismatch

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
ROBUST = CONFIGS / "boxwing_robust.yaml"
SHORT = ["scenario.duration_s=20", "evaluation.rmse_window_s=[10, 20]"]


@pytest.mark.parametrize("override, message", [
    ("scenario.noise_var=0", "scenario.noise_var: 0 must be > 0"),
    ("scenario.noise_var=-0.01", "scenario.noise_var: -0.01 must be > 0"),
    ("scenario.noise_var=.nan", "scenario.noise_var: nan is not finite"),
    ("scenario.noise_var=nan", "scenario.noise_var: nan is not finite"),
    ("filter.measurement_noise=0", "filter.measurement_noise: 0 must be > 0"),
    ("filter.measurement_noise=-1", "filter.measurement_noise: -1 must be > 0"),
    ("filter.measurement_noise=.nan", "filter.measurement_noise: nan is not finite"),
    ("scenario.surface.f0=1.5", "scenario.surface.f0: 1.5 is outside [0, 1]"),
    ("scenario.surface.rho=0", "scenario.surface.rho: 0 is outside (0, 1]"),
    ("scenario.surface.bogus=1", "scenario.surface.bogus: unknown key (known keys: rho, f0, n_u, n_v)"),
])
def test_a_bad_noise_level_or_truth_surface_is_one_line_naming_its_key(override, message):
    with pytest.raises(ConfigError) as info:
        load_config(ROBUST, [override])
    assert str(info.value) == message


def test_the_estimate_command_reports_a_bad_noise_level_in_one_line(tmp_path, capsys):
    code = estimate.main([str(ROBUST), "--set", "scenario.noise_var=0", "--out", str(tmp_path), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err == "error: scenario.noise_var: 0 must be > 0"


def test_the_truth_surface_leaves_every_model_key_as_it_was():
    base = load_config(ROBUST)
    other = load_config(ROBUST, ["scenario.surface.f0=0.9", "scenario.surface.n_u=50"])
    model_side = load_config(ROBUST, ["surface.f0=0.9"])
    assert model_key(other) == model_key(base) != model_key(model_side)
    assert config_hash(other) != config_hash(base)
    trained = SimpleNamespace(extra=model_record(base))
    assert training_mismatch(trained, other) is None
    assert training_mismatch(trained, model_side).startswith("surface.f0: the model was trained with 0.5")
    assert truth_is_model_surface(base) and not truth_is_model_surface(other)
    assert truth_material(other) == (0.5, 0.9, 50.0, 800.0)
    assert truth_material(load_config(ROBUST, ["scenario.surface.rho=0.3"]), None)[0] == 0.3
    assert truth_material(load_config(ROBUST, ["scenario.surface.rho=0.3"]), 0.7)[0] == 0.7  # --rho-true wins


def test_another_truth_surface_is_what_the_scenario_renders():
    cfg = load_config(ROBUST, [*SHORT, "scenario.surface.f0=0.9", "scenario.surface.n_v=40"])
    base = load_config(ROBUST, SHORT)
    sc, sc_base = simulate_scenario(cfg, seeds=[0, 1]), simulate_scenario(base, seeds=[0, 1])
    scene = Scene.from_config(cfg)
    direct = scene.magnitude(sc.q_true[0].unsqueeze(0), surface=Surface(*(torch.tensor([v], dtype=torch.float64)
                                                                         for v in (0.5, 0.9, 800.0, 40.0))))[0]
    torch.testing.assert_close(sc.m_clean[0], direct, rtol=0, atol=1e-12)
    assert float((sc.m_clean[0] - sc_base.m_clean[0]).abs().max()) > 0.05
    assert float(sc.surface.f0[0]) == 0.9 and float(sc.surface.n_v[1]) == 40.0
    draw = paper_case_draw(cfg, [0], rho=0.5)
    assert (float(draw.surface.f0[0]), float(draw.surface.n_v[0])) == (0.9, 40.0)


def test_the_default_truth_renders_exactly_as_before():
    """No scenario.surface: the same arithmetic as the model's material at rho_true (bit for bit)."""
    cfg = load_config(ROBUST, SHORT)
    sc = simulate_scenario(cfg, seeds=[3])
    scene = Scene.from_config(cfg)
    assert torch.equal(sc.m_clean[0], scene.magnitude(sc.q_true[0], rho=torch.tensor(0.5, dtype=torch.float64)))
