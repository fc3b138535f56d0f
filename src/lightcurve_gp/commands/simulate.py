"""``python -m lightcurve_gp.simulate CONFIG --out obs.ecsv``: a synthetic observation in the light-curve file format.

Simulates the config's scenario (``scenario`` section: truth from ``q0`` and ``omega0_deg_s``, magnitudes rendered
with ``rho_true``, Gaussian noise of ``noise_var`` drawn with ``--seed`` alone — the noisy light curve of that seed in
:func:`lightcurve_gp.simulation.scenario.simulate_scenario`) and writes it as a light-curve file
(:mod:`lightcurve_gp.observed.lightcurve_file`: ``time`` from ``--start``, ``mag``, ``mag_err = √noise_var`` unless
``--no-mag-err``), with the truth in the sidecar ``<stem>.truth.ecsv`` beside it: per sample the true quaternion,
body rate (deg/s) and noise-free magnitude, each column with its unit; in its metadata the seed, ``rho_true``, the
config's initial estimate ``q_est0`` (what ``estimate --initial-attitude`` takes to repeat the simulated run) and the
config.

Along a pass (``geometry.kind: orbit``) the file starts at ``geometry.start_utc``, carries the per-sample geometry
columns (``sun_*``, ``obs_*``: unit vectors object → Sun and object → observer, GCRS; ``range_km``) and holds the
observable samples only (below the minimum elevation, in the Earth's shadow or with zero flux there is no
magnitude); the sidecar holds the same samples.

``--random-attitude`` and ``--random-rate MIN,MAX`` replace the config's ``scenario.q0`` and ``scenario.omega0_deg_s``
by a draw of ``--truth-seed`` (default ``--seed``): an attitude uniform on SO(3), a rate of log-uniform magnitude in
``[MIN, MAX]`` deg/s about a uniform axis (:func:`random_truth`); the sidecar's config records the drawn values.

``--format damit`` writes the light curve as a DAMIT/convexinv file instead (:mod:`lightcurve_gp.observed.damit`:
``JD intensity sun_xyz earth_xyz``, the vectors rotated from the GCRS into the ecliptic J2000 frame, the Sun at
1 au, the curve flagged calibrated), which ``invert`` with a ``convex:`` config reads; it needs a pass
(``geometry.kind: orbit``: per-sample geometry) and an ``--out`` without a table suffix.

Both files appear together or not at all (temporary files renamed at the end); an existing file is refused unless
``--force``. Errors are one line and exit code 2, as in every command.
"""

from __future__ import annotations

import argparse
import json
import math
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import torch
from astropy.table import Table
from astropy.time import Time, TimeDelta

from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.commands.common import (
    UserError,
    add_common_arguments,
    apply_threads,
    check_output_root,
    check_overrides,
    provenance,
    run_command,
)
from lightcurve_gp.config.load import load_config
from lightcurve_gp.files import atomic_path, json_ready
from lightcurve_gp.observations.observations import CurveInfo, Observations
from lightcurve_gp.observed.damit import AU_M, DEFAULT_SIGMA_MAG, equatorial_to_ecliptic, write_damit
from lightcurve_gp.observed.lightcurve_file import (
    FORMATS,
    LightCurve,
    iso_times,
    light_curve_format,
    light_curve_table,
    write_table,
)
from lightcurve_gp.observed.table_units import ISO_UTC, QUATERNION, set_units
from lightcurve_gp.simulation.scenario import Scenario, simulate_scenario

__all__ = ["truth_path", "truth_table", "random_truth", "damit_observations", "build_parser", "main"]

#: offset of the truth draw's generator from ``--truth-seed`` (apart from the noise seeds)
TRUTH_DRAW_STREAM = 1 << 41


def random_truth(seed: int, *, attitude: bool, rate_range_deg_s: tuple[float, float] | None
                 ) -> tuple[list[float] | None, list[float] | None]:
    """An attitude ``q0`` uniform on SO(3) (when ``attitude``) and a body rate (deg/s) of log-uniform magnitude in
    ``rate_range_deg_s`` about a uniform axis (when given), both from one generator seeded with ``seed``."""
    gen = torch.Generator().manual_seed(TRUTH_DRAW_STREAM + int(seed))
    u = torch.rand(2, generator=gen, dtype=torch.float64)
    axis = torch.randn(3, generator=gen, dtype=torch.float64)
    q0 = [float(v) for v in random_attitudes(1, seed=TRUTH_DRAW_STREAM + int(seed), dtype=torch.float64)[0]]
    rate = None
    if rate_range_deg_s is not None:
        lo, hi = (math.log(v) for v in rate_range_deg_s)
        rate = [float(v) for v in math.exp(lo + (hi - lo) * float(u[0])) * axis / axis.norm()]
    return (q0 if attitude else None), rate


def _rate_range(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise UserError(f"--random-rate: {text!r} is not two numbers MIN,MAX (deg/s)") from None
    if not 0.0 < lo <= hi:
        raise UserError(f"--random-rate: need 0 < MIN <= MAX (deg/s), got {lo:g} and {hi:g}")
    return lo, hi


def truth_path(out: Path) -> Path:
    """The sidecar of ``out``: ``<folder>/<stem>.truth.ecsv``."""
    return out.with_name(f"{out.stem}.truth.ecsv")


#: the truth sidecar's units: the body rate in deg/s like the config's ``omega0_deg_s`` and ``solutions.ecsv``
TRUTH_UNITS = {**{f"q{i}": QUATERNION for i in range(1, 5)}, **{f"omega_{a}": "deg / s" for a in "xyz"},
               "mag_clean": "mag"}


def truth_table(sc: Scenario, lc: LightCurve, record: dict, rows: np.ndarray) -> Table:
    """The truth of one simulated light curve at its samples ``rows`` of the scenario: time (ISO UTC), ``q1…q4``
    (scalar last, inertial → body), ``omega_x…z`` (body rate, deg/s), ``mag_clean`` (mag); every column with its
    unit (:data:`TRUTH_UNITS`)."""
    q, w = sc.q_true[0].cpu().numpy()[rows], np.degrees(sc.omega_true[0].cpu().numpy()[rows])
    table = Table({"time": iso_times(lc.times), **{f"q{i + 1}": q[:, i] for i in range(4)},
                   **{f"omega_{a}": w[:, i] for i, a in enumerate("xyz")},
                   "mag_clean": sc.m_clean[0].cpu().numpy()[rows]})
    set_units(table, TRUTH_UNITS, {"time": ISO_UTC})
    table.meta.update({"seed": sc.seeds[0], "rho_true": sc.rho_true, "noise_var": sc.noise_var,
                       "q_est0": [float(v) for v in sc.q_est0[0].tolist()],
                       "simulation": json.dumps(json_ready(record), default=str, allow_nan=False)})
    return table


def damit_observations(lc: LightCurve, *, source: str) -> Observations:
    """The simulated light curve with its pass geometry as one calibrated curve of :class:`Observations` in the
    ecliptic J2000 frame (what :func:`~lightcurve_gp.observed.damit.write_damit` writes; the Sun at 1 au)."""
    f64 = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float64)  # noqa: E731
    n = lc.t.size
    sigma = lc.mag_err if lc.mag_err is not None else np.full(n, DEFAULT_SIGMA_MAG)
    return Observations(t=f64(lc.t), mag=f64(lc.mag), sigma=f64(sigma), curve=torch.zeros(n, dtype=torch.long),
                        curves=(CurveInfo(source=source, relative=False),),
                        sun=f64(equatorial_to_ecliptic(lc.geometry["sun"])),
                        observer=f64(equatorial_to_ecliptic(lc.geometry["obs"])),
                        range_m=f64(lc.geometry["range_km"] * 1e3), sun_range_m=f64(np.full(n, AU_M)),
                        epoch=iso_times(lc.start))


def build_parser(prog: str = "lightcurve-gp simulate") -> argparse.ArgumentParser:
    """The command's options; ``prog`` is how it was called (its usage line)."""
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Simulate the config's scenario and write its noisy light curve as a light-curve file "
                    "(.ecsv, .csv or .fits) with the truth in <stem>.truth.ecsv beside it.")
    parser.add_argument("config", help="YAML config, e.g. configs/boxwing_robust.yaml")
    parser.add_argument("--out", required=True, type=Path,
                        help="the light-curve file to write (.ecsv, .csv, .fits; with --format damit no suffix)")
    parser.add_argument("--format", dest="file_format", choices=("table", "damit"), default="table",
                        help="table: a light-curve table (its format from the suffix); damit: a DAMIT/convexinv "
                             "file for the convex inversion (needs geometry.kind: orbit)")
    parser.add_argument("--seed", type=int, default=0, help="noise seed, an integer >= 0 (default 0)")
    parser.add_argument("--rho-true", type=float, default=None, help="true rho in (0, 1] (default scenario.rho_true)")
    parser.add_argument("--start", default=None,
                        help="UTC time of the first sample (ISO; default 2025-01-01T00:00:00; a pass config starts "
                             "at geometry.start_utc)")
    parser.add_argument("--time-format", choices=("iso", "mjd", "seconds"), default="iso",
                        help="how the time column is written (seconds: from --start, given as the epoch metadata)")
    parser.add_argument("--no-mag-err", action="store_true", help="leave the mag_err column out")
    parser.add_argument("--band", default=None, help="filter band to record in the metadata")
    parser.add_argument("--random-attitude", action="store_true",
                        help="draw the true initial attitude uniformly on SO(3) instead of scenario.q0")
    parser.add_argument("--random-rate", default=None, metavar="MIN,MAX",
                        help="draw the true body rate: log-uniform magnitude in [MIN, MAX] deg/s, uniform axis")
    parser.add_argument("--truth-seed", type=int, default=None, help="seed of the random truth (default --seed)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                        help="override a config value (repeatable)")
    add_common_arguments(parser, force_help="replace an existing light-curve file and its truth sidecar (both are "
                                            "replaced together at the end, or neither)")
    return parser


def _checked_start(text: str | None, cfg) -> Time:
    if cfg.geometry.kind == "orbit":
        if text is not None:
            raise UserError(f"--start: a pass config starts at geometry.start_utc ({cfg.geometry.start_utc}); "
                            f"leave --start out or change geometry.start_utc")
        text = cfg.geometry.start_utc
    try:
        return Time(text or "2025-01-01T00:00:00", format="isot", scale="utc")
    except ValueError:
        raise UserError(f"--start: {text!r} is not an ISO UTC time (e.g. 2025-01-01T00:00:00)") from None


def _observed_light_curve(sc: Scenario, start: Time, with_err: bool, meta: dict) -> tuple[LightCurve, np.ndarray]:
    """The file's light curve (observable samples only, with the pass's geometry columns along a pass) and the
    scenario rows it holds."""
    mag = sc.observations[0].cpu().numpy()
    rows = np.flatnonzero(np.isfinite(mag))
    if rows.size == 0:
        raise UserError("the simulated pass has no observable sample (geometry.min_elevation_deg, shadow)")
    t = sc.times.cpu().numpy().astype(np.float64)[rows]
    geometry = None
    if sc.geometry is not None:
        g = sc.geometry
        geometry = {"sun": g.sun.numpy()[rows], "obs": g.observer.numpy()[rows],
                    "range_km": g.range_m.numpy()[rows] / 1e3}
        start = start + TimeDelta(float(g.times_s[rows[0]]), format="sec")
    lc = LightCurve(start=start, t=t - t[0], mag=mag[rows],
                    mag_err=np.full(rows.size, math.sqrt(sc.noise_var)) if with_err else None, geometry=geometry,
                    meta=meta)
    return lc, rows


def _run(args: argparse.Namespace) -> int:
    apply_threads(args.threads)
    check_overrides(args.overrides)
    if args.seed < 0:
        raise UserError(f"--seed: {args.seed} must be >= 0")
    if args.seed >= 2**64:
        raise UserError(f"--seed: {args.seed} must be < 2**64 (torch's seed range)")
    q0, rate = random_truth(args.seed if args.truth_seed is None else args.truth_seed,
                            attitude=args.random_attitude, rate_range_deg_s=_rate_range(args.random_rate))
    drawn = ([f"scenario.q0={q0}"] if q0 else []) + ([f"scenario.omega0_deg_s={rate}"] if rate else [])
    cfg = load_config(args.config, args.overrides + drawn)
    if args.rho_true is not None and not 0.0 < args.rho_true <= 1.0:
        raise UserError(f"--rho-true: {args.rho_true:g} is outside (0, 1]")
    damit = args.file_format == "damit"
    if damit and args.out.suffix.lower() in FORMATS:
        raise UserError(f"--out: {args.out} has a table suffix; a DAMIT file (--format damit) has none, e.g. "
                        f"{args.out.with_suffix('')}")
    if damit and cfg.geometry.kind != "orbit":
        raise UserError("--format damit: the file needs per-sample Sun and observer directions; use a pass config "
                        "(geometry.kind: orbit), e.g. configs/geo_night.yaml")
    fmt = None if damit else light_curve_format(args.out)
    start = _checked_start(args.start, cfg)
    sidecar = truth_path(args.out)
    check_output_root(args.out.parent)
    for path in (args.out, sidecar):
        if path.exists() and not args.force:
            raise UserError(f"{path}: already exists; pass --force to replace it, or choose another --out")
    sc = simulate_scenario(cfg, seeds=[args.seed], rho_true=args.rho_true)
    lc, rows = _observed_light_curve(sc, start, not args.no_mag_err, {"band": args.band} if args.band else {})
    record = provenance(cfg, seeds=[args.seed], config_file=str(args.config), rho_true=sc.rho_true)
    with ExitStack() as stack:
        tmp_obs = stack.enter_context(atomic_path(args.out))
        tmp_truth = stack.enter_context(atomic_path(sidecar))
        if damit:
            write_damit(damit_observations(lc, source=f"simulation seed {args.seed}"), tmp_obs)
        else:
            write_table(light_curve_table(lc, args.time_format), tmp_obs, fmt=fmt)
        write_table(truth_table(sc, lc, record, rows), tmp_truth, fmt="ascii.ecsv")
    print(f"written: {args.out} ({rows.size} samples, seed {args.seed}, rho_true {sc.rho_true:g}) and {sidecar}")
    return 0


def main(argv: list[str] | None = None, *, prog: str = "lightcurve-gp simulate") -> int:
    """Run the command on ``argv`` (default ``sys.argv[1:]``), its usage shown as ``prog``; returns the exit code."""
    args = build_parser(prog).parse_args(argv)
    return run_command(lambda: _run(args), debug=args.debug)

