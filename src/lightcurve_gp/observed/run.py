"""The GPUKF on an observed light curve (a light-curve file): attitude history, innovation statistics, global start.

The filter steps from sample to sample of the file (:mod:`lightcurve_gp.attitude.timeline`: increments from the config's
known spin, gaps and irregular steps as they are), with the per-sample measurement variance ``mag_err²`` when the
file gives ``mag_err`` (else ``filter.measurement_noise``). It starts from a given attitude or, without one, from the
global-start bank (:mod:`lightcurve_gp.filters.bank`). The user has no truth, so the run is judged by its innovations:
the NIS ``ν²/Pyy`` of a consistent filter is χ²(1), its mean over ``n`` samples lies in :func:`metrics.chi2_band`.

Geometry (:func:`file_geometry`). A file with per-sample geometry columns (``sun_*``, ``obs_*``, ``range_km``) or
with a TLE and a site gives a :class:`~lightcurve_gp.passes.geometry.PassGeometry` of its samples (the TLE through
:func:`lightcurve_gp.passes.geometry.orbit_pass`, every sample kept: the file's magnitudes were observed), and every
filter
step predicts with its own sample's geometry (:class:`~lightcurve_gp.observation.along_pass.AlongPass`): the
body-frame Sun and observer directions ``A(q) s_k``, ``A(q) v_k`` and the range ``r_k`` of a ``body_geometry`` GP.
Such a file needs a model that takes geometry; a GP trained under one fixed geometry is refused
(:func:`check_model_takes_geometry`) rather than run with a geometry it would ignore. A file without geometry runs
with the config's fixed Sun and observer.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
from astropy.table import Table
from torch import Tensor

from lightcurve_gp.attitude.metrics import chi2_band
from lightcurve_gp.attitude.rotations import quat_normalize, quat_to_euler321
from lightcurve_gp.attitude.timeline import spin_increments
from lightcurve_gp.config.load import ConfigError
from lightcurve_gp.config.schema import GeometryConfig, SiteConfig
from lightcurve_gp.filters.bank import BankResult, bank_attitudes, run_bank
from lightcurve_gp.filters.offset import offset_to_rho
from lightcurve_gp.filters.setup import run_filter
from lightcurve_gp.filters.usque import FilterHistory
from lightcurve_gp.observed.lightcurve_file import LightCurve, LightCurveFileError, iso_times
from lightcurve_gp.observed.table_units import ISO_UTC, QUATERNION, set_units
from lightcurve_gp.passes.geometry import PassGeometry, orbit_pass
from lightcurve_gp.passes.visibility import site_visibility

__all__ = ["ObservedRun", "FileGeometryError", "file_geometry", "check_model_takes_geometry",
           "check_light_curve", "file_inputs", "estimate_light_curve", "euler321_jacobian", "history_table",
           "nis_summary", "bank_table"]


class FileGeometryError(ValueError):
    """The file's geometry cannot be used: a TLE without a site, a model that takes no geometry, or (strict)
    samples the site cannot have seen."""


@dataclass
class ObservedRun:
    """One estimate on a file: the reported filter's history (batch 1), its start and the bank when one ran."""

    lc: LightCurve
    history: FilterHistory
    q_est0: Tensor
    bank: BankResult | None
    seconds: float


def file_geometry(lc: LightCurve, *, strict: bool = False,
                  warn: Callable[[str], None] | None = None) -> PassGeometry | None:
    """The per-sample geometry of a file (module docstring): from its geometry columns, from its TLE and site, or
    ``None`` when it gives neither. Samples of a TLE and site that cannot have been observed (the object below the
    horizon, the site in daylight, the object in the Earth's shadow: :mod:`lightcurve_gp.passes.visibility`) are
    named in one line, refused with ``strict`` (:class:`FileGeometryError`), else given to ``warn``."""
    if lc.geometry is not None:
        g = lc.geometry
        try:
            return PassGeometry.from_columns(times_s=lc.t, sun=g["sun"], observer=g["obs"],
                                             range_m=g["range_km"] * 1e3, start_utc=lc.start.isot, shadow_model="none")
        except ValueError as exc:
            raise FileGeometryError(f"{lc.source}: geometry columns: {exc}") from None
    if not lc.has_tle:
        return None
    _require_site(lc)
    lat, lon, alt_m = lc.site
    geo = GeometryConfig(kind="orbit", tle=[lc.meta["tle_line1"], lc.meta["tle_line2"]],
                         site=SiteConfig(lat_deg=lat, lon_deg=lon, alt_km=alt_m / 1e3), start_utc=lc.start.isot,
                         min_elevation_deg=-90.0)
    try:
        geometry = orbit_pass(geo, np.asarray(lc.t, dtype=np.float64))
    except ConfigError as exc:
        raise FileGeometryError(f"{lc.source}: metadata tle_line1/tle_line2 and site: {exc}") from None
    if strict or warn is not None:
        unseen = site_visibility(geometry, lat_deg=lat, lon_deg=lon, alt_km=alt_m / 1e3).describe(
            lambda i: iso_times(lc.times[i]))
        if unseen is not None and strict:
            raise FileGeometryError(f"{lc.source}: {unseen} (refused with --strict)")
        if unseen is not None:
            warn(f"{lc.source}: {unseen}; check the TLE, the site and the times (--strict refuses such a file)")
    return geometry


def _require_site(lc: LightCurve) -> None:
    if lc.has_tle and lc.site is None:
        raise FileGeometryError(f"{lc.source}: metadata site_lat_deg: missing (a file with a TLE needs the observing "
                                f"site: site_lat_deg, site_lon_deg, site_alt_m)")


def check_model_takes_geometry(model, lc: LightCurve) -> None:
    """Refuse a file with geometry for a model that takes none (module docstring); a TLE without its site is named
    first."""
    _require_site(lc)
    inputs = getattr(model, "config", {}).get("inputs")
    if (lc.geometry is not None or lc.has_tle) and inputs != "body_geometry":
        what = "per-sample geometry columns (sun_*, obs_*, range_km)" if lc.geometry is not None else "a TLE and site"
        raise FileGeometryError(
            f"{lc.source}: the file gives {what}, but the model (inputs: {inputs}) was trained under one fixed "
            f"geometry and would ignore it; use a model with model.inputs: body_geometry (e.g. configs/geo_pass.yaml) "
            f"or remove the geometry from the file to run with the config's fixed Sun and observer")


def check_light_curve(cfg, lc: LightCurve) -> None:
    """Refuse, before anything runs, a light curve the filter of ``cfg`` cannot use: fewer samples than one to
    start from plus one scalar update per unknown of its state (:class:`LightCurveFileError`). Gaps of any length
    are fine: the known-spin increments are closed form (:mod:`lightcurve_gp.attitude.timeline`)."""
    unknowns = {"attitude": 3, "body rate": 3 * int(cfg.filter.estimate_omega),
                "magnitude offset": int(cfg.filter.estimate_offset)}
    dim = sum(unknowns.values())
    n = int(lc.t.size)
    if n < dim + 1:
        raise LightCurveFileError(
            f"{lc.source}: {n} sample{'s' if n != 1 else ''}; the filter needs at least {dim + 1}: the first sets the "
            f"start and each later one is one scalar update of a state with {dim} unknowns "
            f"({', '.join(k for k, v in unknowns.items() if v)})")


def file_inputs(cfg, lc: LightCurve) -> tuple[Tensor, Tensor, Tensor | None]:
    """``(observations (T+1,), increments (T, 4), R (T+1,) or None)`` of a file in the config's dtype/device."""
    dtype, device = cfg.torch_dtype, torch.device(cfg.device)
    t = torch.as_tensor(lc.t, dtype=torch.float64, device=device)  # the increments are computed in float64
    omega0 = torch.deg2rad(torch.tensor(cfg.scenario.omega0_deg_s, dtype=dtype, device=device))
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=dtype, device=device)
    increments = spin_increments(t, omega0=omega0, inertia=inertia)
    y = torch.as_tensor(lc.mag, dtype=dtype, device=device)
    R = None if lc.mag_err is None else torch.as_tensor(lc.mag_err, dtype=dtype, device=device) ** 2
    return y, increments, R


def estimate_light_curve(cfg, model, lc: LightCurve, *, initial_attitude: Tensor | None = None,
                         bank_size: int = 1024, keep: int = 5, prune_after_s: float | None = None,
                         prune_keep: int = 64) -> ObservedRun:
    """The GPUKF of ``cfg`` on ``lc``: from ``initial_attitude (4,)`` when given, else from the best member of a
    bank of ``bank_size`` filters (the best ``keep`` are rerun with the config's settings; with ``prune_after_s``
    only the best ``prune_keep`` run past the samples of the first ``prune_after_s`` seconds)."""

    check_model_takes_geometry(model, lc)
    geometry = file_geometry(lc)
    y, increments, R = file_inputs(cfg, lc)
    start = time.perf_counter()
    if initial_attitude is not None:
        q0 = quat_normalize(initial_attitude.to(y)).reshape(1, 4)
        history = run_filter(cfg, model, q_est0=q0, observations=y.unsqueeze(0), increments=increments,
                             R=None if R is None else R.unsqueeze(0), geometry=geometry)
        return ObservedRun(lc, history, q0[0], None, time.perf_counter() - start)
    prune = None if prune_after_s is None else max(1, int(np.searchsorted(lc.t, lc.t[0] + prune_after_s, "right")) - 1)
    bank = run_bank(cfg, model, observations=y, increments=increments, R=R,
                    q0=bank_attitudes(bank_size, dtype=y.dtype, device=y.device), keep=keep, geometry=geometry,
                    prune_after=prune, prune_keep=min(prune_keep, bank_size))
    best = _select(bank.kept, 0)
    return ObservedRun(lc, best, bank.q0[bank.order[0]], bank, time.perf_counter() - start)


def _select(history: FilterHistory, i: int) -> FilterHistory:
    """Filter ``i`` of a batched history, as a batch of one."""
    fields = {k: (v[i:i + 1] if isinstance(v, Tensor) else v) for k, v in vars(history).items()}
    return FilterHistory(**fields)


def euler321_jacobian(euler: Tensor) -> Tensor:
    """``∂(yaw, pitch, roll) / ∂δθ`` ``(..., 3, 3)`` of 3-2-1 angles ``euler (..., 3)`` (rad) for a small body-frame
    rotation ``δθ`` of the attitude, ``A → (I − [δθ×]) A`` (the filter's error, ``q = δq ⊗ q̂``): the inverse of the
    3-2-1 kinematics, singular at pitch ±90°. To first order the body z error moves yaw, y pitch and x roll."""
    pitch, roll = euler[..., 1], euler[..., 2]
    sr, cr, cp, tp = torch.sin(roll), torch.cos(roll), torch.cos(pitch), torch.tan(pitch)
    zero, one = torch.zeros_like(roll), torch.ones_like(roll)
    rows = [torch.stack([zero, sr / cp, cr / cp], -1), torch.stack([zero, cr, -sr], -1),
            torch.stack([one, sr * tp, cr * tp], -1)]
    return torch.stack(rows, -2)


def history_table(run: ObservedRun, rho_reference: float | None) -> Table:
    """The attitude history: time (ISO UTC), ``t_s``, ``q1…q4``, yaw/pitch/roll (deg, 3-2-1 of ``A(q)``), the 1σ
    of the attitude error about x, y, z (deg, from the GRP block of ``P``) and of yaw, pitch and roll (deg, the same
    block through :func:`euler321_jacobian`), the offset and ρ̂ with their 1σ when estimated, the observed and
    predicted magnitude with its σ (``√Pyy``), the innovation and the NIS; every column with its astropy unit."""
    h = run.history
    q = h.q_est[0].cpu()
    euler_rad = quat_to_euler321(q)
    euler = torch.rad2deg(euler_rad).numpy()
    P = h.P[0].cpu().to(euler_rad.dtype)
    sigma = torch.rad2deg(torch.diagonal(P, dim1=-2, dim2=-1).clamp_min(0).sqrt()).numpy()
    J = euler321_jacobian(euler_rad)
    sigma_euler = torch.diagonal(J @ P @ J.mT, dim1=-2, dim2=-1).clamp_min(0).sqrt().rad2deg().numpy()
    cols = {"time": iso_times(run.lc.times), "t_s": run.lc.t}
    cols.update({f"q{i + 1}": q[:, i].numpy() for i in range(4)})
    cols.update({"yaw_deg": euler[:, 0], "pitch_deg": euler[:, 1], "roll_deg": euler[:, 2]})
    cols.update({f"sigma_{a}_deg": sigma[:, i] for i, a in enumerate("xyz")})
    cols.update({f"sigma_{a}_deg": sigma_euler[:, i] for i, a in enumerate(("yaw", "pitch", "roll"))})
    if h.offset is not None:
        cols["offset_mag"] = h.offset[0].cpu().numpy()
        cols["offset_sigma_mag"] = h.offset_var[0].clamp_min(0).sqrt().cpu().numpy()
        if rho_reference is not None:
            cols["rho_hat"] = offset_to_rho(h.offset[0], rho_reference).cpu().numpy()
    cols.update({"mag_obs": run.lc.mag, "mag_pred": h.y_pred[0].cpu().numpy(),
                 "mag_pred_sigma": h.y_var[0].clamp_min(0).sqrt().cpu().numpy(),
                 "innovation": h.innovation[0].cpu().numpy(), "nis": h.nis()[0].cpu().numpy()})
    units = {"t_s": "s", **{f"q{i}": QUATERNION for i in range(1, 5)}, "rho_hat": "", "nis": "",
             **{name: "deg" for name in cols if name.endswith("_deg")},
             **{name: "mag" for name in cols if name.startswith(("mag_", "offset_")) or name == "innovation"}}
    return set_units(Table(cols), units, {"time": ISO_UTC, "t_s": "seconds from the first sample"})


def nis_summary(history: FilterHistory) -> dict:
    """Mean NIS of the updated steps against the 95 % band of the mean of ``n`` χ²(1) draws, and the share of
    steps whose NIS exceeds χ²(1)'s 95 % point (3.84; 5 % for a consistent filter)."""
    nis = history.nis()[0][history.updated[0]].cpu().double()
    n = int(nis.numel())
    if n == 0:
        return {"n": 0, "mean": math.nan, "band_95": [math.nan, math.nan], "in_band": False,
                "share_above_3.84": math.nan}
    lo, hi = chi2_band(1, n)
    mean = float(nis.mean())
    return {"n": n, "mean": mean, "band_95": [lo, hi], "in_band": bool(lo <= mean <= hi),
            "share_above_3.84": float((nis > 3.841458820694124).double().mean())}


def bank_table(bank: BankResult) -> Table:
    """Every bank member, best first: rank, index, initial quaternion, log-likelihood (nats), posterior weight and,
    when the bank was pruned, whether it ran the whole light curve (a pruned member's log-likelihood covers the first
    stretch only, its weight is 0); every column with its astropy unit (all dimensionless)."""
    order = bank.order.cpu()
    q0 = bank.q0.cpu()[order].numpy()
    cols = {"rank": np.arange(1, order.numel() + 1), "member": order.numpy(),
            **{f"q0_{i + 1}": q0[:, i] for i in range(4)},
            "log_likelihood": bank.log_likelihood.cpu()[order].numpy(), "weight": bank.weights.cpu()[order].numpy()}
    if bank.survivors is not None:
        cols["whole_curve"] = np.isin(order.numpy(), bank.survivors.cpu().numpy())
    units = {"rank": "", "member": "", **{f"q0_{i}": QUATERNION for i in range(1, 5)}, "log_likelihood": "",
             "weight": "", "whole_curve": ""}
    return set_units(Table(cols), units, {"log_likelihood": "nats"})
