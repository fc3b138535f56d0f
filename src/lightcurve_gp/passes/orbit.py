"""Where the object is: a TLE propagated with SGP4, or Keplerian elements as a two-body orbit.

Frames and units. SGP4 (the ``sgp4`` package, Vallado's implementation) gives TEME positions in km at UTC Julian
dates; :func:`tle_positions_gcrs` turns them at once into GCRS (:func:`lightcurve_gp.passes.earth.teme_to_gcrs`), the
inertial frame of the whole package. Keplerian elements are read as osculating elements in the GCRS axes at the
start time (μ = 398 600.4418 km³/s², no perturbations). Every function here returns GCRS positions in **km**
``(T, 3)`` as float64 numpy arrays; :mod:`lightcurve_gp.passes.geometry` converts to metres. UTC times and TLE lines
are read by :mod:`lightcurve_gp.config.parsing` (re-exported here as :func:`parse_utc`, :func:`check_tle`).
"""

from __future__ import annotations

import math

import numpy as np

from lightcurve_gp.config.parsing import check_tle, parse_utc
from lightcurve_gp.passes.earth import TimeGrid, teme_to_gcrs

__all__ = ["MU_EARTH_KM3_S2", "parse_utc", "check_tle", "satellite_from_tle", "tle_positions_gcrs",
           "kepler_positions_gcrs"]

#: the Earth's gravitational parameter (km³/s², WGS84 / EGM96)
MU_EARTH_KM3_S2 = 398600.4418


def satellite_from_tle(lines: list[str]):
    """An ``sgp4.api.Satrec`` from two checked TLE lines (``ValueError`` naming the line otherwise)."""
    from sgp4.api import Satrec

    for i, line in enumerate(lines):
        check_tle(line, i + 1)
    if lines[0][2:7] != lines[1][2:7]:
        raise ValueError(f"line 2 is of satellite {lines[1][2:7].strip()!r}, line 1 of {lines[0][2:7].strip()!r}")
    try:
        return Satrec.twoline2rv(lines[0].rstrip(), lines[1].rstrip())
    except (ValueError, IndexError) as exc:
        raise ValueError(f"SGP4 cannot read the TLE: {exc}") from None


#: SGP4 error codes (sgp4.api.SGP4_ERRORS) in words
_SGP4_ERRORS = {1: "mean eccentricity out of range", 2: "mean motion below zero", 3: "perturbed eccentricity out of "
                "range", 4: "semi-latus rectum below zero", 6: "the orbit has decayed"}


def tle_positions_gcrs(lines: list[str], grid: TimeGrid) -> np.ndarray:
    """GCRS positions ``(T, 3)`` (km) of the TLE ``lines`` at the times of ``grid`` (SGP4 in TEME, then rotated)."""
    sat = satellite_from_tle(lines)
    err, r_teme, _ = sat.sgp4_array(grid.utc_jd1, grid.utc_jd2)
    bad = np.flatnonzero(err)
    if bad.size:
        code = int(err[bad[0]])
        raise ValueError(f"SGP4 error {code} ({_SGP4_ERRORS.get(code, 'unknown')}) at {grid.seconds[bad[0]]:g} s")
    return teme_to_gcrs(np.asarray(r_teme, dtype=np.float64), grid)


def _eccentric_anomaly(mean_anomaly: np.ndarray, e: float) -> np.ndarray:
    """Solve Kepler's equation ``E − e sin E = M`` by Newton's method (to machine precision for e ≤ 0.99)."""
    E = mean_anomaly + e * np.sin(mean_anomaly) if e < 0.8 else np.full_like(mean_anomaly, math.pi)
    for _ in range(50):
        step = (E - e * np.sin(E) - mean_anomaly) / (1.0 - e * np.cos(E))
        E = E - step
        if np.max(np.abs(step)) < 1e-15:
            break
    return E


def kepler_positions_gcrs(*, a_km: float, e: float, i_deg: float, raan_deg: float, argp_deg: float,
                          mean_anomaly_deg: float, seconds: np.ndarray) -> np.ndarray:
    """Two-body GCRS positions ``(T, 3)`` (km) ``seconds (T,)`` after the epoch of the elements."""
    n = math.sqrt(MU_EARTH_KM3_S2 / a_km**3)  # mean motion (rad/s)
    M = math.radians(mean_anomaly_deg) + n * np.asarray(seconds, dtype=np.float64)
    M = np.remainder(M + math.pi, 2.0 * math.pi) - math.pi
    E = _eccentric_anomaly(M, e)
    perifocal = np.stack([a_km * (np.cos(E) - e), a_km * math.sqrt(1.0 - e * e) * np.sin(E), np.zeros_like(E)], -1)
    return perifocal @ _perifocal_to_inertial(math.radians(i_deg), math.radians(raan_deg), math.radians(argp_deg)).T


def _perifocal_to_inertial(i: float, raan: float, argp: float) -> np.ndarray:
    """``R3(−Ω) R1(−i) R3(−ω)``: perifocal (periapsis, in-plane normal, orbit normal) to inertial axes ``(3, 3)``."""
    cO, sO, ci, si, cw, sw = math.cos(raan), math.sin(raan), math.cos(i), math.sin(i), math.cos(argp), math.sin(argp)
    return np.array([
        [cO * cw - sO * sw * ci, -cO * sw - sO * cw * ci, sO * si],
        [sO * cw + cO * sw * ci, -sO * sw + cO * cw * ci, -cO * si],
        [sw * si, cw * si, ci],
    ])
