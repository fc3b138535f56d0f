"""The edges a new observer hits, round two (issue 39): the tests from a shell that ignores SIGINT, the command
line's version and usage, units on every table written, warnings for inputs that carry little information, progress
without a terminal, and the estimate table's bands; one regression test per row, asserting the exact message."""

from __future__ import annotations

import importlib
import importlib.metadata
import json
import os
import signal
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from lightcurve_gp.__main__ import import_deferring_interrupts, main, run

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
VERSION = importlib.metadata.version("lightcurve-gp")


def ignore_sigint() -> None:
    """``preexec_fn`` of a child started the way a script starts a background job: SIGINT ignored."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


# 6. the Ctrl-C tests pass from a shell that ignores SIGINT (they restore Python's handler themselves)
@pytest.mark.slow  # ~10 s on two loaded cores: a second pytest imports torch
def test_the_interrupt_tests_pass_when_the_shell_ignores_sigint():
    tests = ["tests/test_safe_runs.py::test_interrupt_reaches_the_command_during_a_blocking_call",
             "tests/test_safe_runs.py::test_interrupt_taken_inside_a_finaliser_still_reaches_the_command",
             "tests/test_entry_points.py::test_an_interrupt_during_a_command_s_import_is_answered_once_the_import_is_done"]
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *tests],
                          capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=300, preexec_fn=ignore_sigint)
    assert done.returncode == 0, done.stdout[-2000:]
    assert "3 passed" in done.stdout


def test_an_ignored_sigint_stays_ignored_while_a_command_loads(monkeypatch):
    """A background job's command is not interrupted by a Ctrl-C meant for the terminal's foreground job."""
    def signalled_import(name):
        os.kill(os.getpid(), signal.SIGINT)
        return types.SimpleNamespace(name=name)

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        monkeypatch.setattr(importlib, "import_module", signalled_import)
        assert import_deferring_interrupts("lightcurve_gp.commands.train").name == "lightcurve_gp.commands.train"
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)


# 11. a version, and each command's usage in the form it was called
@pytest.mark.parametrize("flag", ["--version", "-V"])
def test_the_entry_point_has_a_version(capsys, flag):
    assert main([flag]) == 0
    assert capsys.readouterr().out == f"lightcurve-gp {VERSION}\n"
    assert main([flag], prog="python -m lightcurve_gp") == 0
    assert capsys.readouterr().out == f"python -m lightcurve_gp {VERSION}\n"


def test_every_command_has_a_version_in_its_own_name(capsys):
    for name in ("train", "estimate", "simulate", "invert", "sweep"):
        with pytest.raises(SystemExit) as stop:
            main([name, "--version"])
        assert stop.value.code == 0
        assert capsys.readouterr().out == f"lightcurve-gp {name} {VERSION}\n"


def test_the_console_script_shows_the_name_it_was_started_as(capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["/somewhere/bin/lightcurve-gp", "train", "--help"])
    with pytest.raises(SystemExit) as stop:
        run()
    assert stop.value.code == 0
    assert capsys.readouterr().out.startswith("usage: lightcurve-gp train [-h] [--set KEY.PATH=VALUE]")


def test_usage_names_the_form_it_was_called_in(capsys):
    assert main([], prog="python -m lightcurve_gp") == 2
    out = capsys.readouterr().out.splitlines()
    assert out[:2] == ["usage: python -m lightcurve_gp COMMAND [options]", "       python -m lightcurve_gp --version"]
    assert out[-1] == "python -m lightcurve_gp COMMAND --help lists the options of COMMAND."
    with pytest.raises(SystemExit):
        main(["estimate", "--help"], prog="python -m lightcurve_gp")
    assert capsys.readouterr().out.startswith("usage: python -m lightcurve_gp estimate [-h]")


@pytest.mark.parametrize("args, first", [
    (["-m", "lightcurve_gp", "--version"], f"python -m lightcurve_gp {VERSION}"),  # imports no torch: fast
])
def test_python_dash_m_says_so_in_its_version(args, first):
    done = subprocess.run([sys.executable, *args], capture_output=True, text=True, env=ENV, timeout=60)
    assert (done.returncode, done.stdout, done.stderr) == (0, first + "\n", "")


@pytest.mark.slow  # ~8 s on two loaded cores: the shim imports torch
def test_the_per_command_module_shows_its_own_form():
    done = subprocess.run([sys.executable, "-m", "lightcurve_gp.train", "--help"], capture_output=True, text=True,
                          env=ENV, timeout=120)
    assert done.returncode == 0
    assert done.stdout.startswith("usage: python -m lightcurve_gp.train [-h] [--set KEY.PATH=VALUE]")


# 8. every column of every table written has its unit; the truth's rates in deg/s like the rest
BOXWING = str(ROOT / "configs" / "boxwing.yaml")
TINY = ["data.icosphere_subdivisions=0", "data.phi_step_deg=120", "data.heldout_size=40", "scenario.duration_s=60",
        "evaluation.rmse_window_s=[30, 60]", "model.exact.fast_variance_neighbors=32", "name=tiny"]


def as_sets(overrides):
    return [a for o in overrides for a in ("--set", o)]


def units_of(table) -> dict[str, str | None]:
    """Each column's unit as ECSV writes it (``None``: no unit, a text column)."""
    return {name: None if table[name].unit is None else table[name].unit.to_string() for name in table.colnames}


@pytest.fixture(scope="module")
def observed(tmp_path_factory) -> Path:
    from lightcurve_gp.commands import simulate

    folder = tmp_path_factory.mktemp("obs")
    assert simulate.main([BOXWING, "--out", str(folder / "obs.ecsv"), "--seed", "2", "--no-progress",
                          *as_sets(TINY)]) == 0
    return folder / "obs.ecsv"


def test_the_truth_sidecar_gives_its_rates_in_deg_per_s_with_units(observed):
    from astropy.table import Table

    truth = Table.read(observed.with_name("obs.truth.ecsv"), format="ascii.ecsv")
    assert units_of(truth) == {"time": None, "q1": "", "q2": "", "q3": "", "q4": "", "omega_x": "deg / s",
                               "omega_y": "deg / s", "omega_z": "deg / s", "mag_clean": "mag"}
    assert truth["time"].description == "ISO 8601 UTC"
    # the config's scenario.omega0_deg_s is the body rate at the first sample
    assert [float(truth[f"omega_{a}"][0]) for a in "xyz"] == pytest.approx([0.1, -0.1, -0.25], rel=1e-12)


@pytest.mark.parametrize("time_format, unit, description", [
    ("iso", None, "ISO 8601 UTC"), ("mjd", "d", "MJD (UTC)"), ("seconds", "s", "seconds from the epoch (metadata)")])
def test_light_curve_files_carry_units(tmp_path, observed, time_format, unit, description):
    from astropy.table import Table

    from lightcurve_gp.observed.lightcurve_file import read_light_curve, write_light_curve

    lc = read_light_curve(observed)
    path = write_light_curve(lc, tmp_path / "again.ecsv", time_format=time_format)
    table = Table.read(path, format="ascii.ecsv")
    assert units_of(table) == {"time": unit, "mag": "mag", "mag_err": "mag"}
    assert table["time"].description == description
    again = read_light_curve(path)  # the reader takes the file with units
    assert np.array_equal(again.mag, lc.mag) and np.allclose(again.t, lc.t, rtol=0, atol=1e-6)


def test_a_column_written_without_a_unit_is_refused():
    from astropy.table import Table

    from lightcurve_gp.observed.table_units import set_units

    with pytest.raises(ValueError) as err:
        set_units(Table({"a": [1.0], "b": [2.0]}), {"a": "deg"})
    assert str(err.value) == "column b: written without a unit (say '' for a dimensionless one)"
    with pytest.raises(ValueError) as err:
        set_units(Table({"time": ["2026-12-06T00:00:00"]}), {})
    assert str(err.value) == "column time: a text column written without a description"


def test_the_solutions_file_has_a_unit_on_every_column(tmp_path):
    import math

    import torch
    from astropy.table import Table

    from lightcurve_gp.inference.families import Families
    from lightcurve_gp.observed.solutions import (
        COLUMNS,
        OPTIONAL_COLUMNS,
        read_solutions,
        solutions_table,
        write_solutions,
    )

    f64 = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    fam = Families(q0=f64([[0.0, 0.0, 0.0, 1.0]]), omega0=torch.deg2rad(f64([[0.1, -0.1, -0.25]])),
                   log_rho=f64([math.log(0.5)]), log_likelihood=f64([10.0]), log_evidence=f64([1.0]),
                   weight=f64([1.0]), mass=f64([1.0]), p_right=f64([1.0]),
                   covariance=torch.diag_embed(torch.full((1, 7), 1e-4, dtype=torch.float64)),
                   members=torch.tensor([3]), images=("body identity · inertial identity",))
    write_solutions(solutions_table(fam), tmp_path / "solutions.ecsv")
    units = units_of(Table.read(tmp_path / "solutions.ecsv", format="ascii.ecsv"))
    rates = {f"{p}omega_{a}" for p in ("", "sigma_") for a in "xyz"}
    assert units == {c: "deg / s" if c in rates else "deg" if c.startswith("sigma_att") else ""
                     for c in COLUMNS + OPTIONAL_COLUMNS}
    assert float(read_solutions(tmp_path / "solutions.ecsv")["omega_z"][0]) == pytest.approx(-0.25, rel=1e-12)


# 9. a non-unit initial attitude is an error; a flat light curve and a coarse bank are warned about in words
def test_a_non_unit_initial_attitude_is_refused_with_its_norm():
    from lightcurve_gp.commands.common import UserError
    from lightcurve_gp.commands.estimate_file import parse_quaternion

    with pytest.raises(UserError) as err:
        parse_quaternion("1,2,3,4")
    assert str(err.value) == ("--initial-attitude: 1,2,3,4 has norm 5.47723, not 1 (a unit quaternion q1,q2,q3,q4, "
                              "scalar last, within 0.001); divide by its norm if that is the attitude meant")
    # a copied value rounded to four decimals passes (norm 1.000018), and is used as given
    q = parse_quaternion("-0.0830,0.0509,-0.0830,0.9918")
    assert q.tolist() == [-0.0830, 0.0509, -0.0830, 0.9918]


def light_curve(mag, mag_err=None):
    from astropy.time import Time

    from lightcurve_gp.observed.lightcurve_file import LightCurve

    mag = np.asarray(mag, dtype=np.float64)
    return LightCurve(start=Time("2026-12-06T00:00:00", scale="utc"), t=np.arange(mag.size, dtype=np.float64),
                      mag=mag, mag_err=None if mag_err is None else np.full(mag.size, mag_err), source="flat.ecsv")


def test_a_flat_light_curve_is_warned_about():
    from lightcurve_gp.observed.information import flat_light_curve

    flat = 10.0 + 0.05 * (-1.0) ** np.arange(100)  # mean 10, every sample 0.5 sigma off: chi-square 25
    assert flat_light_curve(light_curve(flat, 0.1), noise_std=0.7) == (
        "flat.ecsv: flat within its noise (peak to peak 0.1 mag, RMS about the mean 0.05 mag, noise 0.1 mag "
        "from its mag_err; chi-square 25.0 for 99 degrees of freedom, no more than noise alone gives): it carries "
        "little information on the attitude, and the estimate will stay near its start")
    # without mag_err the run's assumed noise is the yardstick
    assert "noise 0.25 mag from the noise the run assumes; chi-square 4.0 for 99" in \
        flat_light_curve(light_curve(flat), noise_std=0.25)
    # a 1-mag variation under 0.1 mag of noise is information; so is an amplitude of 1.5 sigma over 1000 samples
    assert flat_light_curve(light_curve(10.0 + 0.15 * np.sin(np.arange(1000) / 7), 0.1), noise_std=0.7) is None
    t = np.arange(100)
    assert flat_light_curve(light_curve(10.0 + np.sin(2 * np.pi * t / 25), 0.1), noise_std=0.7) is None
    # the same variation under 2 mag of noise is not (chi-square 100 * 0.5 / 4 = 12.4 < 99)
    assert flat_light_curve(light_curve(10.0 + np.sin(2 * np.pi * t / 25), 2.0), noise_std=0.7) is not None


def test_the_bank_coverage_is_the_distance_to_the_nearest_start():
    import torch

    from lightcurve_gp.attitude.rotations import attitude_matrix
    from lightcurve_gp.attitude.sampling import random_attitudes
    from lightcurve_gp.filters.bank import bank_attitudes
    from lightcurve_gp.observed.verdict import COVERAGE_PROBES, COVERAGE_SEED, bank_coverage

    starts = bank_attitudes(16)
    cover = bank_coverage(starts, p0_deg=10.0)
    # independently: the rotation angle from the trace of A(p) A(q)^T
    probes = random_attitudes(COVERAGE_PROBES, COVERAGE_SEED, dtype=torch.float64)
    rel = attitude_matrix(probes)[:, None] @ attitude_matrix(starts)[None].mT
    angle = torch.rad2deg(torch.acos(((rel.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)))
    assert cover.nearest_deg == pytest.approx(float(torch.quantile(angle.amin(1), 0.95)), abs=1e-6)
    assert cover.reach_deg == pytest.approx(10.0 * chi2_99_3() ** 0.5, rel=1e-12)
    assert not cover.adequate and cover.suggested_size == 256
    assert bank_coverage(bank_attitudes(256), p0_deg=10.0).adequate
    assert not bank_coverage(bank_attitudes(128), p0_deg=10.0).adequate
    assert bank_coverage(bank_attitudes(128), p0_deg=15.0).adequate  # a wider prior reaches farther


def chi2_99_3() -> float:
    from scipy.stats import chi2

    return float(chi2.ppf(0.99, 3))


def test_a_coarse_bank_cannot_say_unique():
    import torch

    from lightcurve_gp.filters.bank import BankResult, bank_attitudes
    from lightcurve_gp.filters.state import FilterHistory
    from lightcurve_gp.observed.verdict import bank_coverage, bank_verdict
    from lightcurve_gp.photometry.ambiguity import AmbiguityGroup

    starts = bank_attitudes(16)
    w = torch.full((16,), 1e-6, dtype=torch.float64)
    w[3] = 1.0 - 15e-6
    history = FilterHistory.__new__(FilterHistory)
    history.q_est = starts.unsqueeze(1)
    bank = BankResult(q0=starts, log_likelihood=w.log(), weights=w, order=torch.argsort(w, descending=True),
                      kept=history, bank_history=history, seconds=0.0, kept_seconds=0.0)
    identity = torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=torch.float64)
    group = AmbiguityGroup(body=identity, inertial=identity, labels=("identity",), rate_known=True)
    assert bank_verdict(bank, group).verdict == "unique"  # without the coverage: the old answer
    verdict = bank_verdict(bank, group, p0_deg=10.0)
    assert verdict.verdict == "inconclusive"
    nearest = bank_coverage(starts, p0_deg=10.0).nearest_deg
    assert verdict.sentences(16)[1:] == [
        f"warning: a bank of 16 filters is too coarse to claim a unique answer: 5 % of attitudes lie more than "
        f"{nearest:.1f} deg from every member's start, beyond the 33.7 deg a member's prior reaches (filter.p0_deg); "
        f"use --bank-size 256 or more",
        "verdict: inconclusive (the top family holds the weight of a unique answer, but a bank this coarse may have "
        "started no member near the other answers)"]
    assert verdict.as_dict()["coverage"] == {"size": 16, "nearest_member_deg_95": nearest,
                                             "prior_reach_deg_99": pytest.approx(33.68214175218728, rel=1e-12),
                                             "adequate": False}


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    from lightcurve_gp.commands import train

    out = tmp_path_factory.mktemp("runs")
    assert train.main([BOXWING, "--out", str(out), "--no-progress", *as_sets(TINY)]) == 0
    return out / "tiny" / "model.pt"


def test_a_flat_file_a_bad_start_and_a_coarse_bank_on_the_command_line(tmp_path, capsys, model_file, observed):
    import dataclasses

    from astropy.table import Table

    from lightcurve_gp.commands import estimate
    from lightcurve_gp.observed.lightcurve_file import read_light_curve, write_light_curve

    lc = read_light_curve(observed)
    flat_mag = 8.0 + 0.005 * np.random.default_rng(0).standard_normal(lc.mag.size)  # half its mag_err
    flat = write_light_curve(dataclasses.replace(lc, mag=flat_mag, mag_err=np.full(lc.mag.size, 0.01)),
                             tmp_path / "flat.ecsv")
    base = [BOXWING, "--no-progress", *as_sets(TINY), "--model", str(model_file), "--out", str(tmp_path / "out")]
    assert estimate.main([*base, "--light-curve", str(flat), "--initial-attitude=1,2,3,4"]) == 2
    assert capsys.readouterr().err == ("error: --initial-attitude: 1,2,3,4 has norm 5.47723, not 1 (a unit "
                                       "quaternion q1,q2,q3,q4, scalar last, within 0.001); divide by its norm if "
                                       "that is the attitude meant\n")
    assert not (tmp_path / "out").exists()
    assert estimate.main([*base, "--light-curve", str(flat), "--estimators", "gpukf", "--bank-size", "16",
                          "--bank-keep", "2"]) == 0
    captured = capsys.readouterr()
    assert captured.err.startswith(f"warning: {flat}: flat within its noise (peak to peak ")
    assert "warning: a bank of 16 filters is too coarse to claim a unique answer" in captured.out
    assert "verdict: unique" not in captured.out
    folder = tmp_path / "out" / "estimates" / "tiny" / "light_curve_flat"
    assert json.loads((folder / "summary.json").read_text())["verdict"] in ("ambiguous", "inconclusive")
    # 8. the history and the bank members carry their units
    history = Table.read(folder / "attitude_history.ecsv", format="ascii.ecsv")
    units = units_of(history)
    assert units["time"] is None and units["t_s"] == "s" and units["nis"] == ""
    assert all(units[c] == "" for c in ("q1", "q2", "q3", "q4"))
    assert all(units[c] == "deg" for c in history.colnames if c.endswith("_deg"))
    assert all(units[c] == "mag" for c in ("mag_obs", "mag_pred", "mag_pred_sigma", "innovation"))
    assert set(units) == {"time", "t_s", "q1", "q2", "q3", "q4", "yaw_deg", "pitch_deg", "roll_deg", "sigma_x_deg",
                          "sigma_y_deg", "sigma_z_deg", "sigma_yaw_deg", "sigma_pitch_deg", "sigma_roll_deg",
                          "mag_obs", "mag_pred", "mag_pred_sigma", "innovation", "nis"}
    bank = Table.read(folder / "bank.ecsv", format="ascii.ecsv")
    assert units_of(bank) == {c: "" for c in ("rank", "member", "q0_1", "q0_2", "q0_3", "q0_4", "log_likelihood",
                                              "weight")}
    assert bank["log_likelihood"].description == "nats"


# 10. progress as plain lines, with the time left where tqdm knows it, when stderr is a file or pipe
@pytest.mark.parametrize("bar, line", [
    ("estimators:  50%|#####     | 2/4 [01:03<01:03, 31.50s/filter]",
     "estimators: 50% 2/4 01:03 elapsed, about 01:03 left, 31.50s/filter"),
    ("estimators:   0%|          | 0/4 [00:00<?, ?filter/s]", "estimators: 0% 0/4 00:00 elapsed"),
    ("cases: 3it [00:10, 3.20it/s]", "cases: 3it 00:10 elapsed, 3.20it/s"),
    ("fitting the exact GP: 02:31", "fitting the exact GP: 02:31"),
    ("          ", ""),
])
def test_a_bar_becomes_a_plain_line(bar, line):
    from lightcurve_gp.commands.progress import progress_line

    assert progress_line(bar) == line


def test_bars_to_a_file_are_lines_at_an_interval(monkeypatch):
    import io

    from tqdm import tqdm

    from lightcurve_gp.commands.progress import ProgressLines

    now = [0.0]
    monkeypatch.setattr("tqdm.std.time", lambda: now[0])  # tqdm's own clock: its elapsed and remaining times
    out = io.StringIO()
    lines = ProgressLines(out, interval=10.0, clock=lambda: now[0])
    outer = tqdm(total=4, desc="estimators", unit="filter", file=lines, mininterval=0,
                 bar_format="{desc}: {percentage:.0f}%|{bar}| {n}/{total} [{elapsed}<{remaining}]")
    for step in range(4):
        status = tqdm(desc=f"running {step}", bar_format="{desc}: {elapsed}", file=lines, leave=False, position=1)
        for _ in range(30):  # redrawn every second: one line at its start and one every 10 s
            now[0] += 1.0
            status.refresh()
        status.close()
        outer.update(1)
    outer.close()
    print("error: something", file=lines)
    lines = []
    for step, left in enumerate(["01:30", "01:00", "00:30", "00:00"]):
        lines += [f"running {step}: 00:{s}0" for s in range(4)]
        lines.append(f"estimators: {25 * (step + 1)}% {step + 1}/4 0{(step + 1) // 2}:{30 * ((step + 1) % 2):02d} "
                     f"elapsed, about {left} left")
    assert out.getvalue().splitlines() == ["estimators: 0% 0/4 00:00 elapsed", *lines, "error: something"]


@pytest.mark.slow
def test_a_command_with_stderr_in_a_file_writes_progress_lines(tmp_path, monkeypatch, capsys):
    from lightcurve_gp.commands import estimate

    log = tmp_path / "stderr.txt"
    with open(log, "w") as fh:
        monkeypatch.setattr(sys, "stderr", fh)
        code = estimate.main([BOXWING, *as_sets(TINY), "--seeds", "2", "--estimators", "no_update", "--out",
                              str(tmp_path / "out")])
        monkeypatch.undo()
    assert code == 0
    lines = log.read_text().splitlines()
    assert "\r" not in log.read_text() and lines[0] == "estimators: 0% 0/1 00:00 elapsed"
    assert lines[1].startswith("running no_update: 00:0") and lines[-1].startswith("estimators: 100% 1/1 00:0")
    assert "about 00:00 left" in lines[-1]
    # 13. results.json says where the NEES mean lies against the band of a mean (no NEES without updates: "-")
    results = json.loads((tmp_path / "out" / "estimates" / "tiny" / "rho0.5" / "results.json").read_text())
    assert results["estimators"]["no_update"]["nees_mean_against_band_95"] == "-"
    capsys.readouterr()
    assert estimate.main([BOXWING, *as_sets(TINY), "--seeds", "2", "--estimators", "no_update", "--out",
                          str(tmp_path / "out2")]) == 0
    assert capsys.readouterr().err == ""  # an in-memory stderr gets none


# 13. the estimate table says which NEES band applies to what, and why RMSE/CRB can be below 1
def test_the_estimate_table_puts_the_mean_against_the_band_of_a_mean():
    from scipy.stats import chi2

    from lightcurve_gp.commands.estimate import format_table

    seeds = 20
    lo, hi = chi2.ppf(0.025, 3 * seeds) / seeds, chi2.ppf(0.975, 3 * seeds) / seeds  # 2.02-4.16
    gpukf = {"rmse_deg_median": [3.0, 2.0, 4.0], "rmse_deg_q25": [2.5, 1.5, 3.5], "rmse_deg_q75": [3.5, 2.5, 4.5],
             "fraction_all_axes_below_10deg": 1.0, "lc_rmse_noisy_median": 0.72, "nees_mean": 1.0,
             "nees_median": 0.95, "share_nees_in_band": 1.0, "seconds_per_step": 0.02,
             "seconds_per_filter_step": 0.001, "crb_deg_median": [5.0, 3.4, 6.6], "rmse_over_crb": [0.6, 0.6, 0.6]}
    table = format_table({"rho_true": 0.7, "seeds": seeds, "window_s": [400, 600], "nees_band_95": [lo, hi],
                          "estimators": {"gpukf": gpukf}}).splitlines()
    assert table[4] == ("               CRB yaw / pitch / roll   median RMSE/CRB  NEES mean  mean's band 2.02-4.16  "
                        "median seeds in 0.22-9.35")
    assert table[5] == ("gpukf              5.00 / 3.40 / 6.60   0.6 / 0.6 / 0.6       1.00                  below    "
                        "0.95               100%")
    assert ("  NEES bands (95 %, consistent filter): of the mean over these 20 seeds 2.02-4.16; of one seed "
            "0.22-9.35. Paper: 0.83-0.88 s per GPUKF step, 0.003-0.007 s per UKF step") in table
    assert any(line.startswith("  median RMSE/CRB: the median over the seeds of the RMSE over the median CRB") and
               "not a broken bound" in line for line in table)
    assert "in band" not in "\n".join(table)  # no unqualified band


def test_every_sweep_column_has_a_unit():
    from lightcurve_gp.evaluation.reporting import RESULT_COLUMNS
    from lightcurve_gp.sweep.tables import SUMMARY_COLUMNS, column_unit, table_units

    units = table_units(["case_id", "scenario.noise_var"])
    assert set(units["results.csv"]) == {"case_id", "scenario.noise_var", *RESULT_COLUMNS}
    assert set(units["summary.csv"]) == {"case_id", "scenario.noise_var", *SUMMARY_COLUMNS}
    expected = {"rmse_yaw_deg": "deg", "crb_roll_deg_q75": "deg", "omega_error_final_mod_symmetry_deg_s": "deg / s",
                "lc_rmse_noisy_median": "mag", "seconds_per_step": "s", "nees_median": "", "share_nees_in_band": "",
                "rmse_over_crb_pitch": "", "seed": "", "case_id": None, "scenario.noise_var": None, "error": None}
    merged = {**units["results.csv"], **units["summary.csv"]}
    assert {c: merged[c] for c in expected} == expected
    with pytest.raises(ValueError) as err:
        column_unit("new_metric")
    assert str(err.value) == "column new_metric: no unit known"


@pytest.mark.parametrize("value, where", [(1.0, "below"), (2.02, "inside"), (4.16, "inside"), (4.2, "above"),
                                          (float("nan"), "-")])
def test_against_band(value, where):
    from lightcurve_gp.commands.estimate import against_band

    assert against_band(value, 2.02, 4.16) == where
