"""The DAMIT/convexinv light-curve format: the shipped Ariadne file, malformed files, the writer's round trip."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from astropy.time import Time

from lightcurve_gp.observations.observations import CurveInfo, Observations
from lightcurve_gp.observed.damit import AU_M, is_damit_file, read_damit, write_damit
from lightcurve_gp.observed.lightcurve_file import LightCurveFileError

REPO = Path(__file__).resolve().parents[1]
ARIADNE = REPO / ".." / "shared" / "data" / "ariadne" / "test_lcs_rel"
needs_ariadne = pytest.mark.skipif(not ARIADNE.is_file(), reason=f"the Ariadne data are not at {ARIADNE}")

FIRST = "2438882.233275  9.843520e-01   1.467574e+00 1.309298e+00 8.242228e-02   7.140329e-01 6.399864e-01 8.236481e-02"


@needs_ariadne
def test_shipped_ariadne_file():
    obs = read_damit(ARIADNE)
    assert len(obs.curves) == 37 and len(obs) == 1541
    assert all(c.relative for c in obs.curves)
    assert obs.counts()[0] == 81 and obs.counts()[1] == 91
    assert obs.epoch == Time(2438882.233275, format="jd", scale="utc").isot
    # the file's first line is also the earliest sample
    assert obs.t[0] == 0.0 and obs.curve[0] == 0
    assert obs.mag[0].item() == pytest.approx(-2.5 * math.log10(0.984352), abs=1e-12)
    sun = np.array([1.467574, 1.309298, 0.08242228])
    earth = np.array([0.7140329, 0.6399864, 0.08236481])
    assert obs.sun[0].numpy() == pytest.approx(sun / np.linalg.norm(sun), abs=1e-12)
    assert obs.observer[0].numpy() == pytest.approx(earth / np.linalg.norm(earth), abs=1e-12)
    assert obs.range_m[0].item() == pytest.approx(np.linalg.norm(earth) * AU_M, rel=1e-12)
    assert obs.sun_range_m[0].item() == pytest.approx(np.linalg.norm(sun) * AU_M, rel=1e-12)
    # second sample: 2438882.237650 - 2438882.233275 days
    assert obs.t[1].item() == pytest.approx((2438882.237650 - 2438882.233275) * 86400.0, abs=1e-4)
    assert obs.span_s / 86400.0 == pytest.approx(2447896.33 - 2438882.23, abs=0.01)
    assert is_damit_file(ARIADNE)


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "lcs"
    path.write_text(text)
    return path


ROW = "2450000.5 1.0  1 0 0  0 1 0"


@pytest.mark.parametrize("text, message", [
    ("2\n1 0\n" + ROW + "\n", "line 4: the file ends after 1 of 2 light curves (expected the header 'points flag' of "
                              "light curve 2)"),
    ("1\n2 0\n" + ROW + "\n", "line 4: the file ends after 1 of 2 points of light curve 1"),
    ("1\n1 0\n2450000.5 1.0 1 0 0 0 1\n", "line 3: expected 8 numbers (JD brightness sun_x sun_y sun_z earth_x "
                                          "earth_y earth_z), got 7"),
    ("1\n1 0\n2450000.5 bright 1 0 0 0 1 0\n", "line 3: 'bright' is not a number (JD brightness sun_x sun_y sun_z "
                                               "earth_x earth_y earth_z)"),
    ("1\n1 0\n2450000.5 0.0 1 0 0 0 1 0\n", "line 3: brightness 0 must be > 0 (an intensity, not a magnitude)"),
    ("1\n1 0\n2450000.5 -1.2 1 0 0 0 1 0\n", "line 3: brightness -1.2 must be > 0 (an intensity, not a magnitude)"),
    ("1\n1 0\n2450000.5 1.0 0 0 0 0 1 0\n", "line 3: the Sun vector is zero"),
    ("1\n1 0\n2450000.5 1.0 1 0 0 0 0 0\n", "line 3: the Earth vector is zero"),
    ("1\n1 2\n" + ROW + "\n", "line 2: the flag must be 0 (relative) or 1 (calibrated), got 2"),
    ("1.5\n", "line 1: the number of light curves must be an integer >= 1, got 1.5"),
    ("1\n1 0\n" + ROW + "\n" + ROW + "\n", "line 4: more lines after the 1 light curves the first line announces"),
    ("", "empty file (expected the number of light curves on line 1)"),
])
def test_malformed_file_is_one_line(tmp_path, text, message):
    path = _write(tmp_path, text)
    with pytest.raises(LightCurveFileError) as err:
        read_damit(path)
    assert str(err.value) == f"{path}: {message}"


def test_writer_round_trip_and_time_order(tmp_path):
    # two curves given out of time order in the file; the reader sorts the samples and keeps their curves
    text = ("2\n2 0\n2450010.0 1.1  1 1 0  0 2 0\n2450010.1 0.9  1 1 0  0 2 0\n"
            "1 1\n2450000.0 2.0  3 0 0  0 0 0.5\n")
    obs = read_damit(_write(tmp_path, text), sigma_mag=0.02)
    assert obs.curve.tolist() == [1, 0, 0]
    assert [c.relative for c in obs.curves] == [True, False]
    assert obs.t.tolist() == pytest.approx([0.0, 10 * 86400.0, 10.1 * 86400.0], abs=1e-5)
    assert obs.sigma.tolist() == [0.02] * 3
    assert obs.sun[1].tolist() == pytest.approx([2 ** -0.5, 2 ** -0.5, 0.0])
    back = read_damit(write_damit(obs, tmp_path / "again"), sigma_mag=0.02)
    assert torch.allclose(back.t, obs.t, atol=1e-4)
    assert torch.allclose(back.mag, obs.mag, atol=1e-8)
    for name in ("sun", "observer", "range_m", "sun_range_m"):
        assert torch.allclose(getattr(back, name), getattr(obs, name), rtol=1e-8)
    assert back.curve.tolist() == obs.curve.tolist() and back.epoch == obs.epoch


def test_writer_needs_geometry(tmp_path):
    obs = Observations.single(t=[0.0, 1.0], mag=[0.0, 0.1], sigma=0.01)
    with pytest.raises(ValueError, match="per-sample geometry and an epoch"):
        write_damit(obs, tmp_path / "x")
    assert CurveInfo().relative is False


def test_is_damit_file(tmp_path):
    assert is_damit_file(_write(tmp_path, "1\n1 0\n" + ROW + "\n"))
    table = tmp_path / "lc.ecsv"
    table.write_text("1\n1 0\n")
    assert not is_damit_file(table)
    assert not is_damit_file(_write(tmp_path, "time mag\n0 1\n"))
