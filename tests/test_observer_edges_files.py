"""The edges a new observer hits with files, meshes and geometry (issue 39, rows 1-5 and 12): a mesh that does not
close a volume, a TLE and site that put the samples where they cannot have been seen, a TLE without its site, a CSV
as a spreadsheet saves it, a light curve faster than the rate range; one regression test per defect, each asserting
the exact message."""

from pathlib import Path

import astropy.units as u
import numpy as np
import pytest
import trimesh
from astropy.coordinates import AltAz, EarthLocation, get_sun
from astropy.time import Time

from lightcurve_gp.commands import estimate, invert
from lightcurve_gp.config.load import ConfigError, load_config
from lightcurve_gp.inference.periodogram import lstsq_power, periodogram
from lightcurve_gp.observed.lightcurve_file import LightCurve, read_light_curve, write_light_curve
from lightcurve_gp.observed.run import FileGeometryError, check_model_takes_geometry, file_geometry
from lightcurve_gp.passes.earth import no_downloads
from lightcurve_gp.passes.visibility import Visibility, site_visibility
from lightcurve_gp.photometry.shapes import box_wing_mesh, facets_from_config

ROOT = Path(__file__).resolve().parents[1]
BOXWING = str(ROOT / "configs" / "boxwing.yaml")
LEO = ROOT / "configs" / "leo_pass.yaml"


# 1. a mesh that does not close a volume with outward normals is refused at load, in one line naming the file

def _box(faces=None) -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    return trimesh.Trimesh(box.vertices, box.faces if faces is None else faces(box), process=False)


def _open_box(box: trimesh.Trimesh) -> np.ndarray:
    """The box's faces less its +z and −z sides (the four triangles whose normal is ±z)."""
    return box.faces[np.abs(box.face_normals[:, 2]) < 0.5]


def _one_flipped(box: trimesh.Trimesh) -> np.ndarray:
    faces = box.faces.copy()
    faces[0] = faces[0][::-1]
    return faces


@pytest.mark.parametrize("mesh, message", [
    (lambda: _box(_open_box), "not closed: 8 of its 16 edges belong to one triangle only (a hole or a missing face; "
                              "the first from (-0.5, -0.5, -0.5) to (-0.5, 0.5, -0.5)); the renderer has no "
                              "self-shadowing and needs a closed surface"),
    (lambda: trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False),
     "not closed: 3 of its 3 edges belong to one triangle only (a hole or a missing face; the first from (0, 0, 0) "
     "to (1, 0, 0)); the renderer has no self-shadowing and needs a closed surface"),
    (lambda: _box(_one_flipped), "inconsistent normals: 3 edge(s) are traversed in the same direction by both their "
                                 "triangles (the first from (-0.5, -0.5, -0.5) to (-0.5, 0.5, 0.5)), so one of each "
                                 "pair faces inward; wind every triangle counter-clockwise seen from outside"),
    (lambda: _box(lambda b: b.faces[:, ::-1]), "the normals point inward (the triangles wind clockwise seen from "
                                               "outside; the enclosed volume is -1 m^3); reverse every triangle's "
                                               "winding"),
    (lambda: trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 1]], process=False),
     "encloses no volume (its triangles lie back to back, a sheet with two sides); give the sheet a thickness"),
])
def test_a_mesh_that_does_not_close_a_volume_is_refused_at_load(tmp_path, mesh, message):
    path = tmp_path / "object.obj"
    mesh().export(path)
    with pytest.raises(ConfigError) as info:
        load_config(BOXWING, ["shape.kind=mesh", f"shape.mesh_path={path}"])
    assert str(info.value) == f"shape.mesh_path: {path}: {message}"


def test_closed_meshes_load_the_box_wing_with_its_own_face_vertices_too(tmp_path):
    """The check merges coincident vertices: the box-wing, whose faces keep their own vertices, is closed."""
    box_wing_mesh((1.0, 1.0, 1.3), 2, (1.0, 2.0, 0.1), 2).export(tmp_path / "box_wing.obj")
    _box().export(tmp_path / "box.obj")
    for name, facets in (("box_wing", 4 * 2 * 6 + 2 * (2 * 2 * 2 * 2 + 4 * 2 * 2)), ("box", 12)):
        cfg = load_config(BOXWING, ["shape.kind=mesh", f"shape.mesh_path={tmp_path / name}.obj"])
        assert facets_from_config(cfg).normals.shape[0] == facets


# 2. samples that cannot have been observed from the file's site: one warning line, or refused with --strict

def leo_curve(start: str, t: np.ndarray, source: str = "leo.csv", site: bool = True) -> LightCurve:
    cfg = load_config(LEO)
    s = cfg.geometry.site
    meta = {"tle_line1": cfg.geometry.tle[0], "tle_line2": cfg.geometry.tle[1]}
    if site:
        meta.update(site_lat_deg=s.lat_deg, site_lon_deg=s.lon_deg, site_alt_m=s.alt_km * 1e3)
    return LightCurve(start=Time(start, scale="utc"), t=t, mag=np.full(t.size, 8.0), mag_err=np.full(t.size, 0.1),
                      meta=meta, source=source)


def test_the_suns_elevation_at_the_site_is_astropys_and_daylight_ends_at_civil_twilight():
    lc = leo_curve("2024-05-15T18:50:00", np.arange(0.0, 3600.0, 60.0))
    lat, lon, alt_m = lc.site
    vis = site_visibility(file_geometry(lc), lat_deg=lat, lon_deg=lon, alt_km=alt_m / 1e3)
    site = EarthLocation.from_geodetic(lon=lon * u.deg, lat=lat * u.deg, height=alt_m * u.m)
    with no_downloads():
        sun = get_sun(lc.times).transform_to(AltAz(obstime=lc.times, location=site)).alt.deg  # no refraction
    np.testing.assert_allclose(vis.sun_elevation_deg, sun, atol=0.02)
    clear = np.abs(sun + 6.0) > 0.05
    assert vis.daylight.any() and not vis.daylight.all()  # the arc crosses the end of civil twilight
    np.testing.assert_array_equal(vis.daylight[clear], sun[clear] > -6.0)


def test_every_reason_is_counted_with_its_first_sample():
    flags = lambda *i: np.isin(np.arange(5), i)  # noqa: E731
    vis = Visibility(times_s=np.arange(5.0) * 10, object_elevation_deg=np.zeros(5), sun_elevation_deg=np.zeros(5),
                     below_horizon=flags(1, 2), daylight=flags(2, 3, 4), in_shadow=flags(4))
    assert vis.describe() == (
        "4 of 5 samples cannot have been observed from the site: 2 with the object below the horizon (elevation < 0 "
        "deg), the first at 10 s; 3 in daylight at the site (Sun above -6 deg), the first at 20 s; 1 with the object "
        "in the Earth's shadow, the first at 40 s")
    assert Visibility(np.zeros(1), np.zeros(1), np.zeros(1), *[np.zeros(1, bool)] * 3).describe() is None


UNSEEN = ("leo.csv: 60 of 60 samples cannot have been observed from the site: 21 with the object below the horizon "
          "(elevation < 0 deg), the first at 2024-05-15T15:55:00.000000; 60 in daylight at the site (Sun above -6 "
          "deg), the first at 2024-05-15T15:55:00.000000")


def test_a_pass_below_the_horizon_and_in_daylight_is_a_warning_or_refused():
    lc = leo_curve("2024-05-15T15:55:00", np.arange(0.0, 1200.0, 20.0))
    warnings = []
    geometry = file_geometry(lc, warn=warnings.append)
    assert warnings == [f"{UNSEEN}; check the TLE, the site and the times (--strict refuses such a file)"]
    assert int((geometry.elevation_deg < 0).sum()) == 21
    with pytest.raises(FileGeometryError) as info:
        file_geometry(lc, strict=True)
    assert str(info.value) == f"{UNSEEN} (refused with --strict)"


ISS = ("1 25544U 98067A   19343.69339541  .00001764  00000-0  38792-4 0  9991",
       "2 25544  51.6439 211.2001 0007417  17.6667  85.6398 15.50103472202482")


def iss_curve(seconds: float) -> LightCurve:
    """The ISS from Mount Lemmon (32.44 N, 110.79 W), a night pass from 2019-12-10T02:00:00 UTC, every 10 s."""
    t = np.arange(0.0, seconds, 10.0)
    meta = {"tle_line1": ISS[0], "tle_line2": ISS[1], "site_lat_deg": 32.44, "site_lon_deg": -110.79,
            "site_alt_m": 2790.0}
    return LightCurve(start=Time("2019-12-10T02:00:00", scale="utc"), t=t, mag=np.full(t.size, 2.0), meta=meta,
                      source="iss.csv")


def test_a_night_pass_gives_no_warning_until_the_object_enters_the_shadow():
    """The pass of :func:`iss_curve` is seen from 5.7 deg up at 02:00:00 (the Sun at -21 deg) and enters the shadow
    between 02:03:10 and 02:03:20 (the first 20 samples, to 02:03:10, are all seen)."""
    warnings = []
    geometry = file_geometry(iss_curve(200.0), warn=warnings.append)
    assert warnings == [] and bool((geometry.elevation_deg > 5).all())
    file_geometry(iss_curve(300.0), warn=warnings.append)
    assert warnings == ["iss.csv: 10 of 30 samples cannot have been observed from the site: 10 with the object in "
                        "the Earth's shadow, the first at 2019-12-10T02:03:20.000000; check the TLE, the site and the "
                        "times (--strict refuses such a file)"]


@pytest.fixture()
def unseen_file(tmp_path) -> Path:
    return write_light_curve(leo_curve("2024-05-15T15:55:00", np.arange(0.0, 1200.0, 20.0)), tmp_path / "leo.csv")


def test_invert_warns_on_stderr_and_refuses_with_strict(unseen_file, tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    args = [BOXWING, "--light-curve", str(unseen_file), "--out", str(out), "--no-progress"]
    assert invert.main([*args, "--strict"]) == 2
    assert capsys.readouterr().err == f"error: {UNSEEN.replace('leo.csv', str(unseen_file))} (refused with --strict)\n"

    def stop(path):
        raise invert.UserError("stopped after the geometry")

    monkeypatch.setattr(invert, "check_output_root", stop)
    assert invert.main(args) == 2
    lines = capsys.readouterr().err.splitlines(keepends=True)
    assert lines[0] == (f"warning: {UNSEEN.replace('leo.csv', str(unseen_file))}; check the TLE, the site and the "
                        f"times (--strict refuses such a file)\n")
    assert lines[1].startswith(f"warning: {unseen_file}: flat within its noise")  # its magnitudes are constant
    assert lines[2:] == ["error: stopped after the geometry\n"]
    assert not out.exists()


class GeometryModel:
    config = {"inputs": "body_geometry"}


def test_estimate_refuses_with_strict_and_strict_needs_a_file(unseen_file, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(estimate, "_load_checked_model", lambda args, cfg: (GeometryModel(), {}))
    out = tmp_path / "out"
    base = [BOXWING, "--out", str(out), "--no-progress"]
    code = estimate.main([*base, "--model", "m.pt", "--light-curve", str(unseen_file), "--strict",
                          "--initial-attitude=0,0,0,1"])
    assert code == 2
    assert capsys.readouterr().err == f"error: {UNSEEN.replace('leo.csv', str(unseen_file))} (refused with --strict)\n"
    assert estimate.main([*base, "--strict", "--seeds", "1", "--estimators", "ukf"]) == 2
    assert capsys.readouterr().err == "error: --strict: applies only with --light-curve\n"
    assert not out.exists()


# 3. a TLE without its site: the site is named, before the model's inputs

class FixedGeometryModel:
    config = {"inputs": "quaternion"}


def test_a_tle_without_a_site_names_the_site_before_the_model():
    lc = leo_curve("2024-05-15T15:55:00", np.arange(0.0, 60.0, 20.0), site=False)
    message = ("leo.csv: metadata site_lat_deg: missing (a file with a TLE needs the observing site: site_lat_deg, "
               "site_lon_deg, site_alt_m)")
    for check in (lambda: check_model_takes_geometry(FixedGeometryModel(), lc), lambda: file_geometry(lc)):
        with pytest.raises(FileGeometryError) as info:
            check()
        assert str(info.value) == message
    with pytest.raises(FileGeometryError, match=r"^leo.csv: the file gives a TLE and site, but the model"):
        check_model_takes_geometry(FixedGeometryModel(), leo_curve("2024-05-15T15:55:00", np.arange(0.0, 60.0, 20.0)))


def test_estimate_on_a_tle_without_a_site_names_the_site(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(estimate, "_load_checked_model", lambda args, cfg: (FixedGeometryModel(), {}))
    path = write_light_curve(leo_curve("2024-05-15T15:55:00", np.arange(0.0, 200.0, 20.0), site=False),
                             tmp_path / "leo.csv")
    assert estimate.main([BOXWING, "--out", str(tmp_path / "out"), "--no-progress", "--model", "m.pt",
                          "--light-curve", str(path), "--initial-attitude=0,0,0,1"]) == 2
    assert capsys.readouterr().err == (f"error: {path}: metadata site_lat_deg: missing (a file with a TLE needs the "
                                       f"observing site: site_lat_deg, site_lon_deg, site_alt_m)\n")


# 4. and 5. a CSV as a spreadsheet saves it: byte-order mark, CRLF, ';' between columns with decimal commas

PLAIN = ("# band: V\n# epoch: 2025-01-01T00:00:00\ntime,mag,mag_err\n0,12.5,0.1\n1.5,12.75,0.1\n3,-0.25,0.125\n")


def _same(a: LightCurve, b: LightCurve) -> None:
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.mag, b.mag)
    np.testing.assert_array_equal(a.mag_err, b.mag_err)
    assert a.start == b.start and a.meta == b.meta


def test_a_csv_with_a_byte_order_mark_and_crlf_reads_as_the_same_file(tmp_path):
    (tmp_path / "plain.csv").write_text(PLAIN)
    (tmp_path / "excel.csv").write_bytes(b"\xef\xbb\xbf" + PLAIN.replace("\n", "\r\n").encode())
    _same(read_light_curve(tmp_path / "excel.csv"), read_light_curve(tmp_path / "plain.csv"))
    (tmp_path / "bad.csv").write_bytes(b"\xef\xbb\xbf" + PLAIN.replace("12.75", "x").replace("\n", "\r\n").encode())
    with pytest.raises(ValueError) as info:  # line numbers as an editor shows them
        read_light_curve(tmp_path / "bad.csv")
    assert str(info.value) == f"{tmp_path / 'bad.csv'}: line 5: mag 'x' is not a number"


def test_a_semicolon_csv_with_decimal_commas_reads_as_the_same_file(tmp_path):
    (tmp_path / "plain.csv").write_text(PLAIN)
    semi = PLAIN.replace(",", ";").replace(".", ",").replace("# epoch: 2025-01-01T00:00:00", "# epoch: 2025-01-01")
    (tmp_path / "semi.csv").write_bytes(b"\xef\xbb\xbf" + semi.replace("\n", "\r\n").encode())
    _same(read_light_curve(tmp_path / "semi.csv"), read_light_curve(tmp_path / "plain.csv"))
    iso = "time;mag\n2025-01-01T00:00:00,5;12,5\n2025-01-01T00:00:01;1,25e1\n"  # a time is never rewritten
    (tmp_path / "iso.csv").write_text(iso)
    with pytest.raises(ValueError) as info:
        read_light_curve(tmp_path / "iso.csv")
    assert str(info.value) == (f"{tmp_path / 'iso.csv'}: line 2: time '2025-01-01T00:00:00,5' is not a UTC time "
                               f"astropy reads (e.g. 2025-01-01T00:00:00.000)")
    (tmp_path / "iso.csv").write_text(iso.replace("00:00,5", "00:00.5"))
    assert read_light_curve(tmp_path / "iso.csv").mag.tolist() == [12.5, 12.5]


def test_a_decimal_comma_in_a_comma_separated_file_says_what_to_do(tmp_path):
    (tmp_path / "quoted.csv").write_text('time,mag\n2025-01-01T00:00:00,"5,1"\n2025-01-01T00:00:01,"5,2"\n')
    with pytest.raises(ValueError) as info:
        read_light_curve(tmp_path / "quoted.csv")
    assert str(info.value) == (f"{tmp_path / 'quoted.csv'}: line 2: mag '5,1' is not a number (a decimal comma: "
                               f"write a point, or separate the columns with ';' to have decimal commas read)")


# 12. a light curve faster than the rate range: the periodogram's peak and the range, not "Singular matrix"

def test_the_least_squares_power_is_astropys_where_astropys_is_regular():
    from astropy.timeseries import LombScargle

    rng = np.random.default_rng(0)
    t = np.sort(rng.uniform(0.0, 100.0, 150))
    y = 10.0 + 0.3 * np.sin(2 * np.pi * t / 7.0) + 0.1 * rng.standard_normal(t.size)
    dy = rng.uniform(0.05, 0.15, t.size)
    f = np.linspace(0.01, 1.0, 300)
    np.testing.assert_allclose(lstsq_power(t, y, dy, f, 2), LombScargle(t, y, dy, nterms=2).power(f), atol=1e-9)


def test_a_harmonic_on_the_nyquist_frequency_is_the_model_without_its_sine():
    t = np.arange(41.0)  # on a 1 s grid sin(2π 0.5 t) = 0: the 2-term model at f = 0.25 Hz is singular
    y = 10.0 + 0.5 * np.sin(2 * np.pi * t / 7.0)
    power = lstsq_power(t, y, None, np.array([0.25]), 2)[0]
    k = 2 * np.pi * 0.25 * t
    design = np.stack([np.ones_like(t), np.sin(k), np.cos(k), np.cos(2 * k)], -1)  # without sin(2k), which is 0
    fit = np.linalg.lstsq(design, y, rcond=None)[0]
    assert power == pytest.approx(1.0 - np.sum((y - design @ fit) ** 2) / np.sum((y - y.mean()) ** 2), abs=1e-12)


SEVEN = ("rate range 0.05-5 deg/s excludes every periodogram candidate: no rate in it fits the light curve, whose "
         "periodogram's strongest peak is at 51.3 deg/s (the light curve repeats every 7.02 s; other peaks at 26.1, "
         "37.8 deg/s), and the candidates are 0.5, 1 and 2 times a peak; widen the range to 25.7-103 deg/s if the "
         "object may spin that fast")


def test_invert_on_a_light_curve_faster_than_the_rate_range_names_the_peak(tmp_path, capsys):
    t = np.arange(41.0)
    lc = LightCurve(start=Time("2025-01-01T00:00:00", scale="utc"), t=t, mag=10.0 + 0.5 * np.sin(2 * np.pi * t / 7),
                    mag_err=np.full(t.size, 0.05))
    path = write_light_curve(lc, tmp_path / "plain.csv")
    with pytest.raises(ValueError) as info:
        periodogram(lc.t, lc.mag, lc.mag_err)
    assert str(info.value) == SEVEN
    assert invert.main([BOXWING, "--light-curve", str(path), "--out", str(tmp_path / "out"), "--no-progress",
                        "--starts", "10"]) == 2
    assert capsys.readouterr().err == f"error: {path}: {SEVEN}\n"
    assert not (tmp_path / "out").exists()
