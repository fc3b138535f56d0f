"""End to end on (43) Ariadne's 37 relative light curves (DAMIT's example data): the command finds convexinv's pole
(or its mirror), period and rms with nothing given."""

import math
import subprocess
import sys
from pathlib import Path

import pytest
from astropy.table import Table

from lightcurve_gp.commands.invert_convex import settings_from_config
from lightcurve_gp.config.load import ConfigError, load_config

REPO = Path(__file__).resolve().parents[1]
ARIADNE = REPO / ".." / "shared" / "data" / "ariadne" / "test_lcs_rel"
#: convexinv's answer on these data (the data folder's README)
POLE_DEG = (253.3, -16.9)
PERIOD_H = 5.76198173
RMS = 0.0154


def _separation_deg(a, b) -> float:
    (l1, b1), (l2, b2) = (map(math.radians, a)), (map(math.radians, b))
    c = math.sin(b1) * math.sin(b2) + math.cos(b1) * math.cos(b2) * math.cos(l1 - l2)
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def test_convex_section_is_checked(tmp_path):
    text = (REPO / "configs" / "convex.yaml").read_text().replace("period_range_h: [2.0, 20.0]",
                                                                   "period_range_h: [20.0, 2.0]")
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"^convex.period_range_h: shortest 20 must be below longest 2$"):
        load_config(path, [])
    cfg = load_config(REPO / "configs" / "convex.yaml", [])
    assert cfg.convex is not None and cfg.convex.poles == 200
    assert load_config(REPO / "configs" / "boxwing.yaml", []).convex is None
    with pytest.raises(ConfigError, match=r"^convex.magnitude_weights: expected true or false, got 'yes'$"):
        load_config(REPO / "configs" / "convex.yaml", ["convex.magnitude_weights='yes'"])
    weighted = load_config(REPO / "configs" / "convex.yaml", ["convex.magnitude_weights=true"])
    assert settings_from_config(weighted, 10.0).magnitude_weights
    assert not settings_from_config(cfg, 10.0).magnitude_weights


@pytest.mark.slow
@pytest.mark.skipif(not ARIADNE.is_file(), reason=f"the Ariadne data are not at {ARIADNE}")
def test_ariadne_pole_period_and_rms(tmp_path):
    out = subprocess.run([sys.executable, "-m", "lightcurve_gp.invert", str(REPO / "configs" / "convex.yaml"),
                          "--light-curve", str(ARIADNE), "--out", str(tmp_path), "--no-progress"],
                         capture_output=True, text=True, timeout=600, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert "family 1: pole" in out.stdout
    folder = tmp_path / "estimates" / "convex" / "invert_test_lcs_rel"
    table = Table.read(folder / "solutions.ecsv")
    assert {"pole_lambda_deg", "pole_beta_deg", "period_h", "rms", "weight"} <= set(table.colnames)
    assert str(table["period_h"].unit) == "h" and str(table["pole_lambda_deg"].unit) == "deg"
    best = table[0]
    pole = (float(best["pole_lambda_deg"]), float(best["pole_beta_deg"]))
    mirror = (POLE_DEG[0] + 180.0, POLE_DEG[1])
    assert min(_separation_deg(pole, POLE_DEG), _separation_deg(pole, mirror)) < 5.0
    assert abs(float(best["period_h"]) - PERIOD_H) < 1e-5
    assert abs(float(best["rms"]) / RMS - 1) < 0.1
    # the mirror family is reported too
    poles = [(float(r["pole_lambda_deg"]), float(r["pole_beta_deg"])) for r in table]
    assert any(_separation_deg(p, POLE_DEG) < 5 for p in poles) and any(_separation_deg(p, mirror) < 5 for p in poles)
    for name in ("areas.ecsv", "summary.json", "periodogram.png", "light_curves.png", "shape.png"):
        assert (folder / name).is_file()
