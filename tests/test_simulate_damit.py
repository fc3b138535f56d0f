"""``simulate --format damit``: a pass written as a DAMIT/convexinv file (ecliptic J2000 vectors, intensities) that
``invert configs/convex.yaml --light-curve FILE`` reads back and inverts; the refusals are one line (exit code 2)."""

import math
from pathlib import Path

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import ICRS, BarycentricMeanEcliptic, CartesianRepresentation
from astropy.table import Table
from astropy.time import Time

from lightcurve_gp.commands import simulate
from lightcurve_gp.commands.invert import main as invert_main
from lightcurve_gp.observed.damit import AU_M, equatorial_to_ecliptic, is_damit_file, read_damit

ROOT = Path(__file__).resolve().parents[1]
GEO = str(ROOT / "configs" / "geo_night.yaml")
CONVEX = str(ROOT / "configs" / "convex.yaml")
SHORT = ["--set", "scenario.duration_s=7200", "--set", "evaluation.rmse_window_s=[0,7200]", "--set", "scenario.dt_s=20",
         "--set", "scenario.noise_var=0.0025"]
SMALL = ["--set", "convex.period_range_h=[0.2,1.0]", "--set", "convex.coarse_poles=12", "--set", "convex.poles=40",
         "--set", "convex.starts=2", "--set", "convex.normals=40", "--set", "convex.polish_iterations=10",
         "--set", "convex.top_periods=2", "--set", "convex.screen_normals=30", "--set", "convex.coarse_normals=20",
         "--set", "convex.law=ashikhmin_shirley", "--set", "convex.lobe_exponents=[50]",
         "--set", "convex.ring_normals=24"]


@pytest.fixture(scope="module")
def damit_file(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "geo_lcs"
    assert simulate.main([GEO, "--out", str(out), "--format", "damit", "--seed", "3", "--no-progress", *SHORT]) == 0
    return out


def test_damit_file_holds_the_pass_in_the_ecliptic_frame(damit_file):
    assert is_damit_file(damit_file)
    truth = Table.read(damit_file.with_name("geo_lcs.truth.ecsv"))
    obs = read_damit(damit_file)
    assert len(obs.curves) == 1 and not obs.curves[0].relative and len(obs) == len(truth)
    assert np.allclose(Time(truth["time"]).jd, Time(obs.epoch).jd + obs.t.numpy() / 86400.0, rtol=0, atol=1e-8)
    # noise 0.05 mag around the noiseless magnitudes, intensities written to 10 digits
    resid = obs.mag.numpy() - np.asarray(truth["mag_clean"])
    assert 0.03 < resid.std() < 0.07 and abs(resid.mean()) < 0.01
    assert np.allclose(obs.sun_range_m.numpy(), AU_M)
    # the vectors: GCRS unit vectors of the pass rotated into ecliptic J2000 (astropy's frame to 2e-7)
    ecl = obs.observer.numpy()
    back = ICRS(CartesianRepresentation(ecl.T * u.au)).transform_to(BarycentricMeanEcliptic(equinox="J2000"))
    assert np.abs(back.cartesian.xyz.to_value(u.au).T - equatorial_to_ecliptic(ecl)).max() < 2e-7
    assert np.allclose(np.linalg.norm(ecl, axis=1), 1.0)
    assert 30_000e3 < obs.range_m.numpy().min() and obs.range_m.numpy().max() < 45_000e3      # GEO from a site
    alpha = np.degrees(np.arccos(np.clip((obs.sun.numpy() * ecl).sum(1), -1, 1)))
    assert alpha.max() - alpha.min() > 10.0                                                   # the phase sweeps


@pytest.mark.slow  # ~15 s on two loaded cores
def test_invert_reads_the_simulated_file_back(damit_file, tmp_path, capsys):
    n = len(read_damit(damit_file))
    assert invert_main([CONVEX, "--light-curve", str(damit_file), "--out", str(tmp_path), "--no-progress",
                        *SMALL]) == 0
    printed = capsys.readouterr().out
    assert f"geo_lcs: {n} samples in 1 light curves" in printed
    folder = tmp_path / "estimates" / "convex" / "invert_geo_lcs"
    table = Table.read(folder / "solutions.ecsv")
    assert 0.2 <= float(table[0]["period_h"]) <= 1.0 and math.isfinite(float(table[0]["rms"]))
    areas = Table.read(folder / "areas.ecsv")
    assert {"area_1_diffuse", "area_1_lobe_50"} <= set(areas.colnames) and len(areas) == 40 + 24 + 2


def test_refusals_are_one_line(damit_file, tmp_path, capsys):
    code = simulate.main([GEO, "--out", str(damit_file), "--format", "damit", "--seed", "3", "--no-progress", *SHORT])
    assert code == 2 and "already exists" in capsys.readouterr().err
    code = simulate.main([GEO, "--out", str(tmp_path / "x.ecsv"), "--format", "damit", "--no-progress", *SHORT])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.endswith(f"--out: {tmp_path / 'x.ecsv'} has a table suffix; a DAMIT file "
                                      f"(--format damit) has none, e.g. {tmp_path / 'x'}") and "\n" not in err
    code = simulate.main([str(ROOT / "configs" / "boxwing.yaml"), "--out", str(tmp_path / "x"), "--format", "damit",
                          "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "--format damit: the file needs per-sample Sun and observer directions" in err
    assert not (tmp_path / "x").exists() and not (tmp_path / "x.truth.ecsv").exists()
