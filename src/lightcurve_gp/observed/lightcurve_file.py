"""The light-curve file: one object's observed magnitudes, read and written with ``astropy.table``.

Formats by suffix: ``.ecsv`` (metadata in the YAML header), ``.csv`` (metadata as ``# key: value`` comment lines
before the column names; as a spreadsheet saves it too, with a byte-order mark, CRLF line ends or ``;`` between the
columns and decimal commas: :mod:`lightcurve_gp.observed.text_tables`) and ``.fits``/``.fit`` (metadata as header
cards). Columns:

* ``time`` — UTC times as text in any form astropy's ``Time`` reads (``2025-01-01T00:00:00.000``,
  ``2025-01-01 00:00:00``...), or numbers: seconds from the metadata's ``epoch`` (a UTC time in any such form, quoted
  or not), or MJD (UTC) when the metadata says ``time_format: mjd``. Numbers with neither are refused: seconds read
  as days would put a 600 s light curve 600 days long in the 19th century. Strictly increasing; gaps and irregular
  steps are normal. Every time must lie in :data:`YEARS` and the whole curve within :data:`MAX_SPAN_DAYS`, checked
  before anything is computed from them (:mod:`lightcurve_gp.observed.times`).
* ``mag`` — apparent magnitude; finite and ``|mag| ≤ 40``.
* ``mag_err`` (optional) — 1σ of ``mag`` (mag, > 0): the filter's measurement variance per sample is ``mag_err²``.
* per-sample geometry (optional, all seven or none): ``sun_x, sun_y, sun_z`` and ``obs_x, obs_y, obs_z`` (unit
  vectors object → Sun and object → observer, inertial frame GCRS) and ``range_km`` (object–observer distance).

Metadata (all optional): ``site_lat_deg``, ``site_lon_deg``, ``site_alt_m`` (the observing site, geodetic WGS84),
``tle_line1``, ``tle_line2`` (the object's two-line elements), ``band`` (filter band), ``epoch`` and
``time_format`` (``seconds`` or ``mjd``; see ``time``).
A file gives per-sample geometry or a TLE, not both; every sample of a file with a TLE must lie within
:data:`TLE_VALIDITY_DAYS` of the TLE's epoch.

Every problem is one :class:`LightCurveFileError` line naming the file, the line (text formats; ``row`` in FITS)
or the column, and what is wrong. Times inside the toolkit are seconds from the first sample, rounded to the
microsecond (the resolution of the ISO strings the writer produces), so a written file reads back exactly.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from astropy.table import Table
from astropy.time import Time, TimeDelta
from sgp4.api import Satrec

from lightcurve_gp.files import atomic_path
from lightcurve_gp.observed.table_units import ISO_UTC, set_units
from lightcurve_gp.observed.table_write import write_table
from lightcurve_gp.observed.text_tables import DECIMAL_COMMA, csv_dialect, data_line_numbers, decimal_points, text_lines
from lightcurve_gp.observed.times import (
    MAX_SPAN_DAYS,
    NUMERIC_TIME_FORMATS,
    YEARS,
    TimeColumnError,
    check_order,
    check_span,
    parse_time_column,
    read_epoch,
)
from lightcurve_gp.passes.orbit import check_tle

__all__ = ["LightCurve", "LightCurveFileError", "GEOMETRY_COLUMNS", "MAG_LIMIT", "MAX_SPAN_DAYS",
           "TLE_VALIDITY_DAYS", "YEARS", "iso_times", "light_curve_format", "light_curve_table", "read_light_curve",
           "tle_epoch", "write_light_curve"]

GEOMETRY_COLUMNS = ("sun_x", "sun_y", "sun_z", "obs_x", "obs_y", "obs_z", "range_km")
#: the units a written light-curve file gives its columns (:mod:`~lightcurve_gp.observed.table_units`); ``time``'s
#: follows the time format (ISO strings carry a description instead)
LIGHT_CURVE_UNITS = {"mag": "mag", "mag_err": "mag", **{c: "" for c in GEOMETRY_COLUMNS[:6]}, "range_km": "km"}
TIME_UNITS = {"iso": ("", ISO_UTC), "mjd": ("d", "MJD (UTC)"), "seconds": ("s", "seconds from the epoch (metadata)")}
SITE_KEYS = ("site_lat_deg", "site_lon_deg", "site_alt_m")
META_KEYS = (*SITE_KEYS, "tle_line1", "tle_line2", "band", "epoch", "time_format")
#: an apparent magnitude beyond this is not an observation (the Sun is −26.7)
MAG_LIMIT = 40.0
#: how far from its epoch a TLE is used (days)
TLE_VALIDITY_DAYS = 14.0
FORMATS = {".ecsv": "ascii.ecsv", ".csv": "ascii.csv", ".fits": "fits", ".fit": "fits"}


class LightCurveFileError(ValueError):
    """A light-curve file that cannot be used: one line naming the file, the line or column and the problem."""


@dataclass
class LightCurve:
    """An observed light curve.

    Attributes:
        start: UTC time of the first sample (astropy ``Time``, scalar).
        t: sample times ``(N,)`` in seconds from ``start`` (float64, microsecond resolution, strictly increasing).
        mag: magnitudes ``(N,)``; mag_err: their 1σ ``(N,)`` or ``None``.
        geometry: ``{"sun": (N, 3), "obs": (N, 3), "range_km": (N,)}`` or ``None``.
        meta: the metadata of :data:`META_KEYS` that the file gives (site, TLE, band; ``epoch`` as ISO UTC text
            with microseconds when ``time`` was seconds from it).
        time_format: how ``time`` was given: ``"iso"``, ``"mjd"`` or ``"seconds"``.
        source: the file it came from (for messages).
    """

    start: Time
    t: np.ndarray
    mag: np.ndarray
    mag_err: np.ndarray | None = None
    geometry: dict[str, np.ndarray] | None = None
    meta: dict = field(default_factory=dict)
    time_format: str = "iso"
    source: str = ""

    @property
    def times(self) -> Time:
        """UTC times of the samples ``(N,)``."""
        return self.start + TimeDelta(self.t, format="sec")

    @property
    def has_tle(self) -> bool:
        return "tle_line1" in self.meta

    @property
    def site(self) -> tuple[float, float, float] | None:
        """``(lat_deg, lon_deg, alt_m)`` of the site, or ``None``."""
        return tuple(float(self.meta[k]) for k in SITE_KEYS) if SITE_KEYS[0] in self.meta else None


def light_curve_format(path: str | Path) -> str:
    """The astropy format of ``path``'s suffix; :class:`LightCurveFileError` for an unknown suffix."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise LightCurveFileError(f"{path}: unknown light-curve format {suffix or '(no suffix)'!r} "
                                  f"(use {', '.join(FORMATS)})")
    return FORMATS[suffix]


# ---------------------------------------------------------------------------------------------------- writing

def iso_times(times: Time):
    """ISO UTC strings with microseconds (the resolution of :attr:`LightCurve.t`)."""
    return Time(times.utc, precision=6).isot


def light_curve_table(lc: LightCurve, time_format: str = "iso") -> Table:
    """``lc`` as an astropy table with ``time`` given as ``time_format`` (:func:`write_light_curve`)."""
    if time_format == "iso":
        time = iso_times(lc.times)
    elif time_format == "mjd":
        time = lc.times.utc.mjd
    elif time_format == "seconds":
        time = np.asarray(lc.t, dtype=np.float64)
    else:
        raise ValueError(f"time_format must be iso, mjd or seconds, got {time_format!r}")
    cols = {"time": time, "mag": np.asarray(lc.mag, dtype=np.float64)}
    if lc.mag_err is not None:
        cols["mag_err"] = np.asarray(lc.mag_err, dtype=np.float64)
    if lc.geometry is not None:
        for i, axis in enumerate("xyz"):
            cols[f"sun_{axis}"] = lc.geometry["sun"][:, i]
            cols[f"obs_{axis}"] = lc.geometry["obs"][:, i]
        cols["range_km"] = lc.geometry["range_km"]
    table = Table({name: cols[name] for name in ("time", "mag", "mag_err", *GEOMETRY_COLUMNS) if name in cols})
    meta = {k: v for k, v in lc.meta.items() if k not in ("epoch", "time_format")}
    if time_format == "seconds":
        meta["epoch"] = iso_times(lc.start)
    elif time_format == "mjd":
        meta["time_format"] = "mjd"
    table.meta.update(meta)
    unit, description = TIME_UNITS[time_format]
    return set_units(table, {"time": unit, **LIGHT_CURVE_UNITS}, {"time": description})


def write_light_curve(lc: LightCurve, path: str | Path, *, time_format: str = "iso") -> Path:
    """Write ``lc`` to ``path`` atomically in the format of its suffix; ``time_format`` is ``"iso"`` (ISO UTC with
    microseconds), ``"mjd"`` or ``"seconds"`` (from ``lc.start``, written as the ``epoch`` metadata)."""
    path = Path(path)
    fmt = light_curve_format(path)
    table = light_curve_table(lc, time_format)
    with atomic_path(path) as tmp:
        write_table(table, tmp, fmt=fmt)
    return path


# ---------------------------------------------------------------------------------------------------- reading

class _Locator:
    """Names a data row of the file: ``line N`` of a text file (comments and blank lines counted), ``row N`` of a
    FITS table."""

    def __init__(self, path: Path, fmt: str):
        self.lines: list[int] | None = None
        if fmt.startswith("ascii"):
            self.lines = data_line_numbers(text_lines(path))[1:]  # the first is the column names

    def __call__(self, row: int) -> str:
        if self.lines is not None and row < len(self.lines):
            return f"line {self.lines[row]}"
        return f"row {row + 1}"


def _read_table(path: Path, fmt: str) -> Table:
    if not path.is_file():
        raise LightCurveFileError(f"{path}: no such light-curve file")
    if path.stat().st_size == 0:
        raise LightCurveFileError(f"{path}: empty file (no samples)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if fmt == "ascii.csv":
                lines = text_lines(path)
                dialect = csv_dialect(lines)
                table = Table.read(decimal_points(lines, dialect), format=fmt, comment="#",
                                   delimiter=dialect.delimiter)
            elif fmt.startswith("ascii"):
                table = Table.read(text_lines(path), format=fmt)
            else:
                table = Table.read(path, format=fmt)
    except Exception as exc:  # astropy raises many kinds for a damaged file; one line says which file and why
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise LightCurveFileError(f"{path}: not a readable {fmt.removeprefix('ascii.').upper()} table "
                                  f"({reason})") from None
    if fmt == "ascii.csv":
        table.meta = _csv_meta(path, table.meta.get("comments", []))
    return table


def _csv_meta(path: Path, comments: list[str]) -> dict:
    meta = {}
    for text in comments:
        key, sep, value = text.partition(":")
        if not sep:
            continue
        try:
            meta[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise LightCurveFileError(f"{path}: metadata {key.strip()}: cannot parse {value.strip()!r}") from None
    return meta


def _column(table: Table, name: str) -> np.ndarray:
    col = table[name]
    data = np.ma.filled(col, np.nan) if col.dtype.kind == "f" and np.ma.is_masked(col) else np.asarray(col)
    if data.dtype.kind == "S":
        data = np.char.decode(data, "utf-8")
    return data


def _float_column(table: Table, name: str, path: Path, where: _Locator) -> np.ndarray:
    raw = table[name]
    if raw.dtype.kind not in "fiu":
        values = _column(table, name)
        for i, v in enumerate(values):
            try:
                float(v)
            except (TypeError, ValueError):
                hint = (" (a decimal comma: write a point, or separate the columns with ';' to have decimal commas "
                        "read)" if DECIMAL_COMMA.match(str(v)) else "")
                raise LightCurveFileError(f"{path}: {where(i)}: {name} {str(v)!r} is not a number{hint}") from None
        return values.astype(np.float64)
    return np.asarray(_column(table, name), dtype=np.float64)


def _check_mags(mag: np.ndarray, mag_err: np.ndarray | None, path: Path, where: _Locator) -> None:
    bad = np.flatnonzero(~np.isfinite(mag))
    if bad.size:
        raise LightCurveFileError(f"{path}: {where(int(bad[0]))}: mag is {mag[bad[0]]} (every sample needs a "
                                  f"finite magnitude; leave a missing sample out)")
    bad = np.flatnonzero(np.abs(mag) > MAG_LIMIT)
    if bad.size:
        raise LightCurveFileError(f"{path}: {where(int(bad[0]))}: mag {mag[bad[0]]:g} is absurd (|mag| > "
                                  f"{MAG_LIMIT:g})")
    if mag_err is None:
        return
    bad = np.flatnonzero(~(mag_err > 0))
    if bad.size:
        value = mag_err[bad[0]]
        problem = "is negative" if value < 0 else "must be > 0"
        raise LightCurveFileError(f"{path}: {where(int(bad[0]))}: mag_err {value:g} {problem}")


def _geometry(table: Table, path: Path, where: _Locator) -> dict[str, np.ndarray] | None:
    present = [c for c in GEOMETRY_COLUMNS if c in table.colnames]
    if not present:
        return None
    missing = [c for c in GEOMETRY_COLUMNS if c not in table.colnames]
    if missing:
        raise LightCurveFileError(f"{path}: column {missing[0]}: missing (per-sample geometry needs all of "
                                  f"{', '.join(GEOMETRY_COLUMNS)}; the file has {', '.join(present)})")
    cols = {c: _float_column(table, c, path, where) for c in GEOMETRY_COLUMNS}
    for c in GEOMETRY_COLUMNS:
        bad = np.flatnonzero(~np.isfinite(cols[c]))
        if bad.size:
            raise LightCurveFileError(f"{path}: {where(int(bad[0]))}: {c} is {cols[c][bad[0]]}")
    geometry = {"sun": np.stack([cols[f"sun_{a}"] for a in "xyz"], -1),
                "obs": np.stack([cols[f"obs_{a}"] for a in "xyz"], -1), "range_km": cols["range_km"]}
    for name in ("sun", "obs"):
        norm = np.linalg.norm(geometry[name], axis=-1)
        bad = np.flatnonzero(np.abs(norm - 1.0) > 1e-3)
        if bad.size:
            raise LightCurveFileError(f"{path}: {where(int(bad[0]))}: ({name}_x, {name}_y, {name}_z) has length "
                                      f"{norm[bad[0]]:.6g}, not a unit vector")
    bad = np.flatnonzero(~(geometry["range_km"] > 0))
    if bad.size:
        raise LightCurveFileError(f"{path}: {where(int(bad[0]))}: range_km {geometry['range_km'][bad[0]]:g} "
                                  f"must be > 0")
    return geometry


def tle_epoch(line1: str, line2: str, path: Path | str = "") -> Time:
    """UTC epoch of a TLE after checking its two lines (numbers, lengths, checksums, parse by sgp4)."""

    for number, line in ((1, line1), (2, line2)):
        try:
            check_tle(line, number)
        except ValueError as exc:
            raise LightCurveFileError(f"{path}: metadata tle_line{number}: {exc} (a damaged TLE)") from None
    try:
        sat = Satrec.twoline2rv(line1, line2)
    except ValueError as exc:
        raise LightCurveFileError(f"{path}: metadata tle_line1/tle_line2: not a valid TLE ({exc})") from None
    return Time(sat.jdsatepoch, sat.jdsatepochF, format="jd", scale="utc")


def _check_meta(meta: dict, path: Path) -> dict:
    out = {k: meta[k] for k in META_KEYS if k in meta and meta[k] is not None}
    site = [k for k in SITE_KEYS if k in out]
    if site and len(site) != len(SITE_KEYS):
        missing = next(k for k in SITE_KEYS if k not in out)
        raise LightCurveFileError(f"{path}: metadata {missing}: missing (a site needs {', '.join(SITE_KEYS)})")
    limits = {"site_lat_deg": (-90.0, 90.0), "site_lon_deg": (-180.0, 360.0), "site_alt_m": (-500.0, 1e5)}
    for key in site:
        lo, hi = limits[key]
        try:
            value = float(out[key])
        except (TypeError, ValueError):
            raise LightCurveFileError(f"{path}: metadata {key}: {out[key]!r} is not a number") from None
        if not (math.isfinite(value) and lo <= value <= hi):
            raise LightCurveFileError(f"{path}: metadata {key}: {value:g} is outside [{lo:g}, {hi:g}]")
        out[key] = value
    if ("tle_line1" in out) != ("tle_line2" in out):
        missing = "tle_line2" if "tle_line1" in out else "tle_line1"
        raise LightCurveFileError(f"{path}: metadata {missing}: missing (a TLE needs tle_line1 and tle_line2)")
    for key in ("tle_line1", "tle_line2", "band"):
        if key in out:
            out[key] = str(out[key])
    if "time_format" in out and out["time_format"] not in NUMERIC_TIME_FORMATS:
        raise LightCurveFileError(f"{path}: metadata time_format: {out['time_format']!r} is not one of "
                                  f"{', '.join(NUMERIC_TIME_FORMATS)}")
    if "epoch" in out:
        out["epoch"] = read_epoch(out["epoch"])
    return out


def _check_tle_span(meta: dict, times: Time, raw_time, path: Path, where: _Locator) -> None:
    epoch = tle_epoch(meta["tle_line1"], meta["tle_line2"], path)
    days = (times - epoch).jd
    bad = np.flatnonzero(np.abs(days) > TLE_VALIDITY_DAYS)
    if bad.size:
        i = int(bad[0])
        raise LightCurveFileError(f"{path}: {where(i)}: time {str(raw_time[i]).strip()} is {days[i]:+.1f} days "
                                  f"from the TLE epoch {epoch.isot}, outside its validity (±{TLE_VALIDITY_DAYS:g} "
                                  f"days)")


def read_light_curve(path: str | Path) -> LightCurve:
    """Read and check a light-curve file (module docstring); every problem is a :class:`LightCurveFileError`."""
    path = Path(path)
    fmt = light_curve_format(path)
    table = _read_table(path, fmt)
    if len(table) == 0:
        raise LightCurveFileError(f"{path}: no samples (the table has no rows)")
    for name in ("time", "mag"):
        if name not in table.colnames:
            raise LightCurveFileError(f"{path}: column {name}: missing (the file has columns "
                                      f"{', '.join(table.colnames) or 'none'})")
    where = _Locator(path, fmt)
    try:
        meta = _check_meta({str(k).lower(): v for k, v in table.meta.items()}, path)
        time_column = table["time"] if isinstance(table["time"], Time) else _column(table, "time")
        start, t, time_format = parse_time_column(time_column, meta, where)
        raw_time = time_column.isot if isinstance(time_column, Time) else time_column
        check_order(t, raw_time, where)
        check_span(t, raw_time, time_format != "iso", where)
    except TimeColumnError as exc:
        raise LightCurveFileError(f"{path}: {exc}") from None
    mag = _float_column(table, "mag", path, where)
    mag_err = _float_column(table, "mag_err", path, where) if "mag_err" in table.colnames else None
    _check_mags(mag, mag_err, path, where)
    geometry = _geometry(table, path, where)
    if geometry is not None and "tle_line1" in meta:
        raise LightCurveFileError(f"{path}: column sun_x: the file gives both per-sample geometry and a TLE; "
                                  f"give one of them")
    if "tle_line1" in meta:
        _check_tle_span(meta, start + TimeDelta(t, format="sec"), raw_time, path, where)
    meta.pop("time_format", None)
    if time_format == "seconds":
        meta["epoch"] = iso_times(meta["epoch"])
    else:
        meta.pop("epoch", None)
    return LightCurve(start=start, t=t, mag=mag, mag_err=mag_err, geometry=geometry, meta=meta,
                      time_format=time_format, source=str(path))
