"""Whether a site could have seen an object at each sample: above the horizon, the sky dark, the object sunlit.

An optical light curve of an object lit by the Sun exists only where three things hold at once; a sample where one
fails cannot have been observed, so a file whose TLE and site put many samples there has the wrong TLE, site or
times (a time zone taken for UTC, longitude east for west). Per sample of a :class:`PassGeometry` built from a TLE
and a site (:func:`lightcurve_gp.passes.geometry.orbit_pass`):

* **below the horizon**: the object's elevation at the site (geodetic WGS84 vertical, no refraction) is below 0°;
* **daylight at the site**: the Sun's elevation at the site is above :data:`TWILIGHT_SUN_ELEVATION_DEG` = −6°, the
  end of civil twilight (the sky is too bright for a satellite before; a rule of thumb, nautical twilight at −12° is
  darker still, so −6° flags only samples that cannot have been taken);
* **in the Earth's shadow**: :attr:`PassGeometry.in_shadow` (cylindrical shadow, no penumbra).

:func:`site_visibility` computes the flags, :meth:`Visibility.describe` names them in one line: the counts and each
kind's first sample. Units: degrees, seconds after the geometry's ``start_utc``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from lightcurve_gp.passes.earth import TimeGrid, site_gcrs, sun_gcrs
from lightcurve_gp.passes.geometry import PassGeometry, elevation_deg
from lightcurve_gp.passes.orbit import parse_utc

__all__ = ["HORIZON_DEG", "TWILIGHT_SUN_ELEVATION_DEG", "Visibility", "site_visibility"]

#: the object is below the horizon below this elevation at the site (deg; geometric, no refraction)
HORIZON_DEG = 0.0
#: the site is in daylight while the Sun is above this elevation (deg; the end of civil twilight)
TWILIGHT_SUN_ELEVATION_DEG = -6.0


@dataclass(frozen=True)
class Visibility:
    """Per-sample flags of ``T`` samples: why each could not have been observed from the site.

    Attributes:
        times_s: the sample times ``(T,)`` (s after the geometry's ``start_utc``).
        object_elevation_deg: the object's elevation at the site ``(T,)`` (deg).
        sun_elevation_deg: the Sun's elevation at the site ``(T,)`` (deg).
        below_horizon: ``object_elevation_deg < HORIZON_DEG`` ``(T,)``.
        daylight: ``sun_elevation_deg > TWILIGHT_SUN_ELEVATION_DEG`` ``(T,)``.
        in_shadow: the object in the Earth's shadow ``(T,)``.
    """

    times_s: np.ndarray
    object_elevation_deg: np.ndarray
    sun_elevation_deg: np.ndarray
    below_horizon: np.ndarray
    daylight: np.ndarray
    in_shadow: np.ndarray

    @property
    def unseen(self) -> np.ndarray:
        """Samples that cannot have been observed for any of the three reasons ``(T,)`` (bool)."""
        return self.below_horizon | self.daylight | self.in_shadow

    def describe(self, when: Callable[[int], str] | None = None) -> str | None:
        """One line: how many samples cannot have been observed and why, each reason's count and its first sample
        (``when(index)``, by default its time in seconds); ``None`` when every sample could have been."""
        when = when or (lambda i: f"{float(self.times_s[i]):g} s")
        unseen = int(self.unseen.sum())
        if not unseen:
            return None
        reasons = []
        for flags, what in ((self.below_horizon, f"with the object below the horizon (elevation < {HORIZON_DEG:g} "
                                                 f"deg)"),
                            (self.daylight, f"in daylight at the site (Sun above {TWILIGHT_SUN_ELEVATION_DEG:g} "
                                            f"deg)"),
                            (self.in_shadow, "with the object in the Earth's shadow")):
            if flags.any():
                reasons.append(f"{int(flags.sum())} {what}, the first at {when(int(np.argmax(flags)))}")
        total = self.times_s.size
        return (f"{unseen} of {total} sample{'s' if total != 1 else ''} cannot have been observed from the site: "
                f"{'; '.join(reasons)}")


def site_visibility(geometry: PassGeometry, *, lat_deg: float, lon_deg: float, alt_km: float) -> Visibility:
    """The :class:`Visibility` of the samples of ``geometry`` (a pass with its ``start_utc``, elevations and shadow
    flags, e.g. from :func:`~lightcurve_gp.passes.geometry.orbit_pass`) from the WGS84 site ``lat_deg``,
    ``lon_deg`` (deg), ``alt_km`` (km): the Sun's elevation there is computed at every sample time."""
    if geometry.start_utc is None:
        raise ValueError("site_visibility: the geometry has no start_utc (a fixed geometry has no site)")
    start = parse_utc(geometry.start_utc)
    seconds = geometry.times_s.cpu().numpy()
    grid = TimeGrid.after(start, seconds)
    site, up = site_gcrs(lat_deg, lon_deg, alt_km, grid)
    sun = elevation_deg(sun_gcrs(grid), site, up)
    obj = geometry.elevation_deg.cpu().numpy()
    return Visibility(times_s=seconds, object_elevation_deg=obj, sun_elevation_deg=sun,
                      below_horizon=obj < HORIZON_DEG, daylight=sun > TWILIGHT_SUN_ELEVATION_DEG,
                      in_shadow=geometry.in_shadow.cpu().numpy().astype(bool))
