"""The GPUKF on an observed light curve (a light-curve file): attitude history, innovation statistics, global start.

The filter steps from sample to sample of the file (:mod:`lightcurve_gp.timeline`: increments from the config's
known spin, gaps and irregular steps as they are), with the per-sample measurement variance ``mag_err²`` when the
file gives ``mag_err`` (else ``filter.measurement_noise``). It starts from a given attitude or, without one, from the
global-start bank (:mod:`lightcurve_gp.global_start`). The user has no truth, so the run is judged by its innovations:
the NIS ``ν²/Pyy`` of a consistent filter is χ²(1), its mean over ``n`` samples lies in :func:`metrics.chi2_band`.

Geometry. The filter on a file takes the config's fixed Sun and observer (``geometry``); a file with per-sample
geometry columns or a TLE is refused (:func:`check_geometry_usable`) rather than run with a geometry it does not have.
Per-sample geometry enters here: the observation model would take the body-frame Sun and observer directions per
step (``A(q) s_k``, ``A(q) v_k``) and the range ``r_k`` (Eq. (8): ``+5 log10(r_k / r_ref)``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from astropy.table import Table
from torch import Tensor

from .global_start import BankResult, bank_attitudes, run_bank, run_filter
from .lightcurve_file import LightCurve, iso_times
from .metrics import chi2_band
from .rotations import quat_normalize, quat_to_euler321
from .timeline import spin_increments
from .ukf import FilterHistory
from .ukf_offset import offset_to_rho

__all__ = ["ObservedRun", "GeometryNotSupported", "check_geometry_usable", "file_inputs", "estimate_light_curve",
           "history_table", "nis_summary", "bank_table"]


class GeometryNotSupported(ValueError):
    """The file carries geometry that ``estimate --light-curve`` does not use yet."""


@dataclass
class ObservedRun:
    """One estimate on a file: the reported filter's history (batch 1), its start and the bank when one ran."""

    lc: LightCurve
    history: FilterHistory
    q_est0: Tensor
    bank: BankResult | None
    seconds: float


def check_geometry_usable(lc: LightCurve) -> None:
    """Refuse a file whose geometry ``estimate --light-curve`` does not use yet (module docstring)."""
    what = "per-sample geometry columns (sun_*, obs_*, range_km)" if lc.geometry is not None else \
        "a TLE (tle_line1, tle_line2)" if lc.has_tle else None
    if what is not None:
        raise GeometryNotSupported(
            f"{lc.source}: the file gives {what}, which estimate --light-curve does not use yet: it runs with the "
            f"config's fixed Sun and observer (geometry section); remove them from the file to run with the config's "
            f"geometry")


def file_inputs(cfg, lc: LightCurve) -> tuple[Tensor, Tensor, Tensor | None]:
    """``(observations (T+1,), increments (T, 4), R (T+1,) or None)`` of a file in the config's dtype/device."""
    dtype, device = cfg.torch_dtype, torch.device(cfg.device)
    t = torch.as_tensor(lc.t, dtype=dtype, device=device)
    omega0 = torch.deg2rad(torch.tensor(cfg.scenario.omega0_deg_s, dtype=dtype, device=device))
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=dtype, device=device)
    increments = spin_increments(t, omega0=omega0, inertia=inertia, max_step=float(cfg.scenario.dt_s))
    y = torch.as_tensor(lc.mag, dtype=dtype, device=device)
    R = None if lc.mag_err is None else torch.as_tensor(lc.mag_err, dtype=dtype, device=device) ** 2
    return y, increments, R


def estimate_light_curve(cfg, model, lc: LightCurve, *, initial_attitude: Tensor | None = None,
                         bank_size: int = 1024, keep: int = 5) -> ObservedRun:
    """The GPUKF of ``cfg`` on ``lc``: from ``initial_attitude (4,)`` when given, else from the best member of a
    bank of ``bank_size`` filters (the best ``keep`` are rerun with the config's settings)."""
    import time

    check_geometry_usable(lc)
    y, increments, R = file_inputs(cfg, lc)
    start = time.perf_counter()
    if initial_attitude is not None:
        q0 = quat_normalize(initial_attitude.to(y)).reshape(1, 4)
        history = run_filter(cfg, model, q_est0=q0, observations=y.unsqueeze(0), increments=increments,
                             R=None if R is None else R.unsqueeze(0))
        return ObservedRun(lc, history, q0[0], None, time.perf_counter() - start)
    bank = run_bank(cfg, model, observations=y, increments=increments, R=R,
                    q0=bank_attitudes(bank_size, dtype=y.dtype, device=y.device), keep=keep)
    best = _select(bank.kept, 0)
    return ObservedRun(lc, best, bank.q0[bank.order[0]], bank, time.perf_counter() - start)


def _select(history: FilterHistory, i: int) -> FilterHistory:
    """Filter ``i`` of a batched history, as a batch of one."""
    fields = {k: (v[i:i + 1] if isinstance(v, Tensor) else v) for k, v in vars(history).items()}
    return FilterHistory(**fields)


def history_table(run: ObservedRun, rho_reference: float | None) -> Table:
    """The attitude history: time (ISO UTC), ``t_s``, ``q1…q4``, yaw/pitch/roll (deg, 3-2-1 of ``A(q)``), the 1σ
    of the attitude error about x, y, z (deg, from the GRP block of ``P``), the offset and ρ̂ with their 1σ when
    estimated, the observed and predicted magnitude with its σ (``√Pyy``), the innovation and the NIS."""
    h = run.history
    q = h.q_est[0].cpu()
    euler = torch.rad2deg(quat_to_euler321(q)).numpy()
    sigma = torch.rad2deg(torch.diagonal(h.P[0], dim1=-2, dim2=-1).clamp_min(0).sqrt()).cpu().numpy()
    cols = {"time": iso_times(run.lc.times), "t_s": run.lc.t}
    cols.update({f"q{i + 1}": q[:, i].numpy() for i in range(4)})
    cols.update({"yaw_deg": euler[:, 0], "pitch_deg": euler[:, 1], "roll_deg": euler[:, 2]})
    cols.update({f"sigma_{a}_deg": sigma[:, i] for i, a in enumerate("xyz")})
    if h.offset is not None:
        cols["offset_mag"] = h.offset[0].cpu().numpy()
        cols["offset_sigma_mag"] = h.offset_var[0].clamp_min(0).sqrt().cpu().numpy()
        if rho_reference is not None:
            cols["rho_hat"] = offset_to_rho(h.offset[0], rho_reference).cpu().numpy()
    cols.update({"mag_obs": run.lc.mag, "mag_pred": h.y_pred[0].cpu().numpy(),
                 "mag_pred_sigma": h.y_var[0].clamp_min(0).sqrt().cpu().numpy(),
                 "innovation": h.innovation[0].cpu().numpy(), "nis": h.nis()[0].cpu().numpy()})
    return Table(cols)


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
    """Every bank member, best first: rank, index, initial quaternion, log-likelihood (nats), posterior weight."""
    order = bank.order.cpu()
    q0 = bank.q0.cpu()[order].numpy()
    return Table({"rank": np.arange(1, order.numel() + 1), "member": order.numpy(),
                  **{f"q0_{i + 1}": q0[:, i] for i in range(4)},
                  "log_likelihood": bank.log_likelihood.cpu()[order].numpy(),
                  "weight": bank.weights.cpu()[order].numpy()})
