"""The light-curve file: round trips in every format and time encoding, and one exact message per bad file."""

import numpy as np
import pytest
from astropy.time import Time

from lightcurve_gp.observed.lightcurve_file import (
    LightCurve,
    LightCurveFileError,
    read_light_curve,
    tle_epoch,
    write_light_curve,
)

TLE1 = "1 25544U 98067A   19343.69339541  .00001764  00000-0  38792-4 0  9991"
TLE2 = "2 25544  51.6439 211.2001 0007417  17.6667  85.6398 15.50103472202482"
HEADER = "# %ECSV 1.0\n# ---\n# datatype:\n# - {name: time, datatype: string}\n# - {name: mag, datatype: float64}\n"


def curve(n=6, **kw):
    t = np.cumsum(np.r_[0.0, np.linspace(0.5, 3.25, n - 1)])  # irregular steps
    return LightCurve(start=Time("2019-12-10T01:02:03.25", scale="utc"), t=t, mag=13.0 + 0.1 * np.arange(n),
                      **kw)


@pytest.mark.parametrize("suffix", ["ecsv", "csv", "fits"])
@pytest.mark.parametrize("time_format", ["iso", "mjd", "seconds"])
def test_every_format_and_time_encoding_reads_back_what_was_written(tmp_path, suffix, time_format):
    lc = curve(mag_err=np.full(6, 0.25), meta={"band": "V", "site_lat_deg": 32.5, "site_lon_deg": -110.7,
                                               "site_alt_m": 2096.0, "tle_line1": TLE1, "tle_line2": TLE2})
    path = write_light_curve(lc, tmp_path / f"obs.{suffix}", time_format=time_format)
    back = read_light_curve(path)
    np.testing.assert_array_equal(back.t, lc.t)
    np.testing.assert_array_equal(back.mag, lc.mag)
    np.testing.assert_array_equal(back.mag_err, lc.mag_err)
    assert abs((back.start - lc.start).sec) < 1e-6
    assert back.time_format == time_format
    assert back.site == (32.5, -110.7, 2096.0) and back.meta["band"] == "V" and back.has_tle
    assert back.geometry is None


def test_geometry_columns_read_back(tmp_path):
    n = 6
    sun = np.tile([0.6, 0.0, 0.8], (n, 1))
    obs = np.tile([0.0, 1.0, 0.0], (n, 1))
    lc = curve(n, geometry={"sun": sun, "obs": obs, "range_km": np.linspace(900.0, 1200.0, n)})
    back = read_light_curve(write_light_curve(lc, tmp_path / "obs.ecsv"))
    for key in ("sun", "obs", "range_km"):
        np.testing.assert_array_equal(back.geometry[key], lc.geometry[key])


def test_writer_never_leaves_a_partial_file(tmp_path):
    path = tmp_path / "obs.ecsv"
    with pytest.raises(ValueError):
        write_light_curve(curve(), path, time_format="julian")
    assert list(tmp_path.iterdir()) == []


def test_tle_epoch_is_the_epoch_field():
    # 19343.69339541: day 343 of 2019 is December 9, 0.69339541 d = 16:38:29.363
    assert tle_epoch(TLE1, TLE2).isot == "2019-12-09T16:38:29.363"


def write(tmp_path, text, name="bad.ecsv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def iso_file(rows, meta=""):
    meta_block = f"# meta: !!omap\n{meta}" if meta else ""
    return HEADER + meta_block + "# schema: astropy-2.0\ntime mag\n" + "".join(f"{t} {m}\n" for t, m in rows)


GOOD = [("2019-12-10T00:00:00", 13.0), ("2019-12-10T00:00:01", 13.1), ("2019-12-10T00:00:02", 13.2)]


def message(path):
    with pytest.raises(LightCurveFileError) as info:
        read_light_curve(path)
    return str(info.value)


def test_empty_file(tmp_path):
    path = write(tmp_path, "")
    assert message(path) == f"{path}: empty file (no samples)"


def test_file_without_rows(tmp_path):
    path = write(tmp_path, iso_file([]))
    assert message(path) == f"{path}: no samples (the table has no rows)"


def test_missing_column(tmp_path):
    path = write(tmp_path, "time,magnitude\n2019-12-10T00:00:00,13.0\n", "bad.csv")
    assert message(path) == f"{path}: column mag: missing (the file has columns time, magnitude)"


def test_unparseable_time(tmp_path):
    rows = GOOD[:1] + [("2019-13-10T00:00:01", 13.1)] + GOOD[2:]
    path = write(tmp_path, iso_file(rows))
    assert message(path) == (f"{path}: line 9: time '2019-13-10T00:00:01' is not a UTC time astropy reads "
                             f"(e.g. 2025-01-01T00:00:00.000)")


def test_non_monotonic_time(tmp_path):
    rows = [GOOD[0], GOOD[2], GOOD[1]]
    path = write(tmp_path, iso_file(rows))
    assert message(path) == (f"{path}: line 10: time 2019-12-10T00:00:01 is earlier than the sample before "
                             f"(times must increase)")


def test_duplicate_time(tmp_path):
    rows = [GOOD[0], GOOD[1], (GOOD[1][0], 13.3)]
    path = write(tmp_path, iso_file(rows))
    assert message(path) == (f"{path}: line 10: time 2019-12-10T00:00:01 repeats the time of the sample before "
                             f"(duplicate time)")


def test_nan_magnitude(tmp_path):
    path = write(tmp_path, iso_file([GOOD[0], (GOOD[1][0], "nan"), GOOD[2]]))
    assert message(path) == (f"{path}: line 9: mag is nan (every sample needs a finite magnitude; leave a "
                             f"missing sample out)")


def test_absurd_magnitude(tmp_path):
    path = write(tmp_path, iso_file([GOOD[0], GOOD[1], (GOOD[2][0], 99.5)]))
    assert message(path) == f"{path}: line 10: mag 99.5 is absurd (|mag| > 40)"


def test_negative_mag_err(tmp_path):
    text = "time,mag,mag_err\n2019-12-10T00:00:00,13.0,0.2\n2019-12-10T00:00:01,13.1,-0.2\n"
    path = write(tmp_path, text, "bad.csv")
    assert message(path) == f"{path}: line 3: mag_err -0.2 is negative"


def test_text_in_a_number_column(tmp_path):
    text = "time,mag\n2019-12-10T00:00:00,13.0\n2019-12-10T00:00:01,bright\n"
    path = write(tmp_path, text, "bad.csv")
    assert message(path) == f"{path}: line 3: mag 'bright' is not a number"


def test_time_outside_the_tle_validity(tmp_path):
    meta = f"# - {{tle_line1: '{TLE1}'}}\n# - {{tle_line2: '{TLE2}'}}\n"
    rows = [("2019-12-20T00:00:00", 13.0), ("2019-12-22T00:00:00", 13.1), ("2019-12-24T00:00:00", 13.2)]
    path = write(tmp_path, iso_file(rows, meta))
    assert message(path) == (f"{path}: line 13: time 2019-12-24T00:00:00 is +14.3 days from the TLE epoch "
                             f"2019-12-09T16:38:29.363, outside its validity (±14 days)")


def test_damaged_tle(tmp_path):
    broken = TLE2[:20] + "9" + TLE2[21:]  # the '.' of 211.2001 (counts 0) becomes 9: the sum mod 10 goes 2 -> 1
    meta = f"# - {{tle_line1: '{TLE1}'}}\n# - {{tle_line2: '{broken}'}}\n"
    path = write(tmp_path, iso_file(GOOD, meta))
    assert message(path) == (f"{path}: metadata tle_line2: line 2 checksum: the line sums to 1, its last digit is 2 "
                             "(a damaged TLE)")


def test_partial_geometry(tmp_path):
    text = "time,mag,sun_x,sun_y\n2019-12-10T00:00:00,13.0,1.0,0.0\n"
    path = write(tmp_path, text, "bad.csv")
    assert message(path) == (f"{path}: column sun_z: missing (per-sample geometry needs all of sun_x, sun_y, "
                             f"sun_z, obs_x, obs_y, obs_z, range_km; the file has sun_x, sun_y)")


def test_partial_site(tmp_path):
    path = write(tmp_path, "# site_lat_deg: 32.0\ntime,mag\n2019-12-10T00:00:00,13.0\n", "bad.csv")
    assert message(path) == (f"{path}: metadata site_lon_deg: missing (a site needs site_lat_deg, site_lon_deg, "
                             f"site_alt_m)")


def test_unknown_suffix_and_missing_file(tmp_path):
    assert message(tmp_path / "obs.txt") == (f"{tmp_path / 'obs.txt'}: unknown light-curve format '.txt' "
                                             f"(use .ecsv, .csv, .fits, .fit)")
    assert message(tmp_path / "obs.ecsv") == f"{tmp_path / 'obs.ecsv'}: no such light-curve file"


def test_not_a_table(tmp_path):
    path = write(tmp_path, b"\x00\x01garbage".decode("latin-1"), "bad.fits")
    assert message(path).startswith(f"{path}: not a readable FITS table (")


# ---------------------------------------------------------------- times a user writes by hand (issue 30, items 1-2)

SECONDS = "time,mag\n0,13.0\n1,13.1\n2.5,13.2\n"


def test_numeric_times_without_an_epoch_are_refused_naming_the_column(tmp_path):
    path = write(tmp_path, SECONDS, "obs.csv")
    assert message(path) == (f"{path}: column time: numbers without an epoch (the first is 0); give the UTC time "
                             f"of t = 0 as an epoch metadata line (CSV: '# epoch: 2025-01-01T00:00:00', ECSV: "
                             f"meta epoch, FITS: header card EPOCH) for seconds from it, or say 'time_format: mjd' "
                             f"if the numbers are MJD (UTC)")


@pytest.mark.parametrize("epoch", ["2025-01-01T00:00:00", "'2025-01-01T00:00:00'", "2025-01-01 00:00:00",
                                   "\"2025-01-01 00:00:00.000\"", "2025-01-01", "2025-01-01T00:00:00Z"])
def test_an_iso_epoch_in_any_form_astropy_reads_is_accepted_in_a_csv_header(tmp_path, epoch):
    path = write(tmp_path, f"# epoch: {epoch}\n" + SECONDS, "obs.csv")
    lc = read_light_curve(path)
    assert lc.start.isot == "2025-01-01T00:00:00.000" and lc.time_format == "seconds"
    np.testing.assert_array_equal(lc.t, [0.0, 1.0, 2.5])
    assert lc.meta["epoch"] == "2025-01-01T00:00:00.000000"


def test_an_unquoted_epoch_in_the_ecsv_meta_is_accepted(tmp_path):
    text = ("# %ECSV 1.0\n# ---\n# datatype:\n# - {name: time, datatype: float64}\n# - {name: mag, datatype: "
            "float64}\n# meta: !!omap\n# - {epoch: 2025-01-01T00:00:10}\n# schema: astropy-2.0\ntime mag\n"
            "0 13.0\n1 13.1\n")
    lc = read_light_curve(write(tmp_path, text))
    assert lc.start.isot == "2025-01-01T00:00:10.000" and lc.time_format == "seconds"


def test_a_fits_epoch_card_is_accepted(tmp_path):
    lc = LightCurve(start=Time("2025-01-01T00:00:00", scale="utc"), t=np.array([0.0, 1.0]), mag=np.array([13.0, 13.1]))
    path = write_light_curve(lc, tmp_path / "obs.fits", time_format="seconds")
    assert read_light_curve(path).start.isot == "2025-01-01T00:00:00.000"


def test_a_bad_epoch_names_the_metadata_and_what_is_accepted(tmp_path):
    path = write(tmp_path, "# epoch: yesterday\n" + SECONDS, "obs.csv")
    assert message(path) == (f"{path}: metadata epoch: 'yesterday' is not a UTC time astropy reads (e.g. "
                             f"2025-01-01T00:00:00 or 2025-01-01 00:00:00)")


def test_time_format_mjd_states_the_numbers_are_mjd(tmp_path):
    path = write(tmp_path, "# time_format: mjd\ntime,mag\n60676.0,13.0\n60676.5,13.1\n", "obs.csv")
    lc = read_light_curve(path)
    assert lc.start.isot == "2025-01-01T00:00:00.000" and lc.time_format == "mjd"
    np.testing.assert_array_equal(lc.t, [0.0, 43200.0])


def test_seconds_declared_as_mjd_are_refused_before_any_geometry(tmp_path):
    path = write(tmp_path, "# time_format: mjd\n" + SECONDS, "obs.csv")
    assert message(path) == (f"{path}: line 3: time 0 as MJD is 1858-11-17, outside 1957-2100: are these seconds? "
                             f"Then give an epoch instead of time_format: mjd")


def test_an_implausibly_long_span_is_refused(tmp_path):
    path = write(tmp_path, "# epoch: 2025-01-01T00:00:00\ntime,mag\n0,13.0\n1,13.1\n2000000,13.2\n", "obs.csv")
    assert message(path) == (f"{path}: line 5: time 2000000 is 23.1 days after the first sample; a light curve "
                             f"longer than 14 days is refused (check the unit of the time column: seconds from "
                             f"the epoch, or MJD days with time_format: mjd)")


def test_unknown_time_format_is_named(tmp_path):
    path = write(tmp_path, "# time_format: jd\n" + SECONDS, "obs.csv")
    assert message(path) == f"{path}: metadata time_format: 'jd' is not one of seconds, mjd"


@pytest.mark.parametrize("text", ["2019-12-10 00:00:00", "2019-12-10T00:00:00Z"])
def test_iso_time_columns_in_any_form_astropy_reads(tmp_path, text):
    rows = [(f'"{text[:17]}0{i}{text[19:]}"', 13.0 + i) for i in range(3)]
    lc = read_light_curve(write(tmp_path, "time,mag\n" + "".join(f"{t},{m}\n" for t, m in rows), "obs.csv"))
    np.testing.assert_array_equal(lc.t, [0.0, 1.0, 2.0])
    assert lc.start.isot == "2019-12-10T00:00:00.000"
