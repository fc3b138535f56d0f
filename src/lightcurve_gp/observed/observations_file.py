"""Light-curve files as :class:`~lightcurve_gp.observations.Observations`: one or several files of one object.

Each file is one light curve (:mod:`lightcurve_gp.observed.lightcurve_file`): its samples, 1σ (``mag_err``, else
the value given), geometry (per-sample columns, or a TLE and site through
:func:`lightcurve_gp.observed.run.file_geometry`, or none: the config's fixed geometry) and whether its zero point
is known. Several files are placed on the time axis of the first one by their UTC times (gaps of hours or days are
kept as they are) and merged in time order; a file's light curve keeps its own geometry and zero point.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch

from lightcurve_gp.observations.observations import Observations, ObservationsError
from lightcurve_gp.observed.information import flat_light_curve
from lightcurve_gp.observed.lightcurve_file import LightCurve, LightCurveFileError, iso_times, read_light_curve
from lightcurve_gp.observed.run import file_geometry

__all__ = ["light_curve_observations", "read_observations"]


def light_curve_observations(lc: LightCurve, *, mag_err: float | None = None, relative: bool = False,
                             strict: bool = False, warn: Callable[[str], None] | None = None) -> Observations:
    """One file's light curve as observations (times from its first sample); ``mag_err`` (mag) is every sample's
    1σ when the file has no ``mag_err`` column (a :class:`LightCurveFileError` when neither gives one); ``strict``
    and ``warn``: samples its TLE and site say cannot have been observed (:func:`file_geometry`)."""
    if lc.mag_err is None and mag_err is None:
        raise LightCurveFileError(f"{lc.source}: no mag_err column; give the magnitudes' 1-sigma (--mag-err)")
    sigma = lc.mag_err if lc.mag_err is not None else np.full(lc.t.size, float(mag_err))
    geometry = file_geometry(lc, strict=strict, warn=warn)
    extra = {}
    if geometry is not None:
        extra = {"sun": geometry.sun, "observer": geometry.observer, "range_m": geometry.range_m}
    return Observations.single(t=lc.t, mag=lc.mag, sigma=sigma, source=lc.source, relative=relative,
                               band=lc.meta.get("band"), epoch=str(iso_times(lc.start)), **extra)


def read_observations(paths: Sequence[str | Path], *, mag_err: float | None = None,
                      relative: bool | Sequence[bool] = False, strict: bool = False,
                      warn: Callable[[str], None] | None = None) -> Observations:
    """Read light-curve files of one object into one :class:`Observations` (module docstring). ``relative``: one
    flag for every file or one per file (the zero point of that light curve is unknown). Errors are one
    :class:`LightCurveFileError` line naming the file; ``warn`` gets a line for each file whose TLE and site say some
    samples cannot have been observed (``strict`` refuses it instead) and for each flat light curve
    (:func:`lightcurve_gp.observed.information.flat_light_curve`)."""
    paths = list(paths)
    if not paths:
        raise LightCurveFileError("no light-curve file given")
    flags = [bool(relative)] * len(paths) if isinstance(relative, bool) else [bool(r) for r in relative]
    if len(flags) != len(paths):
        raise LightCurveFileError(f"{len(flags)} zero-point flags for {len(paths)} light-curve files")
    curves = [read_light_curve(p) for p in paths]
    parts = [light_curve_observations(lc, mag_err=mag_err, relative=r, strict=strict, warn=warn)
             for lc, r in zip(curves, flags)]
    if warn is not None:
        for lc, part in zip(curves, parts):
            message = flat_light_curve(lc, noise_std=float(torch.median(part.sigma)))
            if message:
                warn(message)
    first = curves[0].start
    offsets = [float((lc.start - first).sec) for lc in curves]
    try:
        obs = Observations.combine(parts, offsets_s=offsets)
    except ObservationsError as exc:
        raise LightCurveFileError(str(exc)) from None
    if len(obs) > 1:
        same = torch.nonzero(torch.diff(obs.t) <= 0).flatten()
        if same.numel():
            k = int(same[0])
            names = {obs.curves[int(obs.curve[i])].source for i in (k, k + 1)}
            raise LightCurveFileError(f"{' and '.join(sorted(names))}: two samples at the same time "
                                      f"{float(obs.t[k]):.6f} s after {iso_times(first)}; the estimators step from "
                                      f"sample to sample (drop or merge one)")
    return obs
