"""The Earth's orientation, an observer's site and the Sun in the GCRS, from astropy and ERFA, without downloads.

Frames. GCRS is the inertial frame of the package (geocentric, ICRS axes). A site's ITRS position (WGS84 geodetic
coordinates, ``EarthLocation``) is rotated to the GCRS by ``Wᵀ R3(−ERA) Cᵀ`` (IAU 2006/2000A, CIO based:
``C`` = ``erfa.c2i06a``, ERA = ``erfa.era00`` at UT1, ``W`` = polar motion ``erfa.pom00``) — the rotation astropy's
``EarthLocation.get_gcrs_posvel`` applies; TEME (SGP4's frame) goes to the ITRS by ``W R3(GMST82)`` as astropy's
``TEME`` frame does. The Sun is astropy's ``get_sun`` (apparent geocentric position, built-in ephemeris).

Cost. ``C``, polar motion, UT1 − TT and the Sun change slowly; they are evaluated at nodes every ``node_s``
(600 s) and interpolated linearly (error ≪ 1 mas for ``C`` and the Sun's direction); ERA and GMST are evaluated at
every sample. Positions agree with astropy's direct transforms to far below a metre (``tests/test_geometry.py``).

IERS data come from the ``astropy-iers-data`` package; automatic downloads are switched off inside
:func:`no_downloads` (a time past the bundled tables uses their last values, with astropy's warning).
Units: km, seconds, radians. astropy's coordinates and ERFA (about a second to import) are imported inside the
functions that use them, so that runs under the fixed geometry never load them.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import numpy as np

__all__ = ["TimeGrid", "no_downloads", "gcrs_to_itrs", "teme_to_gcrs", "site_gcrs", "sun_gcrs", "EARTH_RADIUS_KM"]

#: WGS84 equatorial radius (km)
EARTH_RADIUS_KM = 6378.137
_NODE_S = 600.0
_DAY_S = 86400.0


@contextlib.contextmanager
def no_downloads():
    """astropy's IERS auto-download off (the bundled tables only) for the duration of the block; a time past the
    tables' predictions uses their last values with astropy's warning instead of an error."""
    from astropy.utils import iers

    with iers.conf.set_temp("auto_download", False), iers.conf.set_temp("auto_max_age", None), \
            iers.conf.set_temp("iers_degraded_accuracy", "warn"):
        yield


@dataclass(frozen=True)
class TimeGrid:
    """Sample times after a UTC start, with the Julian dates the frames need (two-part, float64).

    Attributes:
        start: astropy ``Time`` of the first sample (UTC).
        seconds: sample times after ``start`` ``(T,)`` (SI seconds).
        utc_jd1, utc_jd2, tt_jd1, tt_jd2, ut1_jd1, ut1_jd2: Julian dates ``(T,)`` in UTC (SGP4's input), TT, UT1.
        node_seconds: the interpolation nodes ``(K,)`` (s after ``start``).
    """

    start: object
    seconds: np.ndarray
    utc_jd1: np.ndarray
    utc_jd2: np.ndarray
    tt_jd1: np.ndarray
    tt_jd2: np.ndarray
    ut1_jd1: np.ndarray
    ut1_jd2: np.ndarray
    node_seconds: np.ndarray

    @classmethod
    def after(cls, start, seconds: np.ndarray, node_s: float = _NODE_S) -> TimeGrid:
        """Grid of ``seconds (T,)`` after the UTC ``Time`` ``start``: TT is uniform (exact), UTC and UT1 − TT come
        from nodes every ``node_s`` (UTC's leap seconds fall on whole seconds, so a pass across one is exact at the
        nodes and off by at most the nodes' spacing in the linear part; UT1 − TT drifts by milliseconds a day)."""
        import astropy.units as u

        seconds = np.asarray(seconds, dtype=np.float64)
        nodes = np.unique(np.concatenate([np.arange(0.0, seconds.max() + node_s, node_s), seconds[[0, -1]]]))
        with no_downloads():
            t_nodes = start + nodes * u.s
            tt, ut1, utc = t_nodes.tt, t_nodes.ut1, t_nodes.utc
        tt0 = start.tt
        tt_jd2 = tt0.jd2 + seconds / _DAY_S
        offset_utc = ((utc.jd1 - tt.jd1) + (utc.jd2 - tt.jd2)) * _DAY_S  # UTC − TT (s) at the nodes
        offset_ut1 = ((ut1.jd1 - tt.jd1) + (ut1.jd2 - tt.jd2)) * _DAY_S
        jd1 = np.full_like(seconds, tt0.jd1)
        return cls(start=start, seconds=seconds, utc_jd1=jd1, utc_jd2=tt_jd2 + np.interp(seconds, nodes, offset_utc)
                   / _DAY_S, tt_jd1=jd1, tt_jd2=tt_jd2, ut1_jd1=jd1,
                   ut1_jd2=tt_jd2 + np.interp(seconds, nodes, offset_ut1) / _DAY_S, node_seconds=nodes)

    def nodes_time(self):
        """astropy ``Time`` of the nodes."""
        import astropy.units as u

        return self.start + self.node_seconds * u.s

    def interpolate(self, values: np.ndarray) -> np.ndarray:
        """Linear interpolation of node values ``(K, ...)`` to the samples ``(T, ...)``."""
        flat = values.reshape(values.shape[0], -1)
        out = np.stack([np.interp(self.seconds, self.node_seconds, col) for col in flat.T], -1)
        return out.reshape(self.seconds.shape[0], *values.shape[1:])


def _polar_motion(grid: TimeGrid, tio_locator: bool) -> np.ndarray:
    """``W`` ``(T, 3, 3)``: polar motion (IERS tables), with the TIO locator s′ for the CIO-based chain."""
    import erfa
    from astropy.utils import iers

    t_nodes = grid.nodes_time()
    with no_downloads():
        xp, yp = iers.earth_orientation_table.get().pm_xy(t_nodes)
    xp, yp = grid.interpolate(xp.to_value("rad")), grid.interpolate(yp.to_value("rad"))
    sp = erfa.sp00(grid.tt_jd1, grid.tt_jd2) if tio_locator else np.zeros_like(xp)
    return erfa.pom00(xp, yp, sp)


def gcrs_to_itrs(grid: TimeGrid) -> np.ndarray:
    """Rotation matrices GCRS → ITRS ``(T, 3, 3)`` at the samples of ``grid`` (IAU 2006/2000A, CIO based)."""
    import erfa

    c2i_nodes = erfa.c2i06a(*_node_tt(grid))
    c2i = grid.interpolate(c2i_nodes)
    era = erfa.era00(grid.ut1_jd1, grid.ut1_jd2)
    return erfa.c2tcio(c2i, era, _polar_motion(grid, tio_locator=True))


def _node_tt(grid: TimeGrid) -> tuple[np.ndarray, np.ndarray]:
    tt = grid.start.tt
    return np.full_like(grid.node_seconds, tt.jd1), tt.jd2 + grid.node_seconds / _DAY_S


def teme_to_gcrs(r_teme: np.ndarray, grid: TimeGrid) -> np.ndarray:
    """TEME positions ``(T, 3)`` → GCRS ``(T, 3)`` (same units): TEME → ITRS by ``W R3(GMST82)``, then to GCRS."""
    import erfa

    gmst = erfa.gmst82(grid.ut1_jd1, grid.ut1_jd2)
    c, s = np.cos(gmst), np.sin(gmst)
    pef = np.stack([c * r_teme[:, 0] + s * r_teme[:, 1], -s * r_teme[:, 0] + c * r_teme[:, 1], r_teme[:, 2]], -1)
    itrs = np.einsum("tij,tj->ti", _polar_motion(grid, tio_locator=False), pef)
    return np.einsum("tji,tj->ti", gcrs_to_itrs(grid), itrs)


def site_gcrs(lat_deg: float, lon_deg: float, alt_km: float, grid: TimeGrid,
              gcrs_from_itrs: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A WGS84 site's GCRS position ``(T, 3)`` (km) and its local vertical (geodetic up, unit) ``(T, 3)``.

    ``gcrs_from_itrs`` (``(T, 3, 3)``, ITRS → GCRS) reuses rotations already computed for the grid.
    """
    import astropy.units as u
    from astropy.coordinates import EarthLocation

    loc = EarthLocation.from_geodetic(lon=lon_deg * u.deg, lat=lat_deg * u.deg, height=alt_km * u.km,
                                      ellipsoid="WGS84")
    itrs = np.array([loc.x.to_value(u.km), loc.y.to_value(u.km), loc.z.to_value(u.km)])
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    up = np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
    m = gcrs_from_itrs if gcrs_from_itrs is not None else np.swapaxes(gcrs_to_itrs(grid), -1, -2)
    return m @ itrs, m @ up


def sun_gcrs(grid: TimeGrid) -> np.ndarray:
    """The Sun's apparent geocentric GCRS position ``(T, 3)`` (km): astropy ``get_sun`` at the nodes, interpolated."""
    import astropy.units as u
    from astropy.coordinates import get_sun

    with no_downloads():
        nodes = get_sun(grid.nodes_time()).cartesian.xyz.to_value(u.km).T
    return grid.interpolate(nodes)
