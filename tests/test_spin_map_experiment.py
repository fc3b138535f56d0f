"""The spin experiment's MAP rows: stored once in the case store and read back, one cell per column of the tables."""

import pytest

from experiments import spin_unknown
from experiments.common import ROOT, SPIN_HEADER, case_overrides
from experiments.spin_tuning import choose
from experiments.spin_unknown import build_parser, main
from lightcurve_gp.config.load import apply_overrides, config_from_dict, load_raw_config


@pytest.mark.slow
def test_map_case_is_stored_and_read_back(tmp_path, monkeypatch):
    raw = apply_overrides(load_raw_config(ROOT / "configs/boxwing_robust.yaml"), ["name=spin_unknown"])
    raw = apply_overrides(raw, [*case_overrides(100.0, 0.03), "evaluation.rmse_window_s=[50, 100]"])
    first = spin_unknown.map_case(raw, seeds=[200, 201], rho_true=0.3, model="renderer", every=50.0, out=tmp_path)
    assert first["checkpoints_s"] == [50.0, 100.0] and first["scored_s"] == [50.0, 100.0]
    assert len(first["rmse_deg"]) == 2 and len(first["truth_cost_below_map"]) == 2
    stored = list((tmp_path / "spin_unknown" / "map" / "cases").glob("*.json"))
    assert len(stored) == 1

    def fail(*args, **kwargs):
        raise AssertionError("solved again")

    monkeypatch.setattr(spin_unknown, "solve_map", fail)
    again = spin_unknown.map_case(raw, seeds=[200, 201], rho_true=0.3, model="renderer", every=50.0, out=tmp_path)
    assert again == first
    assert len(spin_unknown.map_row("MAP", first)) == len(SPIN_HEADER)
    assert len(spin_unknown.map_diagnostics_row(0.03, first)) == len(spin_unknown.DIAGNOSTICS_HEADER)
    with pytest.raises(ValueError, match="--map-models: 'gp' is not one of renderer, gp_offset"):
        spin_unknown.map_case(raw, seeds=[200], rho_true=0.3, model="gp", every=50.0, out=tmp_path)


def test_map_key_ignores_the_rate_process_noise_only():
    """The MAP has no process noise: tuning ``filter.omega_process_noise`` must not recompute it, any key it reads
    (here the measurement noise of its prior) must."""
    raw = apply_overrides(load_raw_config(ROOT / "configs/boxwing_robust.yaml"), case_overrides(600.0, 0.03))

    def key(*overrides):
        return spin_unknown.map_key(config_from_dict(apply_overrides(raw, list(overrides))), [200], "renderer", [50])

    assert key("filter.omega_process_noise=0") == key("filter.omega_process_noise=3e-10")
    assert key("filter.omega_process_noise=0") != key("filter.measurement_noise=0.6")


@pytest.mark.parametrize("argv, message", [(["--map-models", "renderer,gp"], "argument --map-models: 'renderer,gp'"),
                                           (["--map", "--sigmas", "0"], "--sigmas: 0 must be > 0 with --map"),
                                           (["--map", "--durations", "600", "--map-durations", "1800"],
                                            "--map-durations: [1800.0] must be among --durations [600.0]")])
def test_bad_map_arguments_exit_2_naming_the_option(argv, message, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2 and message in capsys.readouterr().err
    assert build_parser().parse_args(["--map"]).map_models == ["renderer"]


def test_rate_noise_rule_leaves_out_a_duration_no_value_reaches():
    scores = {0.0: {600.0: 0.25, 1800.0: 6.5}, 1e-10: {600.0: 0.07, 1800.0: 6.2}, 3e-10: {600.0: 0.32, 1800.0: 4.5}}
    assert choose(scores) == (1e-10, [600.0], 3e-10)
    scores[3e-10][1800.0] = 0.9  # now within reach: the worst score over both durations decides
    assert choose(scores) == (3e-10, [600.0, 1800.0], 3e-10)
