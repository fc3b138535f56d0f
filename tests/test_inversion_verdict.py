"""The inversion's verdict: the fit test against closed forms, the box-wing's inversion of a cylinder's light curve
says "no fit" (in the library and through the command), and the widening runs when the first search's fit fails and
not when it fits."""

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.commands.invert import main as invert_main
from lightcurve_gp.config.load import load_config
from lightcurve_gp.inference.answer import Answer, answer, widened_settings
from lightcurve_gp.inference.families import Families
from lightcurve_gp.inference.fit_verdict import P_NO_FIT, fit_test, judged, verdict
from lightcurve_gp.inference.forward import GroupRenderer
from lightcurve_gp.inference.inversion import InversionSettings, rate_starts
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.observed.solutions import read_solutions
from lightcurve_gp.photometry.ambiguity import ambiguity_group
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.photometry.shapes import facets_from_mesh

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "boxwing.yaml"
F64 = torch.float64
T = 120
SIGMA = 0.05
SMALL = InversionSettings(starts=256, attitudes=64, arcs_s=(30.0, 80.0, 0.0), keep=(48, 12))


def test_fit_test_against_the_closed_form_of_two_degrees_of_freedom():
    # chi2 with 2 degrees of freedom: P(X >= x) = exp(-x / 2), and chi2 = 2 cost, so p = exp(-cost)
    for cost in (0.3, 2.0, 9.0):
        test = fit_test(cost, samples=9, parameters=7)
        assert test.dof == 2 and test.chi2 == pytest.approx(2 * cost)
        assert test.p_value == pytest.approx(math.exp(-cost), rel=1e-12)
    edge = -math.log(P_NO_FIT)  # p exactly at the threshold: fits; a little worse: no fit
    assert fit_test(edge * (1 - 1e-9), samples=9).fits and not fit_test(edge * (1 + 1e-6), samples=9).fits
    assert not fit_test(float("nan"), samples=9).fits
    with pytest.raises(ValueError, match="7 samples leave no degree of freedom for 7 parameters"):
        fit_test(1.0, samples=7)


def test_verdict_rule():
    good, bad = fit_test(100.0, samples=207), fit_test(400.0, samples=207)
    assert good.fits and not bad.fits
    assert verdict(good, 0.95) == "unique" and verdict(good, 0.9) == "unique"
    assert verdict(good, 0.89) == "ambiguous"
    assert verdict(bad, 1.0) == "no_fit"  # a misfit is never unique, whatever its weight
    assert verdict(good, 0.99, ridge=True) == "ambiguous"  # nor is a rate its profile does not fix
    assert verdict(bad, 0.99, ridge=True) == "no_fit"
    assert judged(fits=True, top_weight=0.95) == "unique" and judged(fits=False, top_weight=0.95) == "no_fit"


@pytest.fixture(scope="module")
def setup():
    cfg = load_config(CONFIG)
    scene = Scene.from_config(cfg, rho=0.5)
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=F64)
    group = ambiguity_group(scene, times_s=torch.arange(T + 1.0), inertia=inertia, rate_known=False, probes=2)
    g = torch.Generator().manual_seed(0)
    axis = torch.randn(3, generator=g, dtype=F64)
    q0 = random_attitudes(1, seed=5, dtype=F64)[0]
    w0 = math.radians(2.0) * axis / axis.norm()
    q, _ = propagate(q0, w0, inertia, 1.0, T)
    noise = SIGMA * torch.randn(T + 1, generator=g, dtype=F64)
    cylinder = facets_from_mesh(trimesh.creation.cylinder(radius=0.8, height=2.5, sections=24), rho=0.5, f0=0.5,
                                n_u=800.0, n_v=800.0)
    other = Scene(cylinder, scene.sun, scene.observer, scene.r_obs)
    return scene, inertia, group, q, w0, noise, other


def _problem(scene, inertia, y):
    K = y.shape[0]
    return TrajectoryProblem(GroupRenderer(scene), torch.arange(K, dtype=F64), y, torch.full((K,), SIGMA, dtype=F64),
                             inertia, torch.zeros(0, 4, dtype=F64))


@pytest.mark.slow  # ~15 s on two loaded cores
def test_the_box_wing_inversion_of_a_cylinders_light_curve_says_no_fit(setup):
    scene, inertia, group, q, _, noise, cylinder = setup
    y = cylinder.magnitude(q, rho=0.4) + noise
    ans = answer(_problem(scene, inertia, y), group, settings=SMALL)
    assert ans.widened and not ans.first_fit.fits
    assert ans.verdict == "no_fit" and ans.fit.chi2_per_dof > 5.0
    assert ans.words().startswith("no solution fits this light curve after a widened search")
    # a rejected model states no probability of being right; the weights still compare the basins
    assert bool((ans.families.p_right == 0).all()) and float(ans.families.weight.sum()) == pytest.approx(1.0)
    # the widened search's rows joined the first's: twice the continuation's last keep at most, more than the first
    assert ans.inversion.q0.shape[0] > SMALL.keep[-1]


@pytest.mark.slow  # ~35 s on two loaded cores
def test_widening_runs_after_a_failed_first_search_and_not_after_a_good_one(setup):
    scene, inertia, _, _, _, _, _ = setup
    # 200 s: over 120 s a basin at another rate fits as well (within the noise) and no first search fails
    span = 200
    group = ambiguity_group(scene, times_s=torch.arange(span + 1.0), inertia=inertia, rate_known=False, probes=2)
    g = torch.Generator().manual_seed(0)
    axis = torch.randn(3, generator=g, dtype=F64)
    w0 = math.radians(2.0) * axis / axis.norm()
    q, _ = propagate(random_attitudes(1, seed=5, dtype=F64)[0], w0, inertia, 1.0, span)
    y = scene.magnitude(q, rho=0.4) + SIGMA * torch.randn(span + 1, generator=g, dtype=F64)
    problem = _problem(scene, inertia, y)
    # a starved first search: every screened rate a twentieth of the truth's, all from the 30 s arc, so the
    # continuation cannot reach it
    starved = rate_starts([], count=24, rate_range_deg_s=(0.08, 0.1), span_s=span, shell_ratio=2.0)
    bad = answer(problem, group, settings=replace(SMALL, entry_turn_deg=0.0), rate_grid=starved, ridge=False)
    assert not bad.first_fit.fits and bad.widened
    assert bad.fit.fits and bad.verdict in ("unique", "ambiguous")
    assert float(torch.linalg.vector_norm(bad.families.omega0[0])) == pytest.approx(float(w0.norm()), rel=0.02)
    assert "widening" in bad.seconds
    good = answer(problem, group, settings=SMALL, ridge=False)
    assert good.first_fit.fits and not good.widened and "widening" not in good.seconds
    # one basin, but 200 s do not pin the rate to 2 % (1σ ~1.5 % per axis): right with probability ~0.7, not unique
    fam = good.families
    assert float(fam.weight[0]) > 0.99 and 0.5 < float(fam.p_right[0]) < 0.9 and good.verdict == "ambiguous"
    assert "does not pin it within 10 deg and 2 %" in good.words()


def test_widened_settings():
    wide = widened_settings(InversionSettings())
    assert (wide.starts, wide.attitudes, wide.keep, wide.seed) == (20_000, 512, None, 1)
    assert wide.stage_keep() == (5000, 1500, 500, 250)  # the same shares of twice the starts
    counted = widened_settings(InversionSettings(keep=(1000, 300, 100, 50)))
    assert counted.stage_keep() == (2000, 600, 200, 100)  # counts given are doubled
    # the screen grid is starts x screen_factor points: four times the first
    assert wide.starts * wide.screen_factor == 4 * InversionSettings().starts * InversionSettings().screen_factor
    assert wide.shell_ratio == pytest.approx(math.sqrt(1.5))


@pytest.mark.slow  # ~30 s on two loaded cores
def test_invert_says_no_fit_on_a_cylinders_light_curve(setup, tmp_path, capsys):
    _, _, _, q, _, noise, cylinder = setup
    y = (cylinder.magnitude(q, rho=0.4) + noise).numpy()
    path = tmp_path / "cylinder.csv"
    rows = "\n".join(f"{k},{m:.6f},{SIGMA}" for k, m in enumerate(y))
    path.write_text(f"# epoch: 2025-01-01T00:00:00\ntime,mag,mag_err\n{rows}\n")
    out = tmp_path / "runs"
    assert invert_main([str(CONFIG), "--light-curve", str(path), "--starts", "256", "--out", str(out),
                        "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "verdict: no solution fits this light curve after a widened search" in printed
    run = out / "estimates" / "boxwing" / "invert_cylinder"
    summary = json.loads((run / "summary.json").read_text())
    assert summary["verdict"] == "no_fit" and summary["widened"] and not summary["fit"]["fits"]
    assert summary["fit"]["dof"] == T + 1 - 7 and summary["fit"]["p_value"] < P_NO_FIT
    table = read_solutions(run / "solutions.ecsv")
    assert table.meta["verdict"] == "no_fit"
    assert np.all(np.asarray(table["p_right"]) == 0.0) and summary["top_p_right"] == 0.0
    assert np.isclose(table.meta["chi2_per_dof"], summary["fit"]["chi2_per_dof"])


def test_the_verdict_says_when_the_probability_counts_neighbouring_families():
    f64 = lambda v: torch.tensor(v, dtype=F64)  # noqa: E731
    fam = Families(q0=f64([[0.0, 0.0, 0.0, 1.0]] * 2), omega0=f64([[0.0, 0.0, 0.02]] * 2), log_rho=f64([0.0, 0.0]),
                   log_likelihood=f64([-300.0, -300.4]), log_evidence=f64([-310.0, -310.4]), weight=f64([0.6, 0.4]),
                   mass=f64([0.98, 0.98]), p_right=f64([0.95, 0.94]),
                   covariance=torch.eye(7, dtype=F64).expand(2, 7, 7), members=torch.tensor([3, 2]),
                   images=("identity",))
    test = fit_test(300.0, samples=601)
    said = Answer(inversion=None, families=fam, fit=test, verdict=verdict(test, 0.95), widened=False, first_fit=test,
                  ridge=False, rate_interval_deg_s=(1.1459, 1.1459))
    assert said.verdict == "unique"
    assert said.words().startswith("unique: one family carries weight 0.600 and is within 10 deg and 2 % of the truth "
                                   "with probability 0.950 (rates 1.146-1.146 deg/s; the probability counts the "
                                   "other families' mass within that tolerance of it)")
    alone = replace(said, families=replace(fam, p_right=f64([0.588, 0.392])), verdict="ambiguous")
    assert "other families' mass" not in alone.words()
