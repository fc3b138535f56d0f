"""The multi-term periodogram of relative light curves over decades: the seed of the convex search's period.

A light curve's shape changes from one apparition to the next (another aspect, another phase angle) and every
relative curve has its own zero point, so the periodogram fits, at each trial frequency ``f``, a Fourier series of
``H`` harmonics *per apparition* (curves closer than ``gap_days`` in time) plus one offset per curve, and sums the
residual sums of squares over apparitions:

    χ²(f) = Σ_g min_{θ_g, o_c} Σ_{i∈g} (ỹ_i − o_c(i) − Σ_h θ_gh·[cos 2πh f t_i, sin 2πh f t_i])².

The offsets are profiled by removing every curve's mean from the data and from each basis column. The grid is
uniform in frequency with step ``1 / (oversample · T_g)``, ``T_g`` the longest apparition's span (the peaks are
that wide: the phase is not followed from one apparition to the next here; the convex search does that). A
double-peaked asteroid curve puts its strongest single harmonic at half the rotation period; with ``H ≥ 2`` the
minimum lies at the rotation period itself, and the search tries the candidates' doubles too.

Batched over frequencies (chunks of ``chunk``), float64.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

__all__ = ["ConvexPeriodogram", "apparitions", "multiterm_periodogram"]

HOUR_S = 3600.0


@dataclass(frozen=True)
class ConvexPeriodogram:
    """The periodogram of :func:`multiterm_periodogram`.

    Attributes:
        period_h: trial periods ``(F,)`` (h, decreasing: the grid is uniform in frequency).
        chi2: residual sum of squares at each ``(F,)`` (relative intensity²).
        minima_h: the periods of the deepest local minima, best first (h).
        peak_width_h: the half-width of a peak at the best period, ``P² / T_g`` (h).
        longest_group_h: ``T_g``, the longest apparition's span (h; at least the longest trial period).
        groups: apparitions found.
        seconds: time taken (s).
    """

    period_h: np.ndarray
    chi2: np.ndarray
    minima_h: np.ndarray
    peak_width_h: float
    longest_group_h: float
    groups: int
    seconds: float


def apparitions(t_s: Tensor, curve: Tensor, curves: int, *, gap_days: float = 60.0) -> Tensor:
    """The apparition ``(C,)`` (int64 from 0, in time order) of each light curve: curves whose time ranges are less
    than ``gap_days`` apart share one."""
    start = torch.full((curves,), math.inf, dtype=torch.float64).scatter_reduce(
        0, curve.cpu(), t_s.cpu(), reduce="amin")
    order = torch.argsort(start)
    group = torch.zeros(curves, dtype=torch.int64)
    g, last = 0, float(start[order[0]])
    for c in order.tolist():
        if float(start[c]) - last > gap_days * 86400.0:
            g += 1
        group[c], last = g, max(last, float(start[c]))
    return group


def multiterm_periodogram(t_s: Tensor, y: Tensor, curve: Tensor, curves: int, *, period_range_h=(2.0, 20.0),
                          harmonics: int = 4, oversample: float = 5.0, gap_days: float = 60.0,
                          minima: int = 5, chunk: int = 256) -> ConvexPeriodogram:
    """χ²(f) of per-apparition Fourier series with per-curve offsets (module docstring).

    Args:
        t_s: times ``(N,)`` (s); y: relative intensities ``(N,)``; curve: light curve per sample ``(N,)``;
        curves: their number ``C``.
        period_range_h: the shortest and longest trial period (h).
        harmonics: ``H``; oversample: grid points per peak width; gap_days: what separates apparitions.
        minima: local minima reported; chunk: frequencies per batch.
    """
    start = time.perf_counter()
    lo, hi = period_range_h
    if not 0 < lo < hi:
        raise ValueError(f"period range: need 0 < shortest < longest, got {lo:g} and {hi:g} h")
    t_s, y, curve = t_s.to(torch.float64), y.to(torch.float64), curve.to(t_s.device)
    group_of_curve = apparitions(t_s, curve, curves, gap_days=gap_days).to(t_s.device)
    group = group_of_curve[curve]
    groups = int(group_of_curve.max()) + 1
    span = torch.zeros(groups, dtype=torch.float64).scatter_reduce(0, group.cpu(), t_s.cpu(), "amax") - \
        torch.full((groups,), math.inf, dtype=torch.float64).scatter_reduce(0, group.cpu(), t_s.cpu(), "amin")
    longest = max(float(span.max()), 3600.0 * hi)
    counts = torch.bincount(curve, minlength=curves).to(torch.float64)

    def demean(x: Tensor) -> Tensor:                                   # (…, N) less each curve's mean
        sums = torch.zeros(*x.shape[:-1], curves, dtype=x.dtype, device=x.device).index_add_(-1, curve, x)
        return x - (sums / counts)[..., curve]

    yd = demean(y)
    members = [torch.nonzero(group == g).flatten() for g in range(groups)]
    df = 1.0 / (oversample * longest)
    freq = torch.arange(1.0 / (hi * HOUR_S), 1.0 / (lo * HOUR_S) + df, df, dtype=torch.float64)
    h = torch.arange(1, harmonics + 1, dtype=torch.float64)
    chi2 = torch.zeros_like(freq)
    eye = torch.eye(2 * harmonics, dtype=torch.float64)
    for s in range(0, freq.numel(), chunk):
        f = freq[s:s + chunk]
        turns = torch.remainder(f[:, None, None] * h[None, :, None] * t_s[None, None, :], 1.0)   # (F, H, N)
        arg = 2 * math.pi * turns
        X = demean(torch.cat([torch.cos(arg), torch.sin(arg)], 1))                              # (F, 2H, N)
        for idx in members:
            Xg, yg = X[:, :, idx], yd[idx]
            A = Xg @ Xg.transpose(1, 2)                                                         # (F, 2H, 2H)
            b = Xg @ yg                                                                         # (F, 2H)
            ridge = 1e-9 * torch.diagonal(A, dim1=-2, dim2=-1).mean(-1).clamp_min(1e-30)[:, None, None]
            sol = torch.linalg.solve(A + ridge * eye, b[..., None])[..., 0]
            chi2[s:s + chunk] += (yg * yg).sum() - (b * sol).sum(-1)
    period_h = (1.0 / freq / HOUR_S).numpy()
    c = chi2.numpy()
    interior = np.nonzero((c[1:-1] <= c[:-2]) & (c[1:-1] <= c[2:]))[0] + 1
    best = interior[np.argsort(c[interior])][:minima]
    p0 = float(period_h[best[0]]) if best.size else float(period_h[np.argmin(c)])
    return ConvexPeriodogram(period_h=period_h, chi2=c, minima_h=period_h[best], peak_width_h=p0 * p0 / (
        longest / HOUR_S), longest_group_h=longest / HOUR_S, groups=groups, seconds=time.perf_counter() - start)
