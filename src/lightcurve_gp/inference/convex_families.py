"""The families of a convex inversion: polished (pole, period) solutions merged and weighted.

Solutions are merged when their poles are within ``separation_deg`` and their periods within the resolution; each
family's log-likelihood ratio to the best is ``N_eff (rss / rss_best − 1) / 2``: the noise variance is the best
fit's residual variance (the DAMIT format gives no 1σ) and, since the residuals of a model that is not exact are
correlated along a light curve, ``N_eff = N / τ`` with ``τ`` their integrated autocorrelation time within curves
(:func:`effective_samples`; uncorrelated residuals give the plain ratio). Those within ``max_log_ratio`` nats are
kept, weighted by ``exp(−ratio)``; the best solution at the best's mirror pole (λ + 180°, β) is reported too,
flagged, when it lies beyond.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from lightcurve_gp.inference.convex_fit import ConvexData, relative_residuals
from lightcurve_gp.inference.convex_polish import Polished
from lightcurve_gp.photometry.convex import SatelliteScattering, Scattering, pole_vector

__all__ = ["HOUR_S", "ConvexFamilies", "convex_families", "distinct_solutions", "effective_samples"]

HOUR_S = 3600.0


@dataclass(frozen=True)
class ConvexFamilies:
    """Pole/period families within the likelihood ratio, best first (``F`` of them), and the best solution at the
    mirror pole of the best (λ + 180°, β) when it lies beyond the ratio (last, weight 0, ``within_ratio`` false).

    Attributes:
        lam_deg, beta_deg: pole (deg) ``(F,)`` (``β`` past ±90° where the polish crossed the ecliptic's pole: the
            state that reproduces the fit, :class:`~lightcurve_gp.inference.convex_polish.Polished`); period_h:
            sidereal period ``(F,)`` (h); period_sigma_h: its 1σ.
        rms: convexinv's rms (relative intensity) ``(F,)``; log_ratio: nats below the best ``(F,)``;
        weight: ``exp(−log_ratio)`` normalised over the families within the ratio ``(F,)``; areas: ``(F, K)``
        (relative, summing to 1); within_ratio: ``(F,)`` bool.
    """

    lam_deg: np.ndarray
    beta_deg: np.ndarray
    period_h: np.ndarray
    period_sigma_h: np.ndarray
    rms: np.ndarray
    log_ratio: np.ndarray
    weight: np.ndarray
    areas: np.ndarray
    within_ratio: np.ndarray

    def __len__(self) -> int:
        return int(self.lam_deg.size)


def distinct_solutions(order: np.ndarray, lam: np.ndarray, beta: np.ndarray, period: np.ndarray, count: int,
              separation_deg: float, period_tol_h: float) -> list[int]:
    """The first ``count`` indices of ``order`` whose (pole, period) is not within ``separation_deg`` and
    ``period_tol_h`` of one already taken."""
    taken: list[int] = []
    v = pole_vector(torch.as_tensor(lam), torch.as_tensor(beta)).numpy()
    cos_sep = math.cos(math.radians(separation_deg))
    for i in order:
        if all(v[i] @ v[j] < cos_sep or abs(period[i] - period[j]) > period_tol_h for j in taken):
            taken.append(int(i))
        if len(taken) == count:
            break
    return taken


def effective_samples(r: Tensor, curve: Tensor, *, max_lag: int = 50) -> tuple[float, float]:
    """The lag-1 autocorrelation ``ρ_1`` of residuals ``r`` ``(N,)`` within light curves (samples in time order)
    and the effective number of independent samples ``N / τ``, ``τ = 1 + 2 Σ_k ρ_k`` the integrated
    autocorrelation time summed over lags until the first ``ρ_k ≤ 0`` (Geyer's initial positive sequence; at most
    ``max_lag``). For AR(1) residuals ``τ = (1 + ρ)/(1 − ρ)``."""
    power = (r * r).sum().clamp_min(1e-300)
    tau, rho1 = 1.0, 0.0
    for k in range(1, min(max_lag, r.numel() - 1) + 1):
        same = curve[k:] == curve[:-k]
        rho = float(((r[k:] * r[:-k])[same]).sum() / power)
        if k == 1:
            rho1 = max(rho, 0.0)
        if rho <= 0:
            break
        tau += 2 * rho
    return rho1, r.numel() / tau


def convex_families(p: Polished, data: ConvexData, normals: Tensor, *, scattering: Scattering | SatelliteScattering,
                    separation_deg: float, max_log_ratio: float,
                    resolution_h: float) -> tuple[ConvexFamilies, float, float]:
    """The families of the polished solutions ``p`` (module docstring), the best fit's residual lag-1 correlation
    and the effective number of samples."""
    rss = (p.fit_rms ** 2 * len(data)).numpy()
    rss = np.where(np.isfinite(rss), rss, np.inf)                       # a polish that failed ranks last
    lam, beta = np.degrees(p.lam.numpy()), np.degrees(p.beta.numpy())
    period = p.period_s.numpy() / HOUR_S
    order = np.argsort(rss)
    keep = distinct_solutions(order, np.radians(lam), np.radians(beta), period, order.size, separation_deg,
                     resolution_h)
    b = keep[0]
    r = relative_residuals(data, normals, scattering, lam=p.lam[b:b + 1], beta=p.beta[b:b + 1],
                           period_s=p.period_s[b:b + 1], areas=p.areas[b:b + 1])[0] * data.weights()
    rho, n_eff = effective_samples(r, data.curve)
    ratio_all = 0.5 * n_eff * (rss[keep] / rss[b] - 1.0)
    within = [k for k, q in zip(keep, ratio_all) if q <= max_log_ratio or k == b]
    # the best solution at the mirror pole (λ + 180°, β) of the best is reported even beyond the ratio
    v = pole_vector(torch.as_tensor(np.radians(lam)), torch.as_tensor(np.radians(beta))).numpy()
    mirror = pole_vector(torch.as_tensor(math.radians(lam[b] + 180.0)), torch.as_tensor(math.radians(beta[b])))
    near = [k for k in keep if v[k] @ mirror.numpy() > math.cos(math.radians(separation_deg))]
    extra = [near[0]] if near and near[0] not in within else []
    rows = within + extra
    ratio = ratio_all[[keep.index(k) for k in rows]]
    weight = np.where(np.arange(len(rows)) < len(within), np.exp(-ratio), 0.0)
    fam = ConvexFamilies(lam_deg=lam[rows], beta_deg=beta[rows], period_h=period[rows],
                         period_sigma_h=p.period_sigma_s.numpy()[rows] / HOUR_S, rms=p.rms.numpy()[rows],
                         log_ratio=ratio, weight=weight / weight.sum(), areas=p.areas.numpy()[rows],
                         within_ratio=np.arange(len(rows)) < len(within))
    return fam, rho, n_eff
