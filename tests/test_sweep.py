"""Resumable sweeps: grid parsing and expansion, config validation, per-case storage, resume, failures, tables."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from lightcurve_gp.config.load import ConfigError, apply_overrides, config_from_dict, content_hash
from lightcurve_gp.evaluation.reporting import RESULT_COLUMNS
from lightcurve_gp.sweep.cli import main
from lightcurve_gp.sweep.grid import expand_grid, make_cases, parse_grid
from lightcurve_gp.sweep.runner import run_case, run_sweep
from lightcurve_gp.sweep.tables import SUMMARY_COLUMNS

BOXWING = Path(__file__).resolve().parents[1] / "configs" / "boxwing.yaml"
TINY = ["name=tiny", "data.icosphere_subdivisions=0", "data.phi_step_deg=120", "data.heldout_size=10",
        "scenario.duration_s=30", "evaluation.rmse_window_s=[10, 30]"]
METRICS = ("rmse_yaw_deg", "rmse_pitch_deg", "rmse_roll_deg", "lc_rmse_noisy", "lc_rmse_clean", "nees_mean")


def tiny_raw(*extra: str) -> dict:
    return apply_overrides(yaml.safe_load(BOXWING.read_text()), TINY + list(extra))


def counting_runner(calls: list, key: str):
    """A case runner that records ``spec[key]`` of every case it runs."""
    def counting(spec):
        calls.append(spec[key])
        return run_case(spec)
    return counting


def interrupting_runner(seen: list):
    """A case runner that runs the first case (its id appended to ``seen``), then raises KeyboardInterrupt."""
    def interrupted_after_one(spec):
        if seen:
            raise KeyboardInterrupt
        seen.append(spec["case_id"])
        return run_case(spec)
    return interrupted_after_one


def read_csv(path: Path) -> tuple[list[str], list[dict]]:
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames), list(reader)


# ----------------------------------------------------------------------------------------------- grid

def test_grid_values_are_parsed_as_yaml():
    assert parse_grid("data.t_span_past=10,20.5") == ("data.t_span_past", [10, 20.5])
    assert parse_grid("scenario.initial_error_deg=[1, 2, 3],[4, 5, 6]") == (
        "scenario.initial_error_deg", [[1, 2, 3], [4, 5, 6]])
    assert parse_grid("filter.add_model_variance=true,false") == ("filter.add_model_variance", [True, False])
    assert parse_grid("model.kind=exact,sparse") == ("model.kind", ["exact", "sparse"])
    with pytest.raises(ConfigError, match="expected key.path=value"):
        parse_grid("data.t_span_past")
    with pytest.raises(ConfigError, match="no values"):
        parse_grid("data.t_span_past=")


def test_grid_expansion_is_the_cartesian_product_last_axis_fastest():
    points = expand_grid([("a", [1, 2]), ("b", ["x", "y", "z"])])
    assert points == [{"a": a, "b": b} for a in (1, 2) for b in ("x", "y", "z")]
    assert expand_grid([]) == [{}]
    with pytest.raises(ConfigError, match="a: grid axis given more than once"):
        expand_grid([("a", [1]), ("a", [2])])


def test_cases_apply_the_grid_and_share_models_across_scenario_values():
    cases = make_cases(tiny_raw(), [("data.t_span_past", [10, 20]), ("scenario.rho_true", [0.3, 0.7])], range(2))
    assert [(c.config.data.t_span_past, c.config.scenario.rho_true) for c in cases] == [
        (10.0, 0.3), (10.0, 0.7), (20.0, 0.3), (20.0, 0.7)]
    assert len({c.case_id for c in cases}) == 4
    # the model depends on data.t_span_past only: two distinct models for four cases
    assert cases[0].model_hash == cases[1].model_hash != cases[2].model_hash == cases[3].model_hash
    # a filter-only change keeps the model; other seeds make another case
    other = make_cases(tiny_raw("filter.add_model_variance=false"), [("data.t_span_past", [10])], range(2))[0]
    assert other.model_hash == cases[0].model_hash and other.case_id != cases[0].case_id
    assert make_cases(tiny_raw(), [("data.t_span_past", [10]), ("scenario.rho_true", [0.3])], range(3))[0].case_id \
        != cases[0].case_id
    # no GPUKF, no model
    assert make_cases(tiny_raw(), [], range(2), estimators=["ukf"])[0].model_hash is None


def test_bad_grid_key_or_value_is_an_error_naming_the_key():
    with pytest.raises(ConfigError, match=r"^data\.t_span_pst: unknown key"):
        make_cases(tiny_raw(), [("data.t_span_pst", [10])], range(1))
    with pytest.raises(ConfigError, match=r"scenario\.rho_true: 1\.7 is outside \(0, 1\].*scenario.rho_true=1.7"):
        make_cases(tiny_raw(), [("scenario.rho_true", [0.3, 1.7])], range(1))
    with pytest.raises(ConfigError, match="estimators: unknown estimator 'ekf'"):
        make_cases(tiny_raw(), [], range(1), estimators=["ekf"])


def test_cli_reports_a_bad_grid_key_and_documents_the_outputs(tmp_path, capsys):
    code = main([str(BOXWING), "--out", str(tmp_path), "--grid", "data.t_span_pst=10,20", "--seeds", "1"])
    assert code == 2
    assert "data.t_span_pst: unknown key" in capsys.readouterr().err
    assert not (tmp_path / "boxwing").exists()  # nothing ran
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for word in ("--grid", "--seeds", "--workers", "results.csv", "summary.csv", "resume", "failed"):
        assert word in text


def test_cli_user_errors_are_one_line_and_exit_2(tmp_path, capsys):
    def error_of(*argv: str) -> str:
        assert main([str(BOXWING), "--out", str(tmp_path), "--seeds", "1", "--no-progress", *argv]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err
        return err.strip()

    assert error_of("--set", "surface.f0=2") == "error: surface.f0: 2 is outside [0, 1]"
    assert error_of("--grid", "data.t_span_past") == ("error: --grid 'data.t_span_past': expected "
                                                      "key.path=value1,value2,...")
    assert error_of("--threads", "0") == "error: --threads: 0 must be >= 1"
    assert error_of("--seeds", "0") == "error: --seeds: 0 must be >= 1"
    missing = tmp_path / "none.yaml"
    assert main([str(missing), "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err == f"error: config file {str(missing)!r} does not exist\n"
    assert not (tmp_path / "boxwing").exists()  # nothing ran


def test_cli_resolves_a_relative_mesh_path_against_the_config_file_and_reports_a_missing_one(tmp_path, capsys):
    folder = tmp_path / "configs"
    folder.mkdir()
    config = folder / "mesh.yaml"
    config.write_text(yaml.safe_dump(apply_overrides(yaml.safe_load(BOXWING.read_text()),
                                                     ["shape.kind=mesh", "shape.mesh_path=shapes/none.obj"])))
    assert main([str(config), "--out", str(tmp_path / "out"), "--seeds", "1", "--no-progress"]) == 2
    expected = str(folder / "shapes" / "none.obj")
    assert capsys.readouterr().err == f"error: shape.mesh_path: {expected!r} does not exist or is not a file\n"
    assert not (tmp_path / "out").exists()


def test_missing_mesh_is_a_config_error_when_hashed():
    raw = tiny_raw("shape.kind=mesh", "shape.mesh_path=/nonexistent/box.obj")
    with pytest.raises(ConfigError) as exc:
        content_hash(config_from_dict(raw), "shape")
    assert str(exc.value) == "shape.mesh_path: '/nonexistent/box.obj' does not exist or is not a file"


def test_cli_ctrl_c_is_one_line_exit_130_and_keeps_finished_cases(tmp_path, capsys, monkeypatch):
    import lightcurve_gp.sweep.cli as sweep_cli

    seen = []
    interrupted_after_one = interrupting_runner(seen)
    monkeypatch.setattr(sweep_cli, "run_sweep",
                        lambda *a, **k: run_sweep(*a, **k, case_runner=interrupted_after_one))
    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump(tiny_raw()))
    code = main([str(config), "--out", str(tmp_path), "--grid", "scenario.rho_true=0.3,0.7", "--seeds", "1",
                 "--estimators", "ukf", "--no-progress"])
    assert code == 130
    out, err = capsys.readouterr()
    cases = tmp_path / "sweeps" / "tiny" / "cases"  # beside the training runs, not in OUT/tiny/
    assert err.startswith(f"interrupted; 1 of 2 cases stored in {cases} (partial tables in "
                          f"{tmp_path / 'sweeps' / 'tiny' / 'sweep'}")
    assert err.endswith("); rerun the same command to resume\n") and err.count("\n") == 1
    assert out.startswith("kept so far: 1 of 2 cases\n") and "written:" not in out
    assert [p.stem for p in cases.glob("*.json")] == seen and not (tmp_path / "tiny").exists()


# ----------------------------------------------------------------------------------------------- tables

@pytest.mark.slow  # trains two GPs and runs four cases
def test_results_table_has_one_row_per_case_seed_estimator_and_summary_agrees(tmp_path):
    axes = [("data.t_span_past", [10, 20]), ("scenario.rho_true", [0.3, 0.7])]
    res = run_sweep(tiny_raw(), axes, range(3), out=tmp_path, sweep_id="s", progress=False)
    columns, rows = read_csv(tmp_path / "tiny" / "sweep" / "s" / "results.csv")
    assert columns == ["case_id", "data.t_span_past", "scenario.rho_true", *RESULT_COLUMNS]
    assert len(rows) == 4 * 3 * 4
    keys = {(r["case_id"], r["seed"], r["estimator"]) for r in rows}
    assert len(keys) == len(rows)
    assert {r["status"] for r in rows} == {"ok"}
    assert {(r["data.t_span_past"], r["scenario.rho_true"]) for r in rows} == {
        ("10", "0.3"), ("10", "0.7"), ("20", "0.3"), ("20", "0.7")}
    # one trained model per distinct t_span_past, and one stored file per case
    assert len(list((tmp_path / "models").glob("*/model.pt"))) == 2
    assert len(list((tmp_path / "tiny" / "cases").glob("*.json"))) == 4
    # no_update never looks at an observation: same RMSE for every case and seed
    nu = {(r["rmse_yaw_deg"], r["rmse_pitch_deg"], r["rmse_roll_deg"]) for r in rows if r["estimator"] == "no_update"}
    assert len(nu) == 1 and all(r["lc_rmse_noisy"] == "" for r in rows if r["estimator"] == "no_update")

    columns, summary = read_csv(tmp_path / "tiny" / "sweep" / "s" / "summary.csv")
    assert columns == ["case_id", "data.t_span_past", "scenario.rho_true", *SUMMARY_COLUMNS]
    assert len(summary) == 4 * 4
    for entry in summary:
        record = json.loads((tmp_path / "tiny" / "cases" / f"{entry['case_id']}.json").read_text())
        est = record["summary"]["estimators"][entry["estimator"]]  # the scenario result's own summary
        for i, axis in enumerate(("yaw", "pitch", "roll")):
            assert float(entry[f"rmse_{axis}_deg_median"]) == est["rmse_deg_median"][i]
            assert float(entry[f"rmse_{axis}_deg_q25"]) == est["rmse_deg_q25"][i]
        assert entry["seeds_ok"] == "3"
    assert json.loads((res.folder / "summary.json").read_text())["complete"] is True


# ----------------------------------------------------------------------------------------------- resume

def test_failing_case_is_recorded_the_others_finish_and_a_rerun_retries_only_it(tmp_path):
    # 30.5 s passes config validation but is not a multiple of dt: simulate_scenario raises at run time
    axes = [("scenario.duration_s", [30, 30.5, 40])]
    est = ["ukf", "no_update"]
    first = run_sweep(tiny_raw(), axes, range(2), out=tmp_path, sweep_id="s", estimators=est, progress=False)
    assert len(first.ran) == 3
    bad = first.record(**{"scenario.duration_s": 30.5})
    assert bad.status == "failed" and "multiple of scenario.dt_s" in bad.error
    assert first.failed == [c.case_id for c in first.cases if c.values["scenario.duration_s"] == 30.5]
    _, rows = read_csv(first.folder / "results.csv")
    assert len(rows) == 3 * 2 * 2
    failed_rows = [r for r in rows if r["scenario.duration_s"] == "30.5"]
    assert len(failed_rows) == 4 and all(r["status"] == "failed" and "multiple" in r["error"] and
                                         r["rmse_yaw_deg"] == "" for r in failed_rows)
    assert all(r["status"] == "ok" and np.isfinite(float(r["rmse_yaw_deg"]))
               for r in rows if r["scenario.duration_s"] != "30.5")
    assert json.loads((first.folder / "summary.json").read_text())["failed_cases"] == first.failed

    stamps = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "tiny" / "cases").glob("*.json")}
    calls = []
    counting = counting_runner(calls, "values")
    again = run_sweep(tiny_raw(), axes, range(2), out=tmp_path, sweep_id="s", estimators=est, progress=False,
                      case_runner=counting)
    assert calls == [{"scenario.duration_s": 30.5}]
    for name, stamp in stamps.items():
        if name != f"{first.failed[0]}.json":
            assert (tmp_path / "tiny" / "cases" / name).stat().st_mtime_ns == stamp
    key = lambda rows: [(r["case_id"], r["seed"], r["estimator"], r["status"], r["rmse_yaw_deg"]) for r in rows]  # noqa
    assert key(again.rows) == key(first.rows)

    calls.clear()
    run_sweep(tiny_raw(), axes, range(2), out=tmp_path, sweep_id="s", estimators=est, progress=False,
              case_runner=counting, rerun_failed=False)
    assert calls == []


def test_interrupt_keeps_finished_cases_and_a_rerun_resumes(tmp_path):
    axes = [("scenario.rho_true", [0.3, 0.5, 0.7])]
    est = ["ukf"]
    seen = []
    interrupted_after_one = interrupting_runner(seen)
    first = run_sweep(tiny_raw(), axes, range(2), out=tmp_path, sweep_id="s", estimators=est, progress=False,
                      case_runner=interrupted_after_one)
    assert first.interrupted and first.ran == seen
    _, rows = read_csv(first.folder / "results.csv")
    assert {r["case_id"] for r in rows} == set(seen)
    assert json.loads((first.folder / "summary.json").read_text())["complete"] is False

    calls = []
    counting = counting_runner(calls, "case_id")
    second = run_sweep(tiny_raw(), axes, range(2), out=tmp_path, sweep_id="s", estimators=est, progress=False,
                       case_runner=counting)
    assert not second.interrupted and len(calls) == 2 and seen[0] not in calls
    _, rows = read_csv(second.folder / "results.csv")
    assert len(rows) == 3 * 2 and {r["status"] for r in rows} == {"ok"}


@pytest.mark.slow  # spawns worker processes
def test_results_are_deterministic_and_parallel_workers_agree(tmp_path):
    axes = [("scenario.rho_true", [0.3, 0.7])]
    est = ["ukf", "matched_ukf"]
    a = run_sweep(tiny_raw(), axes, range(2), out=tmp_path / "a", estimators=est, progress=False)
    b = run_sweep(tiny_raw(), axes, range(2), out=tmp_path / "b", estimators=est, progress=False, workers=2)
    assert len(b.ran) == 2 and not b.failed
    pick = lambda rows: [(r["case_id"], r["seed"], r["estimator"], *(r[m] for m in METRICS)) for r in rows]  # noqa
    assert pick(a.rows) == pick(b.rows)
    # the mismatched UKF differs between the two rho_true, the matched one knows each
    yaw = {(r["scenario.rho_true"], r["estimator"]): r["rmse_yaw_deg"] for r in a.rows if r["seed"] == 0}
    assert yaw[("0.3", "ukf")] != yaw[("0.7", "ukf")]
    assert np.isfinite([r["rmse_yaw_deg"] for r in a.rows]).all()


def test_an_in_process_sweep_leaves_the_callers_thread_count_alone(tmp_path):
    import torch

    before = torch.get_num_threads()
    res = run_sweep(tiny_raw(), [], range(1), out=tmp_path, estimators=["no_update"], threads=before + 1,
                    progress=False)
    assert not res.failed and len(res.ran) == 1
    assert torch.get_num_threads() == before
