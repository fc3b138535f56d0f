"""Per-sample geometry of an observation: where the Sun and the observer are seen from the object, and whether the
object can be seen at all.

:class:`PassGeometry` is the one exchange format: sample times and, per sample, the inertial unit vectors
object → Sun ``s`` and object → observer ``v``, the range, the object's elevation at the site and a shadow flag.
The renderer (:class:`lightcurve_gp.photometry.render.Scene`), the scenario and the filters consume it; a reader of
measured
light curves builds it with :meth:`PassGeometry.from_columns` (e.g. from ``sun_x, sun_y, sun_z, obs_x, …,
range_km`` columns).

``geometry.kind: fixed`` (the paper, Table 3): the same ``s``, ``v`` and range at every sample, never shadowed,
elevation 90°. ``geometry.kind: orbit``: the object's GCRS position from a TLE (SGP4) or Keplerian elements
(:mod:`lightcurve_gp.passes.orbit`), the site and the Sun from astropy (:mod:`lightcurve_gp.passes.earth`), then

* ``s = (r_sun − r) / |r_sun − r|``, ``v = (r_site − r) / |r_site − r|``, range ``|r_site − r|``;
* elevation ``atan2(up · d, |d − (up · d) up|)`` of ``d = r − r_site`` with ``up`` the site's geodetic (WGS84) vertical;
* shadow: **cylindrical** Earth shadow (no penumbra), radius 6378.137 km along the Sun direction ``ŝ⊕`` seen from
  the geocentre: shadowed when ``r·ŝ⊕ < 0`` and ``|r − (r·ŝ⊕) ŝ⊕| < R⊕``.

A sample below ``geometry.min_elevation_deg`` or in shadow is not :attr:`PassGeometry.observable`: its observation
is missing (NaN). Frame: GCRS. Units: seconds after ``start_utc``, metres for ranges inside the code, km in configs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from lightcurve_gp.config.load import Config, ConfigError, GeometryConfig
from lightcurve_gp.passes.earth import EARTH_RADIUS_KM, TimeGrid, gcrs_to_itrs, site_gcrs, sun_gcrs
from lightcurve_gp.passes.orbit import kepler_positions_gcrs, parse_utc, tle_positions_gcrs

__all__ = ["PassGeometry", "SHADOW_MODEL", "sample_times", "pass_geometry", "orbit_pass", "cylindrical_shadow",
           "elevation_deg"]

#: the shadow model of :func:`cylindrical_shadow`
SHADOW_MODEL = "cylindrical"


@dataclass(frozen=True)
class PassGeometry:
    """Geometry of ``T`` samples (float64 tensors on the CPU; GCRS).

    Attributes:
        times_s: sample times after the first ``(T,)`` (s), increasing; irregular steps are allowed.
        sun: unit vectors object → Sun ``(T, 3)``.
        observer: unit vectors object → observer ``(T, 3)``.
        range_m: object–observer distance ``(T,)`` (m).
        elevation_deg: the object's elevation at the site ``(T,)`` (deg; 90 for a fixed geometry).
        in_shadow: the object is in the Earth's shadow ``(T,)`` (bool).
        min_elevation_deg: samples below it are not observable.
        start_utc: ISO UTC time of ``times_s = 0`` (``None`` for a fixed geometry).
        shadow_model: how ``in_shadow`` was computed (``"cylindrical"``, ``"none"`` or the reader's word).
    """

    times_s: Tensor
    sun: Tensor
    observer: Tensor
    range_m: Tensor
    elevation_deg: Tensor
    in_shadow: Tensor
    min_elevation_deg: float = -90.0
    start_utc: str | None = None
    shadow_model: str = SHADOW_MODEL

    @classmethod
    def from_columns(cls, *, times_s, sun, observer, range_m, elevation_deg=None, in_shadow=None,
                     min_elevation_deg: float = -90.0, start_utc: str | None = None,
                     shadow_model: str = "none") -> PassGeometry:
        """Check and normalise per-sample columns (any array-likes): ``sun``/``observer`` ``(T, 3)`` directions or
        positions relative to the object (normalised here), ``range_m (T,)`` > 0, ``times_s (T,)`` increasing;
        elevation defaults to 90° and the shadow flag to false. Errors name the column."""
        f64 = lambda x: torch.as_tensor(np.asarray(x, dtype=np.float64))  # noqa: E731
        times, s, v, r = f64(times_s), f64(sun), f64(observer), f64(range_m)
        T = times.shape[0] if times.ndim == 1 else -1
        if T < 1:
            raise ValueError(f"times_s: expected a 1-D array of sample times, got shape {tuple(times.shape)}")
        if T > 1 and not bool((times[1:] > times[:-1]).all()):
            raise ValueError("times_s: sample times must increase")
        for name, vec in (("sun", s), ("observer", v)):
            if vec.shape != (T, 3):
                raise ValueError(f"{name}: expected shape ({T}, 3), got {tuple(vec.shape)}")
            if not bool((torch.linalg.vector_norm(vec, dim=-1) > 0).all()) or not bool(torch.isfinite(vec).all()):
                raise ValueError(f"{name}: every row must be a finite non-zero vector")
        if r.shape != (T,) or not bool((r > 0).all()) or not bool(torch.isfinite(r).all()):
            raise ValueError(f"range_m: expected {T} finite ranges > 0, got shape {tuple(r.shape)}")
        elev = torch.full((T,), 90.0, dtype=torch.float64) if elevation_deg is None else f64(elevation_deg)
        shadow = torch.zeros(T, dtype=torch.bool) if in_shadow is None else torch.as_tensor(np.asarray(in_shadow,
                                                                                                       dtype=bool))
        for name, col in (("elevation_deg", elev), ("in_shadow", shadow)):
            if col.shape != (T,):
                raise ValueError(f"{name}: expected shape ({T},), got {tuple(col.shape)}")
        unit = lambda x: x / torch.linalg.vector_norm(x, dim=-1, keepdim=True)  # noqa: E731
        return cls(times, unit(s), unit(v), r, elev, shadow, float(min_elevation_deg), start_utc, shadow_model)

    def __len__(self) -> int:
        return self.times_s.shape[0]

    @property
    def observable(self) -> Tensor:
        """Samples above the minimum elevation and out of the shadow ``(T,)`` (bool)."""
        return (self.elevation_deg >= self.min_elevation_deg) & ~self.in_shadow

    @property
    def phase_angle_deg(self) -> Tensor:
        """Sun–object–observer angle per sample ``(T,)`` (deg)."""
        return torch.rad2deg(torch.acos((self.sun * self.observer).sum(-1).clamp(-1.0, 1.0)))

    def subset(self, index: Tensor) -> PassGeometry:
        """The samples ``index`` (bool mask or integer indices), times kept as they are."""
        return PassGeometry(self.times_s[index], self.sun[index], self.observer[index], self.range_m[index],
                            self.elevation_deg[index], self.in_shadow[index], self.min_elevation_deg,
                            self.start_utc, self.shadow_model)


def cylindrical_shadow(r_km: np.ndarray, sun_km: np.ndarray, radius_km: float = EARTH_RADIUS_KM) -> np.ndarray:
    """Cylindrical Earth shadow: ``r (T, 3)`` (geocentric) is shadowed when behind the Earth (``r·ŝ < 0``) within
    ``radius_km`` of the shadow axis; ``sun (T, 3)`` the geocentric Sun. Returns ``(T,)`` bool."""
    s_hat = sun_km / np.linalg.norm(sun_km, axis=-1, keepdims=True)
    along = (r_km * s_hat).sum(-1)
    perpendicular = np.linalg.norm(r_km - along[:, None] * s_hat, axis=-1)
    return (along < 0.0) & (perpendicular < radius_km)


def elevation_deg(r_km: np.ndarray, site_km: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Elevation ``(T,)`` (deg) of positions ``r (T, 3)`` seen from ``site (T, 3)`` with unit vertical ``up (T, 3)``."""
    line = r_km - site_km
    vertical = (line * up).sum(-1)
    horizontal = np.linalg.norm(line - vertical[:, None] * up, axis=-1)
    return np.degrees(np.arctan2(vertical, horizontal))  # accurate near the zenith, unlike asin


def sample_times(cfg: Config) -> np.ndarray:
    """Sample times ``(T,)`` (s): ``geometry.timestamps_s``, or every ``scenario.dt_s`` up to ``duration_s``, less
    the ``geometry.gap_fraction`` dropped at random (seeded by ``geometry.gap_seed``; the first sample is kept)."""
    geo, sc = cfg.geometry, cfg.scenario
    if geo.kind == "orbit" and geo.timestamps_s is not None:
        times = np.asarray(geo.timestamps_s, dtype=np.float64)
    else:
        times = np.arange(int(round(sc.duration_s / sc.dt_s)) + 1, dtype=np.float64) * sc.dt_s
    if geo.kind == "orbit" and geo.gap_fraction > 0:
        rng = np.random.default_rng(geo.gap_seed)
        keep = rng.random(times.shape[0]) >= geo.gap_fraction
        keep[0] = True
        times = times[keep]
    return times


def orbit_pass(geo: GeometryConfig, seconds: np.ndarray) -> PassGeometry:
    """The geometry of an orbit from ``geo`` (``kind: orbit``) at ``seconds (T,)`` after ``geo.start_utc``.

    Raises :class:`ConfigError` naming the key when the TLE cannot be propagated or when the object is never
    observable (below ``min_elevation_deg`` or in shadow at every sample).
    """
    start = parse_utc(geo.start_utc)
    grid = TimeGrid.after(start, seconds)
    try:
        if geo.tle is not None:
            r_obj = tle_positions_gcrs(geo.tle, grid)
        else:
            el = geo.elements
            r_obj = kepler_positions_gcrs(a_km=el.a_km, e=el.e, i_deg=el.i_deg, raan_deg=el.raan_deg,
                                          argp_deg=el.argp_deg, mean_anomaly_deg=el.mean_anomaly_deg, seconds=seconds)
    except ValueError as exc:
        raise ConfigError(f"geometry.tle: {exc}") from None
    rot = np.swapaxes(gcrs_to_itrs(grid), -1, -2)  # ITRS → GCRS
    site, up = site_gcrs(geo.site.lat_deg, geo.site.lon_deg, geo.site.alt_km, grid, gcrs_from_itrs=rot)
    sun = sun_gcrs(grid)
    out = PassGeometry.from_columns(times_s=seconds, sun=sun - r_obj, observer=site - r_obj,
                                    range_m=np.linalg.norm(site - r_obj, axis=-1) * 1e3,
                                    elevation_deg=elevation_deg(r_obj, site, up),
                                    in_shadow=cylindrical_shadow(r_obj, sun), min_elevation_deg=geo.min_elevation_deg,
                                    start_utc=start.isot, shadow_model=SHADOW_MODEL)
    if not bool(out.observable.any()):
        raise ConfigError(f"geometry.site: the object is below geometry.min_elevation_deg "
                          f"({geo.min_elevation_deg:g} deg) or in the Earth's shadow at all {len(out)} samples "
                          f"(highest elevation {float(out.elevation_deg.max()):.1f} deg)")
    return out


def _fixed_pass(geo: GeometryConfig, seconds: np.ndarray) -> PassGeometry:
    """The paper's geometry (object at the origin) repeated at every sample."""
    sun, obs = np.asarray(geo.sun_km, dtype=np.float64), np.asarray(geo.observer_km, dtype=np.float64)
    T = seconds.shape[0]
    return PassGeometry.from_columns(times_s=seconds, sun=np.tile(sun, (T, 1)), observer=np.tile(obs, (T, 1)),
                                     range_m=np.full(T, float(np.linalg.norm(obs)) * 1e3), shadow_model="none")


def pass_geometry(cfg: Config) -> PassGeometry:
    """The per-sample geometry of ``cfg`` at :func:`sample_times` (either ``geometry.kind``)."""
    seconds = sample_times(cfg)
    return orbit_pass(cfg.geometry, seconds) if cfg.geometry.kind == "orbit" else _fixed_pass(cfg.geometry, seconds)
