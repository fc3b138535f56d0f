"""The DAMIT / convexinv light-curve format, read into and written from :class:`Observations`.

The format (plain text, whitespace separated; the example data of the DAMIT inversion software)::

    37                                   number of light curves
    81 0                                 points in this light curve, 0 = relative / 1 = calibrated
    JD  brightness  sun_x sun_y sun_z  earth_x earth_y earth_z      one line per point
    ...

``JD`` is the light-time corrected Julian date (TDB/UTC differences of a minute are irrelevant here and are not
applied: the epoch is read as UTC); ``brightness`` an intensity (not a magnitude); the vectors point from the
object to the Sun and to the Earth in the ecliptic J2000 frame (au). A curve with flag 0 is *relative*: only the
ratios within it mean anything (:attr:`CurveInfo.relative`).

Reading: the intensity ``I`` becomes ``m = −2.5 log10 I``; the epoch is the first JD (ISO UTC, astropy ``Time``
format ``"jd"``) and ``t`` the seconds from it (float64: microseconds over decades); the vectors become unit
vectors ``sun``, ``observer`` (ecliptic J2000, as every estimator of asteroid data takes them) with their lengths in
``sun_range_m``, ``range_m``. The format has no 1σ: every sample gets ``sigma_mag`` (default
:data:`DEFAULT_SIGMA_MAG`). The samples are put in time order (the file need not be); each keeps its light curve.

Every malformed input is one :class:`~lightcurve_gp.observed.lightcurve_file.LightCurveFileError` line naming the
file and the line: a wrong count, a short row, a non-number, a non-positive brightness, a zero vector, a file that
ends early or goes on after the last curve.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from astropy.time import Time

from lightcurve_gp.files import atomic_path
from lightcurve_gp.observations.observations import CurveInfo, Observations
from lightcurve_gp.observed.lightcurve_file import LightCurveFileError

__all__ = ["AU_M", "DEFAULT_SIGMA_MAG", "OBLIQUITY_J2000_RAD", "equatorial_to_ecliptic", "read_damit", "write_damit",
           "is_damit_file"]

#: the astronomical unit (m, IAU 2012)
AU_M = 149_597_870_700.0
#: the 1σ every sample of a DAMIT file gets (mag): the format has none
DEFAULT_SIGMA_MAG = 0.01
SECONDS_PER_DAY = 86_400.0
#: the mean obliquity of the ecliptic at J2000 (IAU 2006: 84381.406″), rad
OBLIQUITY_J2000_RAD = math.radians(84381.406 / 3600.0)


def equatorial_to_ecliptic(v: np.ndarray) -> np.ndarray:
    """Vectors ``(…, 3)`` in the J2000 equatorial frame (the GCRS: its 23 mas frame bias is ignored) in the
    ecliptic J2000 frame of this format: a rotation by the obliquity about the common ``x`` axis (the equinox)."""
    c, s = math.cos(OBLIQUITY_J2000_RAD), math.sin(OBLIQUITY_J2000_RAD)
    return np.stack([v[..., 0], c * v[..., 1] + s * v[..., 2], -s * v[..., 1] + c * v[..., 2]], -1)


def _numbers(text: str, path: Path, line: int, expected: int, what: str) -> list[float]:
    fields = text.split()
    if len(fields) != expected:
        raise LightCurveFileError(f"{path}: line {line}: expected {expected} numbers ({what}), got {len(fields)}")
    try:
        values = [float(f) for f in fields]
    except ValueError:
        bad = next(f for f in fields if not _is_number(f))
        raise LightCurveFileError(f"{path}: line {line}: {bad!r} is not a number ({what})") from None
    if not all(math.isfinite(v) for v in values):
        raise LightCurveFileError(f"{path}: line {line}: a value is not finite ({what})")
    return values


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _integer(value: float, path: Path, line: int, what: str, lo: int) -> int:
    if value != int(value) or value < lo:
        raise LightCurveFileError(f"{path}: line {line}: {what} must be an integer >= {lo}, got {value:g}")
    return int(value)


def is_damit_file(path: str | Path) -> bool:
    """Whether ``path`` looks like a DAMIT light-curve file: no table suffix, a first non-blank line of one integer
    (the number of light curves) and a second of two (points, flag)."""
    path = Path(path)
    if path.suffix.lower() in (".ecsv", ".csv", ".fits", ".fit") or not path.is_file():
        return False
    try:
        with open(path, encoding="utf-8") as fh:
            head = [line.split() for line, _ in zip((ln for ln in fh if ln.strip()), range(2))]
    except (OSError, UnicodeDecodeError):
        return False
    return len(head) == 2 and len(head[0]) == 1 and len(head[1]) == 2 and all(
        f.lstrip("-").isdigit() for f in head[0] + head[1])


def read_damit(path: str | Path, *, sigma_mag: float = DEFAULT_SIGMA_MAG) -> Observations:
    """Read a DAMIT light-curve file (module docstring) into :class:`Observations`.

    Args:
        path: the file.
        sigma_mag: the 1σ of every sample (mag, > 0).

    Returns:
        the observations: ``C`` curves (named ``"<file name> #k"``, k from 1), ``N`` samples in time order.
    """
    path = Path(path)
    if not sigma_mag > 0:
        raise LightCurveFileError(f"{path}: sigma_mag {sigma_mag:g} must be > 0 mag")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise LightCurveFileError(f"{path}: cannot read ({exc.__class__.__name__}: {exc})") from None
    lines = [(k + 1, ln) for k, ln in enumerate(text.splitlines()) if ln.strip()]
    if not lines:
        raise LightCurveFileError(f"{path}: empty file (expected the number of light curves on line 1)")
    pos = 0
    line_no, ln = lines[pos]
    count = _integer(_numbers(ln, path, line_no, 1, "the number of light curves")[0], path, line_no,
                     "the number of light curves", 1)
    pos += 1
    rows, curve, curves = [], [], []
    for c in range(count):
        if pos >= len(lines):
            raise LightCurveFileError(f"{path}: line {lines[-1][0] + 1}: the file ends after {c} of {count} light "
                                      f"curves (expected the header 'points flag' of light curve {c + 1})")
        line_no, ln = lines[pos]
        points, flag = _numbers(ln, path, line_no, 2, f"the header 'points flag' of light curve {c + 1}")
        points = _integer(points, path, line_no, "the number of points", 1)
        if flag not in (0.0, 1.0):
            raise LightCurveFileError(f"{path}: line {line_no}: the flag must be 0 (relative) or 1 (calibrated), "
                                      f"got {flag:g}")
        pos += 1
        curves.append(CurveInfo(source=f"{path.name} #{c + 1}", relative=flag == 0.0))
        for j in range(points):
            if pos >= len(lines):
                raise LightCurveFileError(f"{path}: line {lines[-1][0] + 1}: the file ends after {j} of {points} "
                                          f"points of light curve {c + 1}")
            line_no, ln = lines[pos]
            values = _numbers(ln, path, line_no, 8, "JD brightness sun_x sun_y sun_z earth_x earth_y earth_z")
            if not values[1] > 0:
                raise LightCurveFileError(f"{path}: line {line_no}: brightness {values[1]:g} must be > 0 (an "
                                          f"intensity, not a magnitude)")
            for name, vec in (("Sun", values[2:5]), ("Earth", values[5:8])):
                if math.hypot(*vec) == 0.0:
                    raise LightCurveFileError(f"{path}: line {line_no}: the {name} vector is zero")
            rows.append(values)
            curve.append(c)
            pos += 1
    if pos < len(lines):
        raise LightCurveFileError(f"{path}: line {lines[pos][0]}: more lines after the {count} light curves the "
                                  f"first line announces")
    data = np.asarray(rows, dtype=np.float64)
    order = np.argsort(data[:, 0], kind="stable")
    data, curve = data[order], np.asarray(curve, dtype=np.int64)[order]
    jd0 = data[0, 0]
    epoch = Time(jd0, format="jd", scale="utc").isot
    sun_au = np.linalg.norm(data[:, 2:5], axis=1)
    obs_au = np.linalg.norm(data[:, 5:8], axis=1)
    f64 = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float64)  # noqa: E731
    return Observations(t=f64((data[:, 0] - jd0) * SECONDS_PER_DAY), mag=f64(-2.5 * np.log10(data[:, 1])),
                        sigma=torch.full((data.shape[0],), float(sigma_mag), dtype=torch.float64),
                        curve=torch.as_tensor(curve), curves=tuple(curves),
                        sun=f64(data[:, 2:5] / sun_au[:, None]), observer=f64(data[:, 5:8] / obs_au[:, None]),
                        range_m=f64(obs_au * AU_M), sun_range_m=f64(sun_au * AU_M), epoch=epoch)


def write_damit(obs: Observations, path: str | Path) -> Path:
    """Write ``obs`` (with per-sample geometry and an epoch) as a DAMIT light-curve file (atomically).

    Each light curve is one block, its samples in time order; brightness ``10^(−0.4 m)``; vectors in au (an absent
    ``sun_range_m`` is 1 au). A relative curve gets the flag 0, any other 1. Raises ``ValueError`` for observations
    without geometry or epoch."""
    path = Path(path)
    if not obs.has_geometry or obs.epoch is None:
        raise ValueError(f"{path}: DAMIT files need per-sample geometry and an epoch")
    jd = Time(obs.epoch, scale="utc").jd + obs.t.cpu().numpy() / SECONDS_PER_DAY
    intensity = 10.0 ** (-0.4 * obs.mag.cpu().numpy())
    sun_r = np.full(len(obs), AU_M) if obs.sun_range_m is None else obs.sun_range_m.cpu().numpy()
    sun = obs.sun.cpu().numpy() * (sun_r / AU_M)[:, None]
    earth = obs.observer.cpu().numpy() * (obs.range_m.cpu().numpy() / AU_M)[:, None]
    curve = obs.curve.cpu().numpy()
    out = [f"{len(obs.curves)}"]
    for c, info in enumerate(obs.curves):
        idx = np.nonzero(curve == c)[0]
        out.append(f"{idx.size} {0 if info.relative else 1}")
        for i in idx:
            out.append(f"{jd[i]:.8f} {intensity[i]:.9e}   " + " ".join(f"{v:.9e}" for v in sun[i]) + "   "
                       + " ".join(f"{v:.9e}" for v in earth[i]))
    with atomic_path(path) as tmp:
        Path(tmp).write_text("\n".join(out) + "\n", encoding="utf-8")
    return path
