"""The observations type: what simulations and files both produce and every estimator takes."""

import math

import numpy as np
import pytest
import torch
from astropy.time import TimeDelta
from scipy.stats import chi2

from lightcurve_gp.attitude.metrics import attitude_error_vector, nees
from lightcurve_gp.commands import simulate
from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation.registry import map_solution
from lightcurve_gp.inference.fit_verdict import P_NO_FIT, fit_test, verdict
from lightcurve_gp.observations import CurveInfo, Observations, ObservationsError
from lightcurve_gp.observed.arc_run import estimate_arc
from lightcurve_gp.observed.lightcurve_file import LightCurveFileError, read_light_curve, write_light_curve
from lightcurve_gp.observed.observations_file import read_observations
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario

REALISTIC = "configs/boxwing_realistic.yaml"
#: a 200 s arc keeps each whole-arc MAP to a second or two
SHORT = ["scenario.duration_s=200", "evaluation.rmse_window_s=[100, 200]"]


def one(n=5, **kw):
    return Observations.single(t=np.arange(n, dtype=float), mag=np.full(n, 10.0), sigma=0.1, **kw)


@pytest.mark.parametrize("change, message", [
    ({"mag": torch.zeros(4)}, "mag: expected shape (5,) or (S, 5), got (4,)"),
    ({"sigma": torch.zeros(5)}, "sigma: every 1-sigma must be > 0 mag"),
    ({"t": torch.tensor([0.0, 2.0, 1.0, 3.0, 4.0], dtype=torch.float64)},
     "t: sample times must be finite and non-decreasing"),
    ({"mag": torch.tensor([1.0, math.inf, 1.0, 1.0, 1.0], dtype=torch.float64)},
     "mag: a magnitude is infinite (a missing sample is NaN or left out)"),
    ({"curve": torch.ones(5, dtype=torch.int64)}, "curve: expected int64 indices into the 1 light curves"),
    ({"sun": torch.zeros(5, 3)}, "observer: missing (per-sample geometry needs sun, observer and range_m)"),
])
def test_bad_observations_are_one_line_naming_the_field(change, message):
    base = one()
    fields = {k: getattr(base, k) for k in ("t", "mag", "sigma", "curve", "curves")}
    with pytest.raises(ObservationsError) as err:
        Observations(**{**fields, **change})
    assert str(err.value) == message


def test_combined_light_curves_keep_their_own_curve_and_zero_point_and_interleave_in_time():
    a = Observations.single(t=[0.0, 10.0, 20.0], mag=[1.0, 2.0, 3.0], sigma=0.1, source="a")
    b = Observations.single(t=[0.0, 10.0], mag=[7.0, 8.0], sigma=0.2, source="b", relative=True)
    both = Observations.combine([a, b], offsets_s=[0.0, 5.0])
    assert both.t.tolist() == [0.0, 5.0, 10.0, 15.0, 20.0]
    assert both.mag.tolist() == [1.0, 7.0, 2.0, 8.0, 3.0]
    assert both.curve.tolist() == [0, 1, 0, 1, 0]
    assert both.curves == (CurveInfo("a", False), CurveInfo("b", True))
    assert both.relative.tolist() == [False, True]
    assert both.zero_point_indicator().squeeze(-1).tolist() == [0.0, 1.0, 0.0, 1.0, 0.0]
    later = both.select(both.t >= 12.0)  # light curve b's last sample and a's
    assert later.curves == both.curves and later.curve.tolist() == [1, 0]
    only_a = both.select(both.curve == 0)
    assert only_a.curves == (CurveInfo("a", False),) and only_a.zero_point_indicator() is None


def test_a_file_without_geometry_cannot_join_one_with_it():
    plain = one(source="plain.ecsv")
    seen = Observations.single(t=[0.0, 1.0], mag=[1.0, 1.0], sigma=0.1, sun=[[1.0, 0, 0]] * 2,
                               observer=[[0, 1.0, 0]] * 2, range_m=[1e7] * 2)
    with pytest.raises(ObservationsError) as err:
        Observations.combine([seen, plain])
    assert str(err.value) == ("plain.ecsv: no per-sample geometry while the others have it; give every light curve "
                              "its geometry or none")


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """Seed 4 of the realistic config over 200 s: its scenario and the file simulate writes of it."""
    path = tmp_path_factory.mktemp("obs") / "obs.ecsv"
    sets = [a for o in SHORT for a in ("--set", o)]
    assert simulate.main([REALISTIC, "--out", str(path), "--seed", "4", "--no-progress", *sets]) == 0
    cfg = load_config(REALISTIC, SHORT)
    return cfg, simulate_scenario(cfg, [4]), path


@pytest.mark.slow
def test_a_scenario_and_the_file_simulate_writes_of_it_give_the_same_estimate(simulated):
    cfg, sc, path = simulated
    problem = sc.problem()
    from_scenario = map_solution(cfg, Scene.from_config(cfg), problem)
    omega0 = torch.deg2rad(torch.tensor(cfg.scenario.omega0_deg_s, dtype=torch.float64))
    run = estimate_arc(cfg, read_observations([path]), q0=sc.q_est0[0], sigma0=math.radians(cfg.filter.p0_deg),
                       omega0=omega0)
    assert torch.allclose(run.solution.q0, from_scenario.q0, atol=1e-7)
    assert torch.allclose(run.solution.theta, from_scenario.theta, atol=1e-6)
    assert run.verdict == "unique" and run.p_value > P_NO_FIT


def _two_files(path, tmp_path, shift):
    """Samples 0–99 and 120–200 of ``path`` as two files, 80 random samples of each kept (irregular steps, a gap of
    20 s or more between them), the second ``shift`` mag fainter."""
    lc = read_light_curve(path)
    rng = np.random.default_rng(0)
    first = np.sort(rng.choice(np.arange(100), 80, replace=False))
    second = np.sort(rng.choice(np.arange(120, lc.t.size), 60, replace=False))
    parts = []
    for name, rows, dm in (("a.ecsv", first, 0.0), ("b.ecsv", second, shift)):
        piece = read_light_curve(path)
        piece.start = lc.start + TimeDelta(lc.t[rows[0]], format="sec")
        piece.t, piece.mag, piece.mag_err = lc.t[rows] - lc.t[rows[0]], lc.mag[rows] + dm, lc.mag_err[rows]
        parts.append(write_light_curve(piece, tmp_path / f"{shift}_{name}"))
    return lc, np.concatenate([first, second]), parts


def test_irregular_times_in_two_files_one_relative_recover_its_zero_point(simulated, tmp_path):
    cfg, sc, path = simulated
    omega0 = torch.deg2rad(torch.tensor(cfg.scenario.omega0_deg_s, dtype=torch.float64))
    runs = []
    for shift in (0.0, 0.3):
        lc, rows, parts = _two_files(path, tmp_path, shift)
        obs = read_observations(parts, relative=[False, True])
        assert len(obs) == rows.size and np.allclose(obs.t.numpy(), lc.t[rows], atol=1e-6)
        runs.append(estimate_arc(cfg, obs, q0=sc.q_est0[0], sigma0=math.radians(cfg.filter.p0_deg), omega0=omega0))
    plain, shifted = runs
    # the offset is profiled exactly: shifting a relative light curve moves its offset by the shift, nothing else
    assert abs(float(shifted.offsets[0] - plain.offsets[0]) - 0.3) < 1e-6
    assert torch.allclose(shifted.solution.q0, plain.solution.q0, atol=1e-8)
    assert abs(float(plain.offsets[0])) < 0.1 and plain.verdict == "unique"
    e = attitude_error_vector(sc.q_true[0, rows[-1]], plain.estimate.q_est[0, -1])
    assert float(nees(e, plain.estimate.P[0, -1])) < 16.3  # χ²(3)'s 99.9 % point: the reported 1σ is honest


def test_a_light_curve_the_shape_cannot_make_is_no_fit(simulated, tmp_path):
    cfg, sc, path = simulated
    lc = read_light_curve(path)
    lc.mag = 13.0 + 0.8 * np.sign(np.sin(2 * math.pi * lc.t / 37.0))  # a square wave no box-wing makes at this spin
    lc.mag_err = np.full(lc.t.size, 0.01)
    square = write_light_curve(lc, tmp_path / "square.ecsv")
    omega0 = torch.deg2rad(torch.tensor(cfg.scenario.omega0_deg_s, dtype=torch.float64))
    run = estimate_arc(cfg, read_observations([square]), q0=sc.q_est0[0], sigma0=math.radians(cfg.filter.p0_deg),
                       omega0=omega0)
    assert run.verdict == "no_fit" and run.chi2 / run.dof > 10


def test_the_verdict_follows_the_p_value_then_the_weight():
    fits, fails = fit_test(100.0, samples=207), fit_test(400.0, samples=207)  # ½χ² against ν = 200
    assert fits.p_value == pytest.approx(chi2.sf(200.0, 200)) and fails.p_value < P_NO_FIT
    assert verdict(fits, 0.95) == "unique" and verdict(fits, 0.6) == "ambiguous"
    assert verdict(fails, 1.0) == "no_fit" and verdict(fit_test(math.nan, samples=207), 1.0) == "no_fit"


def test_two_files_at_the_same_instant_are_refused_naming_both(simulated, tmp_path):
    _, _, path = simulated
    lc = read_light_curve(path)
    write_light_curve(lc, tmp_path / "x.ecsv")
    write_light_curve(lc, tmp_path / "y.ecsv")
    with pytest.raises(LightCurveFileError) as err:
        read_observations([tmp_path / "x.ecsv", tmp_path / "y.ecsv"])
    assert str(err.value).startswith(f"{tmp_path / 'x.ecsv'} and {tmp_path / 'y.ecsv'}: two samples at the same "
                                     f"time 0.000000 s after ")


@pytest.mark.slow
def test_a_no_fit_solutions_file_is_warned_about_as_a_start_not_an_answer(simulated, tmp_path, capsys):
    from astropy.table import Table

    from lightcurve_gp.commands.estimate import main as estimate_main

    cfg, sc, path = simulated
    q = sc.q_est0[0].tolist()
    table = Table({"rank": [1], "weight": [1.0], "log_likelihood": [0.0], "log_evidence": [0.0],
                   **{f"q_{a}": [v] for a, v in zip("xyzw", q)},
                   **{f"omega_{a}": [v] for a, v in zip("xyz", cfg.scenario.omega0_deg_s)}, "rho": [0.5],
                   "members": [1], **{f"sigma_att_{a}": [0.01] for a in "xyz"},
                   **{f"sigma_omega_{a}": [1e-4] for a in "xyz"}, "sigma_rho": [0.01]})
    table.meta.update({"verdict": "no_fit", "chi2_per_dof": 12.5})
    solutions = tmp_path / "solutions.ecsv"
    table.write(solutions, format="ascii.ecsv")
    sets = [a for o in SHORT for a in ("--set", o)]
    assert estimate_main([REALISTIC, "--light-curve", str(path), "--solutions", str(solutions), "--out",
                          str(tmp_path / "out"), "--no-progress", *sets]) == 0
    assert (f"warning: {solutions}: the inversion found no solution that fits (chi2/dof 12.50); its best family is a "
            f"start, not an answer\n") in capsys.readouterr().err
