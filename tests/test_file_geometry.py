"""The geometry of a light-curve file: a TLE and a site give the config's pass geometry; a TLE alone is refused."""

from pathlib import Path

import numpy as np
import pytest
import torch
from astropy.time import Time

from lightcurve_gp.config.load import load_config
from lightcurve_gp.observed.lightcurve_file import LightCurve
from lightcurve_gp.observed.run import FileGeometryError, file_geometry
from lightcurve_gp.passes.geometry import pass_geometry

LEO = Path(__file__).resolve().parents[1] / "configs" / "leo_pass.yaml"


def tle_file(cfg, **site):
    t = np.arange(0.0, 120.0, 10.0)
    meta = {"tle_line1": cfg.geometry.tle[0], "tle_line2": cfg.geometry.tle[1], **site}
    return LightCurve(start=Time(cfg.geometry.start_utc, scale="utc"), t=t, mag=np.full(t.size, 8.0), meta=meta,
                      source="leo.ecsv")


def test_a_tle_and_site_give_the_configs_pass_geometry():
    stamps = ", ".join(str(10 * k) for k in range(12))
    cfg = load_config(LEO, ["scenario.duration_s=110", "evaluation.rmse_window_s=[50, 110]",
                            f"geometry.timestamps_s=[{stamps}]"])
    s = cfg.geometry.site
    g = file_geometry(tle_file(cfg, site_lat_deg=s.lat_deg, site_lon_deg=s.lon_deg, site_alt_m=s.alt_km * 1e3))
    expected = pass_geometry(cfg)
    torch.testing.assert_close(g.sun, expected.sun, rtol=0, atol=1e-12)
    torch.testing.assert_close(g.observer, expected.observer, rtol=0, atol=1e-12)
    torch.testing.assert_close(g.range_m, expected.range_m, rtol=1e-12, atol=0)
    assert bool(g.observable.all())  # every sample of a file was observed: none is masked


def test_a_tle_without_a_site_is_refused():
    cfg = load_config(LEO)
    with pytest.raises(FileGeometryError, match=r"^leo.ecsv: metadata site_lat_deg: missing \(a file with a TLE "
                                                r"needs the observing site"):
        file_geometry(tle_file(cfg))
