"""Per-sample geometry against independent numbers: an analytic Sun, the sgp4 package's published test vector,
astropy's own topocentric elevation, the analytic cylinder-shadow entry of a circular orbit; bad input errors."""

import math

import numpy as np
import pytest

from lightcurve_gp.config.load import ConfigError, load_config
from lightcurve_gp.passes.earth import EARTH_RADIUS_KM, TimeGrid, site_gcrs, sun_gcrs
from lightcurve_gp.passes.geometry import PassGeometry, cylindrical_shadow, elevation_deg, pass_geometry, sample_times
from lightcurve_gp.passes.orbit import MU_EARTH_KM3_S2, kepler_positions_gcrs, parse_utc, tle_positions_gcrs

# the sgp4 package's verification TLE 00005 (SGP4-VER.TLE) and its TEME positions at 0 and 360 min (tcppver.out)
TLE_00005 = ["1 00005U 58002B   00179.78495062  .00000023  00000-0  28098-4 0  4753",
             "2 00005  34.2682 348.7242 1859667 331.7664  19.3264 10.82419157413667"]
TEME_00005_KM = [[7022.46529266, -1400.08296755, 0.03995155], [-7154.03120202, -3783.17682504, -3536.19412294]]

GEO_ORBIT = ("geometry={kind: orbit, elements: {a_km: 42164.0, i_deg: 0.1, mean_anomaly_deg: 150.0}, "
             "site: {lat_deg: 40.0, lon_deg: 10.0, alt_km: 0.3}, start_utc: '2024-05-15T22:00:00'}")


def _orbit_cfg(*overrides):
    return load_config("configs/boxwing.yaml", overrides=[GEO_ORBIT, "scenario.duration_s=600", *overrides])


def _low_precision_sun(jd_utc: np.ndarray) -> np.ndarray:
    """The Astronomical Almanac's low-precision Sun (~0.01 deg, 1950-2050): unit vector, true equator of date."""
    n = jd_utc - 2451545.0
    L = np.radians(280.460 + 0.9856474 * n)
    g = np.radians(357.528 + 0.9856003 * n)
    lam = L + np.radians(1.915) * np.sin(g) + np.radians(0.020) * np.sin(2 * g)
    eps = np.radians(23.439 - 0.0000004 * n)
    return np.stack([np.cos(lam), np.cos(eps) * np.sin(lam), np.sin(eps) * np.sin(lam)], -1)


@pytest.mark.parametrize("date", ["2003-01-01T00:00:00", "2024-03-20T02:00:00", "2024-07-05T18:30:00"])
def test_sun_matches_the_low_precision_formula(date):
    import erfa

    grid = TimeGrid.after(parse_utc(date), np.arange(0.0, 7201.0, 300.0))
    sun = sun_gcrs(grid)
    of_date = np.einsum("tij,tj->ti", erfa.pnm06a(grid.tt_jd1, grid.tt_jd2), sun)  # GCRS -> true equator of date
    ref = _low_precision_sun(grid.utc_jd1 + grid.utc_jd2)
    cos = (of_date * ref).sum(-1) / np.linalg.norm(of_date, axis=-1)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() <= 0.01
    assert np.linalg.norm(sun, axis=-1) == pytest.approx(1.496e8, rel=0.02)  # km, within the orbit's eccentricity


def test_tle_matches_the_sgp4_published_vector():
    import astropy.units as u
    from astropy.coordinates import GCRS, TEME, CartesianRepresentation
    from astropy.time import Time
    from sgp4.api import Satrec

    sat = Satrec.twoline2rv(*TLE_00005)
    epoch = Time(sat.jdsatepoch, sat.jdsatepochF, format="jd", scale="utc")
    grid = TimeGrid.after(epoch, np.array([0.0, 21600.0]))
    r_gcrs = tle_positions_gcrs(TLE_00005, grid)
    times = epoch + grid.seconds * u.s
    back = GCRS(CartesianRepresentation(r_gcrs.T * u.km), obstime=times).transform_to(TEME(obstime=times))
    assert np.abs(back.cartesian.xyz.to_value(u.km).T - np.array(TEME_00005_KM)).max() < 1e-6  # km (1 mm)
    # the GCRS position itself differs from TEME by the frame rotation: precession since 2000 is ~0.3 arcmin
    assert np.linalg.norm(r_gcrs, axis=-1) == pytest.approx(np.linalg.norm(TEME_00005_KM, axis=-1), abs=1e-6)


def test_elevation_of_known_geometry():
    import astropy.units as u
    from astropy.coordinates import GCRS, AltAz, CartesianRepresentation, EarthLocation

    start = parse_utc("2024-05-15T22:00:00")
    seconds = np.arange(0.0, 7201.0, 600.0)
    grid = TimeGrid.after(start, seconds)
    site, up = site_gcrs(40.0, 10.0, 0.3, grid)
    # straight above the site: 90 deg; along a horizontal direction: 0 deg
    assert elevation_deg(site + 1000.0 * up, site, up) == pytest.approx(90.0, abs=1e-6)
    horizontal = np.cross(up, [0.0, 0.0, 1.0])
    assert elevation_deg(site + 500.0 * horizontal, site, up) == pytest.approx(0.0, abs=1e-9)
    # a GEO object: astropy's own topocentric AltAz (its full transformation chain, no refraction)
    r = kepler_positions_gcrs(a_km=42164.0, e=0.0, i_deg=0.1, raan_deg=0.0, argp_deg=0.0, mean_anomaly_deg=150.0,
                              seconds=seconds)
    times = start + seconds * u.s
    loc = EarthLocation.from_geodetic(lon=10 * u.deg, lat=40 * u.deg, height=0.3 * u.km)
    altaz = GCRS(CartesianRepresentation(r.T * u.km), obstime=times).transform_to(AltAz(obstime=times, location=loc))
    assert np.abs(altaz.alt.deg - elevation_deg(r, site, up)).max() < 2e-3


def test_site_position_matches_astropy():
    import astropy.units as u
    from astropy.coordinates import EarthLocation

    start = parse_utc("2024-05-15T22:00:00")
    seconds = np.arange(0.0, 7201.0, 7.0)  # between the interpolation nodes
    site, _ = site_gcrs(-33.0, 250.0, 1.2, TimeGrid.after(start, seconds))
    ref, _ = EarthLocation.from_geodetic(lon=250 * u.deg, lat=-33 * u.deg, height=1.2 * u.km).get_gcrs_posvel(
        start + seconds * u.s)
    assert np.abs(site - ref.xyz.to_value(u.km).T).max() < 1e-3  # km


def test_shadow_entry_of_a_circular_orbit_matches_the_cylinder():
    a, seconds = 7000.0, np.arange(0.0, 6000.0, 1.0)
    start = parse_utc("2024-05-15T00:00:00")
    r = kepler_positions_gcrs(a_km=a, e=0.0, i_deg=50.0, raan_deg=30.0, argp_deg=0.0, mean_anomaly_deg=0.0,
                              seconds=seconds)
    sun = sun_gcrs(TimeGrid.after(start, seconds))
    shadow = cylindrical_shadow(r, sun)
    entry = int(np.flatnonzero(~shadow[:-1] & shadow[1:])[0]) + 1  # first shadowed sample after a lit one
    # analytic: r(u) = a (cos u P + sin u Q); shadowed where r.s = -sqrt(a^2 - R^2), entering while r.s decreases
    P, Q = r[0] / a, r[int(round(0.25 * 2 * math.pi / math.sqrt(MU_EARTH_KM3_S2 / a**3)))] / a
    s_hat = sun[entry] / np.linalg.norm(sun[entry])
    A, B = P @ s_hat, Q @ s_hat
    phi, c = math.atan2(B, A), -math.sqrt(1.0 - (EARTH_RADIUS_KM / a) ** 2) / math.hypot(A, B)
    n = math.sqrt(MU_EARTH_KM3_S2 / a**3)
    u_entry = phi + math.acos(c)  # cos(u - phi) = c with sin(u - phi) > 0: r.s still decreasing
    t_entry = (u_entry % (2 * math.pi)) / n
    assert seconds[entry - 1] < t_entry <= seconds[entry]


def test_pass_geometry_columns_are_consistent():
    cfg = _orbit_cfg()
    geo = pass_geometry(cfg)
    assert len(geo) == 601 and geo.start_utc.startswith("2024-05-15T22:00:00")
    assert np.allclose(np.linalg.norm(geo.sun.numpy(), axis=-1), 1.0)
    assert np.allclose(np.linalg.norm(geo.observer.numpy(), axis=-1), 1.0)
    assert 35_786e3 < float(geo.range_m.min()) < 42_164e3  # GEO seen from the ground
    assert bool(geo.observable.all()) and geo.shadow_model == "cylindrical"


def test_gaps_and_timestamps():
    cfg = _orbit_cfg("geometry.gap_fraction=0.2", "geometry.gap_seed=3")
    times = sample_times(cfg)
    assert times[0] == 0.0 and 400 < len(times) < 560 and np.all(np.diff(times) % 1.0 == 0)
    cfg = _orbit_cfg("geometry.timestamps_s=[0, 5, 6, 100]")
    assert sample_times(cfg).tolist() == [0.0, 5.0, 6.0, 100.0]


def test_from_columns_checks_its_columns():
    ok = dict(times_s=[0.0, 1.0], sun=[[1, 0, 0], [1, 0, 0]], observer=[[0, 2, 0], [0, 1, 0]], range_m=[1.0, 2.0])
    geo = PassGeometry.from_columns(**ok)
    assert geo.observer[0].tolist() == [0.0, 1.0, 0.0] and geo.phase_angle_deg.tolist() == [90.0, 90.0]
    with pytest.raises(ValueError, match=r"^sun: expected shape \(2, 3\)"):
        PassGeometry.from_columns(**{**ok, "sun": [[1, 0, 0]]})
    with pytest.raises(ValueError, match="^times_s: sample times must increase"):
        PassGeometry.from_columns(**{**ok, "times_s": [1.0, 0.0]})
    with pytest.raises(ValueError, match="^range_m: expected 2 finite ranges > 0"):
        PassGeometry.from_columns(**{**ok, "range_m": [1.0, 0.0]})


def _bad_checksum(line: str) -> str:
    return line[:68] + str((int(line[68]) + 1) % 10)


@pytest.mark.parametrize("override, message", [
    ("geometry.site.lat_deg=95", "geometry.site.lat_deg: 95 is outside [-90, 90]"),
    ("geometry.start_utc=yesterday noon", "geometry.start_utc: astropy cannot parse 'yesterday noon'"),
    (f"geometry.tle=['{_bad_checksum(TLE_00005[0])}', '{TLE_00005[1]}']",
     "geometry.tle[0]: line 1 checksum: the line sums to 3, its last digit is 4"),
    (f"geometry.tle=['{TLE_00005[0]}', '{TLE_00005[1][:60]}']",
     "geometry.tle[1]: line 2 has 60 characters, a TLE line has 69"),
])
def test_bad_orbit_input_names_the_key(override, message):
    extra = ["geometry.elements=null"] if "tle" in override else []
    with pytest.raises(ConfigError) as err:
        _orbit_cfg(override, *extra)
    assert str(err.value).startswith(message)


def test_pass_below_the_horizon_is_an_error():
    cfg = _orbit_cfg("geometry.site.lon_deg=190")  # the far side of the Earth from the GEO object
    with pytest.raises(ConfigError, match=r"^geometry.site: the object is below geometry.min_elevation_deg \(10 deg\)"):
        pass_geometry(cfg)


def test_fixed_geometry_needs_its_vectors():
    with pytest.raises(ConfigError, match="^geometry.sun_km: required when geometry.kind is fixed"):
        load_config("configs/boxwing.yaml", overrides=["geometry.sun_km=null"])
