"""The time column of a light-curve file: UTC text, seconds from an epoch, or MJD, checked before anything uses it.

A time column holds one of:

* text — UTC times in any form astropy's ``Time`` reads (``2025-01-01T00:00:00.000``, ``2025-01-01 00:00:00``,
  ``2025-01-01T00:00:00Z``...), all in one form (read at once) or mixed (read one by one);
* numbers with an ``epoch`` — seconds from that UTC time (text in any such form, or a YAML date/datetime: an
  unquoted ``2025-01-01T00:00:00`` in a CSV comment line or an ECSV header is one);
* numbers with ``time_format: mjd`` — MJD (UTC).

Numbers with neither are refused (:class:`TimeColumnError`): the likeliest hand-written file gives seconds, and
seconds read as days put a 600 s light curve 600 days long in the 19th century, where ERFA warns of a "dubious
year" at every step and the known-spin propagation through 600 days runs for hours. For the same reason every time
must lie in :data:`YEARS` and the whole curve within :data:`MAX_SPAN_DAYS` of its first sample; both are checked
here, before any geometry or dynamics. Times are returned as seconds from the first sample rounded to the
microsecond.

Messages name the row through ``where(i)`` (the reader's "line N" or "row N") and never the file: the reader
(:mod:`lightcurve_gp.observed.lightcurve_file`) prefixes it.
"""

from __future__ import annotations

import datetime
import warnings
from typing import Callable

import numpy as np
from astropy.time import Time, TimeDelta

__all__ = ["TimeColumnError", "MAX_SPAN_DAYS", "NUMERIC_TIME_FORMATS", "YEARS", "read_time", "read_epoch",
           "parse_time_column", "check_order", "check_span"]

#: the longest light curve read (days): one object's observation over nights or passes, not a catalogue
MAX_SPAN_DAYS = 14.0
#: the years a sample time may lie in: from the first artificial satellite to the end of ERFA's trusted range
YEARS = (1957, 2100)
#: the values of the ``time_format`` metadata (both for numeric times)
NUMERIC_TIME_FORMATS = ("seconds", "mjd")

Where = Callable[[int], str]


class TimeColumnError(ValueError):
    """A time column or epoch that cannot be used: one line naming the row or metadata and the problem."""


def read_time(value) -> Time:
    """One UTC time in any form astropy's ``Time`` reads, or a ``datetime.date``/``datetime`` (what YAML makes of an
    unquoted ISO time); ``ValueError`` when it is none of them."""
    if isinstance(value, datetime.date) and not isinstance(value, datetime.datetime):
        value = value.isoformat()
    if not isinstance(value, (str, datetime.datetime)):
        raise ValueError(f"{value!r} is not a time")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ERFA's "dubious year": the year is checked by the caller
        return Time(value.strip() if isinstance(value, str) else value, scale="utc")


def read_epoch(value) -> Time:
    """The ``epoch`` metadata as a UTC ``Time`` (scalar), its year in :data:`YEARS`; :class:`TimeColumnError`."""
    try:
        epoch = read_time(value)
    except ValueError:
        raise TimeColumnError(f"metadata epoch: {str(value)!r} is not a UTC time astropy reads (e.g. "
                              f"2025-01-01T00:00:00 or 2025-01-01 00:00:00)") from None
    _check_years(epoch, [repr(str(value))], lambda i: "metadata epoch")
    return epoch


def parse_time_column(column, meta: dict, where: Where) -> tuple[Time, np.ndarray, str]:
    """``(start, t (N,) seconds from start, time_format)`` of a time column (module docstring).

    Args:
        column: an astropy ``Time`` column, or an array ``(N,)`` of text or numbers.
        meta: the file's metadata: ``epoch`` (a ``Time``, :func:`read_epoch`) and ``time_format`` when given.
        where: names row ``i`` in messages.

    Returns:
        ``time_format`` is ``"iso"`` (text or a ``Time`` column), ``"seconds"`` or ``"mjd"``.
    """
    if isinstance(column, Time):  # an ECSV/FITS column astropy already reads as times
        return _relative(column.utc, "iso")
    raw = np.asarray(column)
    if raw.dtype.kind in "US":
        if "time_format" in meta:
            raise TimeColumnError(f"metadata time_format: {meta['time_format']!r} is for numeric times; the time "
                                  f"column holds text (UTC times), leave time_format out")
        return _relative(_text_times(raw, where), "iso")
    values = np.asarray(raw, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise TimeColumnError(f"{where(int(bad[0]))}: time {values[bad[0]]} is not finite")
    time_format = meta.get("time_format", "seconds" if "epoch" in meta else None)
    if time_format == "mjd":
        if "epoch" in meta:
            raise TimeColumnError("metadata epoch: given with time_format: mjd; MJD times need no epoch, give one of "
                                  "them")
        _check_mjd(values, where)
        return _relative(Time(values, format="mjd", scale="utc"), "mjd")
    if "epoch" not in meta:
        raise TimeColumnError(
            f"column time: numbers without an epoch (the first is {values[0]:g}); give the UTC time of t = 0 as an "
            f"epoch metadata line (CSV: '# epoch: 2025-01-01T00:00:00', ECSV: meta epoch, FITS: header card EPOCH) "
            f"for seconds from it, or say 'time_format: mjd' if the numbers are MJD (UTC)")
    return meta["epoch"] + TimeDelta(values[0], format="sec"), values - values[0], "seconds"


def _relative(times: Time, time_format: str) -> tuple[Time, np.ndarray, str]:
    """``(first time, seconds from it rounded to the microsecond, time_format)``."""
    return times[0], np.round((times - times[0]).sec * 1e6) / 1e6, time_format


def _text_times(raw: np.ndarray, where: Where) -> Time:
    """The text times of a column: all at once when they share a form, else one by one (naming a bad one)."""
    texts = [str(s).strip() for s in raw]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            times = Time(texts, scale="utc")
    except ValueError:
        parsed = []
        for i, text in enumerate(texts):
            try:
                parsed.append(read_time(text))
            except ValueError:
                raise TimeColumnError(f"{where(i)}: time {text!r} is not a UTC time astropy reads (e.g. "
                                      f"2025-01-01T00:00:00.000)") from None
        times = Time(parsed)
    _check_years(times, [repr(t) for t in texts], where)
    return times


def _check_years(times: Time, shown: list[str], where: Where) -> None:
    """Every time in :data:`YEARS` (``shown[i]`` is time ``i`` as the message writes it)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        years = np.atleast_1d(times.utc.decimalyear)
    bad = np.flatnonzero((years < YEARS[0]) | (years >= YEARS[1] + 1))
    if bad.size:
        i = int(bad[0])
        raise TimeColumnError(f"{where(i)}: time {shown[i]} is in {int(years[i])}, outside {YEARS[0]}-{YEARS[1]}")


def _check_mjd(values: np.ndarray, where: Where) -> None:
    """MJD values in :data:`YEARS`; the message says what a value out of range would be as a date."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ERFA's "dubious year" for 2101
        lo, hi = (Time(f"{year}-01-01", scale="utc").mjd for year in (YEARS[0], YEARS[1] + 1))
    bad = np.flatnonzero((values < lo) | (values >= hi))
    if bad.size:
        i = int(bad[0])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                day = f"is {Time(values[i], format='mjd', scale='utc').strftime('%Y-%m-%d')}"
            except ValueError:  # beyond the dates astropy formats
                day = "is no date"
        raise TimeColumnError(f"{where(i)}: time {values[i]:g} as MJD {day}, outside {YEARS[0]}-{YEARS[1]}: are "
                              f"these seconds? Then give an epoch instead of time_format: mjd")


def check_order(t: np.ndarray, shown, where: Where) -> None:
    """Strictly increasing times ``t (N,)`` (``shown[i]``: sample ``i`` as the file writes it)."""
    step = np.diff(t)
    bad = np.flatnonzero(step <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        problem = "repeats the time of the sample before (duplicate time)" if step[i - 1] == 0 else \
            "is earlier than the sample before (times must increase)"
        raise TimeColumnError(f"{where(i)}: time {str(shown[i]).strip()} {problem}")


def check_span(t: np.ndarray, shown, numeric: bool, where: Where) -> None:
    """The whole curve ``t (N,)`` (s from its first sample) within :data:`MAX_SPAN_DAYS`; ``numeric``: the file gave
    numbers (the message then asks for their unit)."""
    bad = np.flatnonzero(t > MAX_SPAN_DAYS * 86400.0)
    if bad.size:
        i = int(bad[0])
        hint = ("check the unit of the time column: seconds from the epoch, or MJD days with time_format: mjd"
                if numeric else "split it into one file per night or pass")
        raise TimeColumnError(f"{where(i)}: time {str(shown[i]).strip()} is {t[i] / 86400:.1f} days after the "
                              f"first sample; a light curve longer than {MAX_SPAN_DAYS:g} days is refused ({hint})")
