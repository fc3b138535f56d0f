"""``invert`` with a ``convex:`` config section on a small synthetic DAMIT file: it finds the simulated spin and
writes its tables and figures; a file that is not DAMIT and a malformed one are one-line errors (exit code 2)."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from astropy.table import Table
from scipy.spatial import ConvexHull

from lightcurve_gp.commands.invert import main as invert_main
from lightcurve_gp.observations.observations import CurveInfo, Observations
from lightcurve_gp.observed.damit import write_damit
from lightcurve_gp.photometry.convex import Scattering, body_vectors, brightness, phase_angle, pole_vector

ROOT = Path(__file__).resolve().parents[1]
CONFIG = str(ROOT / "configs" / "convex.yaml")
SMALL = ["--set", "convex.coarse_poles=12", "--set", "convex.poles=60", "--set", "convex.starts=2",
         "--set", "convex.normals=60", "--set", "convex.polish_iterations=40", "--set", "convex.top_periods=4",
         "--set", "convex.screen_normals=40", "--set", "convex.window=0.1"]
TRUTH = {"lam": 40.0, "beta": 35.0, "period_h": 6.3}


@pytest.fixture(scope="module")
def damit_file(tmp_path_factory) -> Path:
    """The hull of 40 random points on a 3 : 2 : 1.5 ellipsoid (no symmetry) seen in 12 relative curves of 7 h
    (four nights in each of three apparitions a year apart), noiseless."""
    g = torch.Generator().manual_seed(5)
    f64 = torch.float64
    points = np.random.default_rng(5).standard_normal((40, 3))
    points = points / np.linalg.norm(points, axis=1, keepdims=True) * [3.0, 2.0, 1.5]
    hull = ConvexHull(points)
    tri = points[hull.simplices]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    outward = np.sign(((tri.mean(1) - points.mean(0)) * cross).sum(1))
    normals = torch.as_tensor(cross * outward[:, None] / np.linalg.norm(cross, axis=1, keepdims=True))
    areas = torch.as_tensor(0.5 * np.linalg.norm(cross, axis=1))[None]
    t, sun, obs, curve = [], [], [], []
    for c in range(12):
        start = 86400.0 * (365.0 * (c // 4) + (0.0, 1.0, 2.0, 4.0)[c % 4])
        t.append(start + torch.linspace(0.0, 7 * 3600.0, 30, dtype=f64))
        lon = math.radians(100.0 * (c // 4) + 2.0 * (c % 4))
        s = torch.tensor([math.cos(lon), math.sin(lon), 0.1], dtype=f64)
        s = s / s.norm()
        o = s + 0.15 * torch.randn(3, generator=g, dtype=f64)
        sun.append(s.expand(30, 3))
        obs.append((o / o.norm()).expand(30, 3))
        curve.append(torch.full((30,), c))
    t, sun, obs, curve = torch.cat(t), torch.cat(sun), torch.cat(obs), torch.cat(curve)
    t = t - t[0]
    spin = dict(lam=torch.tensor([math.radians(TRUTH["lam"])], dtype=f64),
                beta=torch.tensor([math.radians(TRUTH["beta"])], dtype=f64),
                period_s=torch.tensor([TRUTH["period_h"] * 3600.0], dtype=f64), phi0=torch.zeros(1, dtype=f64),
                t_s=t)
    L = brightness(areas, normals, body_vectors(sun, **spin), body_vectors(obs, **spin), phase_angle(sun, obs),
                   Scattering())[0]
    data = Observations(t=t, mag=-2.5 * torch.log10(L), sigma=torch.full_like(t, 0.01), curve=curve,
                        curves=tuple(CurveInfo(f"c{c}", True) for c in range(12)), sun=sun, observer=obs,
                        range_m=torch.full_like(t, 1.5e11), sun_range_m=torch.full_like(t, 3e11),
                        epoch="2001-01-01T00:00:00")
    return write_damit(data, tmp_path_factory.mktemp("convex") / "box_lcs")


@pytest.mark.slow  # ~6 s on two loaded cores (the figures included)
def test_convex_invert_finds_the_spin_and_writes_its_files(damit_file, tmp_path, capsys):
    assert invert_main([CONFIG, "--light-curve", str(damit_file), "--out", str(tmp_path), "--no-progress",
                        *SMALL]) == 0
    printed = capsys.readouterr().out
    assert "family 1: pole" in printed and "time: periodogram" in printed
    folder = tmp_path / "estimates" / "convex" / "invert_box_lcs"
    table = Table.read(folder / "solutions.ecsv")
    best = table[0]
    assert bool(best["within_ratio"]) and float(best["weight"]) > 0
    assert np.all(np.abs(np.asarray(table["pole_beta_deg"])) <= 90.0)             # written folded, with its phase
    assert set(np.asarray(table["phase0_deg"]).tolist()) <= {0.0, 180.0}
    truth = pole_vector(torch.tensor(math.radians(TRUTH["lam"])), torch.tensor(math.radians(TRUTH["beta"])))
    mirror = pole_vector(torch.tensor(math.radians(TRUTH["lam"] + 180)), torch.tensor(math.radians(TRUTH["beta"])))
    found = pole_vector(torch.tensor(math.radians(float(best["pole_lambda_deg"]))),
                        torch.tensor(math.radians(float(best["pole_beta_deg"]))))
    # three apparitions near opposition fix the period, not the pole to a few degrees (the Ariadne test does that)
    assert max(float(found @ truth), float(found @ mirror)) > math.cos(math.radians(30.0))
    span_h = 2 * 365 * 24 + 4 * 24
    assert abs(float(best["period_h"]) - TRUTH["period_h"]) < 0.5 * TRUTH["period_h"] ** 2 / span_h
    assert float(best["rms"]) < 0.015                                   # 60 normals for a 76-face body: not exact
    areas = Table.read(folder / "areas.ecsv")
    assert len(areas) == 60 and abs(float(areas["area_1"].sum()) - 1.0) < 1e-9
    summary = json.loads((folder / "summary.json").read_text())
    assert set(summary["seconds"]) == {"periodogram", "coarse", "fine", "polish", "total"}
    for name in ("periodogram.png", "light_curves.png", "shape.png"):
        assert (folder / name).stat().st_size > 0


def test_convex_invert_refuses_a_table_file_and_a_malformed_one(tmp_path, capsys):
    table = tmp_path / "lc.ecsv"
    table.write_text("# %ECSV 1.0\n")
    assert invert_main([CONFIG, "--light-curve", str(table), "--out", str(tmp_path), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"error: {table}: convex inversion (the config's convex: section) reads DAMIT light-curve files "
                   "(first line: the number of light curves; see lightcurve_gp.observed.damit)")
    bad = tmp_path / "bad_lcs"
    bad.write_text("1\n2 0\n2450000.5 1.0 1 0 0 0 1 0\n2450000.6 -1.0 1 0 0 0 1 0\n")
    assert invert_main([CONFIG, "--light-curve", str(bad), "--out", str(tmp_path), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: {bad}: line 4: brightness -1 must be > 0 (an intensity, not a magnitude)"
    assert not (tmp_path / "estimates").exists()
