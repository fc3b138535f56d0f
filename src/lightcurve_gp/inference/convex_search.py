"""Convex inversion with no pole and no period given: periodogram, batched screen, polish, families.

Stages (each timed in :attr:`ConvexSearch.seconds`):

1. ``periodogram`` — :func:`~lightcurve_gp.inference.convex_periodogram.multiterm_periodogram` over the period
   range; its ``period_candidates`` deepest distinct minima seed the scan.
2. ``coarse`` — around each seed, periods ``± window · P²/T_g`` (``T_g`` the longest apparition: the
   periodogram's peak width) at the step ``step · P²/T`` (``T`` the data's span: one rotation more or less over
   the span changes the phase by ``2π / (1/step)``) × a coarse Fibonacci grid of poles, screened by the linear
   area fit (:func:`~lightcurve_gp.inference.convex_fit.fit_areas`) on few normals and every ``subsample``-th
   sample, in float32. The rotation phase at the epoch is not scanned: a rotation about the body's ``z`` axis
   carries the Gaussian image with it, so the areas absorb it (convexinv fixes it too).
3. ``fine`` — the best periods of the coarse stage (``top_periods`` shared equally by the seeds' windows, so a
   seed and its double both go on) × a fine pole grid, on every sample and more normals.
4. ``polish`` — the ``starts`` best (pole, period) of the fine stage (shared equally by the seeds' windows, rounded
   up) that are more than ``separation_deg`` apart in pole (or differ in period), polished by
   Levenberg–Marquardt (:func:`polish_starts`) on the polish normals, the shape a free area per normal
   (``shape_degree`` 0) or log areas as a spherical-harmonic series of that degree; then ``refine_starts``
   starts on each of two rings, ``refine_deg`` and twice that about the best's pole, at its period, polished too,
   and again about the new best while one of them improves on it (``refine_rounds`` rounds at most; 0: none).
5. families — :func:`~lightcurve_gp.inference.convex_families.convex_families`: polished solutions merged by
   pole and period, weighted by their likelihood ratio to the best with correlated residuals counted once.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, fields

import numpy as np
import torch
from torch import Tensor

from lightcurve_gp.inference.convex_families import HOUR_S, ConvexFamilies, convex_families, distinct_solutions
from lightcurve_gp.inference.convex_fit import ConvexData, design, fit_areas
from lightcurve_gp.inference.convex_periodogram import ConvexPeriodogram, multiterm_periodogram
from lightcurve_gp.inference.convex_polish import Polished, polish
from lightcurve_gp.photometry.convex import (
    SatelliteScattering,
    Scattering,
    fibonacci_normals,
    pole_angles,
    pole_vector,
    real_harmonics,
    ring_normals,
)

__all__ = ["ConvexSettings", "ConvexSearch", "convex_search", "period_grid", "pole_grid", "polish_starts",
           "ring_poles", "search_normals"]



@dataclass(frozen=True)
class ConvexSettings:
    """What :func:`convex_search` does (module docstring); periods in hours, angles in degrees. ``ring`` > 0 adds
    that many normals on the body equator (:func:`~lightcurve_gp.photometry.convex.ring_normals`: faces parallel to
    the spin axis) and the two poles ``±z`` to every stage's Fibonacci normals; ``area_refine`` > 0 adds that many
    accelerated projected-gradient steps to every area fit (three times that many before the polish);
    ``magnitude_weights`` weights every fit's intensity residuals by ``1/ỹ``
    (:meth:`~lightcurve_gp.inference.convex_fit.ConvexData.magnitude_weighted`: magnitude-consistent, as magnitude
    noise is Gaussian), the screen, the polish and the families' ratios alike."""

    scattering: Scattering | SatelliteScattering = field(default_factory=Scattering)
    ring: int = 0
    period_range_h: tuple[float, float] = (2.0, 20.0)
    harmonics: int = 2
    period_candidates: int = 1
    window: float = 0.25
    step: float = 0.125
    coarse_poles: int = 24
    coarse_normals: int = 32
    subsample: int = 3
    top_periods: int = 6
    fine_poles: int = 200
    fine_normals: int = 60
    starts: int = 6
    separation_deg: float = 20.0
    polish_normals: int = 120
    polish_iterations: int = 80
    closure: float = 0.1
    smoothness: float = 0.0
    shape_degree: int = 0
    refine_starts: int = 4
    refine_deg: float = 7.0
    refine_rounds: int = 1
    area_iterations: int = 10
    area_refine: int = 0
    max_log_ratio: float = 10.0
    magnitude_weights: bool = False
    chunk: int = 128


def search_normals(count: int, ring: int) -> Tensor:
    """The normals ``(K, 3)`` of a stage: ``count`` Fibonacci normals, and with ``ring`` > 0 that many on the
    equator and the poles ``±z`` (:class:`ConvexSettings`)."""
    if ring <= 0:
        return fibonacci_normals(count)
    poles = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]], dtype=torch.float64)
    return torch.cat([fibonacci_normals(count), ring_normals(ring), poles])


def polish_starts(data: ConvexData, normals: Tensor, settings: ConvexSettings, *, lam: Tensor, beta: Tensor,
                  period_s: Tensor, areas: Tensor) -> Polished:
    """The search's polish (:func:`~lightcurve_gp.inference.convex_polish.polish`) of ``B`` starts (``lam``, ``beta``
    rad, ``period_s`` s, each ``(B,)``; ``areas`` ``(B, K)`` on ``normals``) under ``settings``: the shape is
    ``exp`` of a real spherical-harmonic series of degree ``shape_degree`` (0: free areas per normal); the data
    weighted by ``1/ỹ`` with ``magnitude_weights``."""
    basis = real_harmonics(normals, settings.shape_degree) if settings.shape_degree > 0 else None
    data = data.magnitude_weighted() if settings.magnitude_weights else data
    return polish(data, normals, settings.scattering, lam=lam, beta=beta, period_s=period_s, areas=areas,
                  closure=settings.closure, iterations=settings.polish_iterations, smoothness=settings.smoothness,
                  basis=basis)


def ring_poles(lam: float, beta: float, radius_rad: float, count: int) -> tuple[Tensor, Tensor]:
    """``count`` poles at the angle ``radius_rad`` around the pole (``lam``, ``beta``) (rad), evenly in azimuth:
    longitudes and latitudes (rad) ``(count,)``."""
    p = pole_vector(torch.tensor(lam, dtype=torch.float64), torch.tensor(beta, dtype=torch.float64))
    e1 = torch.linalg.cross(p, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    if float(e1.norm()) < 1e-6:                        # the pole on the ecliptic's: any tangent will do
        e1 = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    e1 = e1 / e1.norm()
    e2 = torch.linalg.cross(p, e1)
    theta = 2 * math.pi * torch.arange(count, dtype=torch.float64) / count
    v = (math.cos(radius_rad) * p + math.sin(radius_rad) * (torch.cos(theta)[:, None] * e1
                                                             + torch.sin(theta)[:, None] * e2))
    return pole_angles(v)


def _joined(a: Polished, b: Polished) -> Polished:
    return Polished(**{f.name: torch.cat([getattr(a, f.name), getattr(b, f.name)]) for f in fields(Polished)})


def pole_grid(n: int, *, dtype: torch.dtype = torch.float64) -> tuple[Tensor, Tensor]:
    """``n`` poles nearly uniform on the sphere: ecliptic longitudes and latitudes (rad) ``(n,)``."""
    return pole_angles(fibonacci_normals(n, dtype=dtype))


def period_grid(center_h: float, half_width_h: float, span_s: float, step: float) -> np.ndarray:
    """Periods (h) ``center ± half_width`` at the step ``step · P² / T`` (``T`` = ``span_s``), uniform in
    frequency (one rotation count apart every ``1/step`` points)."""
    span_h = span_s / HOUR_S
    f0, df = 1.0 / center_h, step / span_h
    half = max(1, int(math.ceil(half_width_h / center_h ** 2 / df)))
    return 1.0 / (f0 + df * np.arange(-half, half + 1))


@dataclass(frozen=True)
class ConvexSearch:
    """What :func:`convex_search` found.

    Attributes:
        periodogram: the seed's periodogram.
        families: the families (best first).
        normals: the polish normals ``(K, 3)`` (body frame) the areas belong to (``M·K`` areas per family, basis
            by basis: ``basis_names``).
        screened: candidates screened per stage.
        seconds: wall time per stage (s).
        coarse_periods_h, coarse_rms: the coarse stage's periods and their best rms over poles (the scan's
            profile, for the figure).
        residual_correlation, effective_samples: the best fit's residual lag-1 correlation within curves and the
            effective number of independent samples the likelihood ratios use.
    """

    periodogram: ConvexPeriodogram
    families: ConvexFamilies
    normals: Tensor
    screened: dict
    seconds: dict
    coarse_periods_h: np.ndarray
    coarse_rms: np.ndarray
    residual_correlation: float
    effective_samples: float
    basis_names: tuple[str, ...] = ("lommel_seeliger",)


def _screen(data: ConvexData, normals: Tensor, settings: ConvexSettings, lam: Tensor, beta: Tensor,
            period_s: Tensor, dtype: torch.dtype) -> Tensor:
    """Screen rms ``(B,)`` of ``B`` spin states, in chunks."""
    out = []
    for s in range(0, lam.shape[0], settings.chunk):
        sl = slice(s, s + settings.chunk)
        G = design(data, normals, settings.scattering, lam=lam[sl], beta=beta[sl], period_s=period_s[sl],
                   dtype=dtype)
        out.append(fit_areas(G, data, normals, closure=settings.closure, iterations=settings.area_iterations,
                             refine=settings.area_refine).rms)
    return torch.cat(out)


def _subsample(data: ConvexData, every: int) -> ConvexData:
    if every <= 1:
        return data
    keep = torch.zeros(len(data), dtype=torch.bool)
    for c in range(data.curves):                      # every `every`-th sample of each curve, its first included
        idx = torch.nonzero(data.curve == c).flatten()
        keep[idx[::every]] = True
    idx = torch.nonzero(keep).flatten()
    curve = data.curve[idx]
    return ConvexData(t_s=data.t_s[idx], sun=data.sun[idx], observer=data.observer[idx], alpha=data.alpha[idx],
                      y=data.y[idx], curve=curve, curves=data.curves,
                      counts=torch.bincount(curve, minlength=data.curves), span_s=data.span_s,
                      weight=None if data.weight is None else data.weight[idx])


def convex_search(data: ConvexData, settings: ConvexSettings = ConvexSettings(), *,
                  progress=None) -> ConvexSearch:
    """Pole, period and convex shape from relative light curves, nothing given (module docstring).

    Args:
        data: the prepared observations (:func:`~lightcurve_gp.inference.convex_fit.convex_data`).
        settings: the stages' sizes.
        progress: ``progress(message)`` after each stage, or ``None``.
    """
    say = progress or (lambda message: None)
    data = data.magnitude_weighted() if settings.magnitude_weights else data
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    pg = multiterm_periodogram(data.t_s, data.y, data.curve, data.curves, period_range_h=settings.period_range_h,
                               harmonics=settings.harmonics, minima=16)
    seeds: list[float] = []
    minima: list[float] = []
    for p in pg.minima_h:                            # the deepest distinct minima, each with its double
        if all(abs(p - q) > pg.peak_width_h for q in minima):
            minima.append(float(p))
            seeds += [float(p)] + ([2.0 * float(p)] if 2.0 * p <= settings.period_range_h[1] else [])
        if len(minima) == settings.period_candidates:
            break
    seconds["periodogram"] = time.perf_counter() - start
    say(f"periodogram: {pg.period_h.size} periods, seeds {', '.join(f'{p:.5f}' for p in seeds)} h "
        f"({seconds['periodogram']:.1f} s)")

    start = time.perf_counter()
    windows = [period_grid(p, settings.window * p * p / pg.longest_group_h, data.span_s, settings.step)
               for p in seeds]
    window_of = np.concatenate([np.full(w.size, k) for k, w in enumerate(windows)])
    periods = np.concatenate(windows)
    lam_c, beta_c = pole_grid(settings.coarse_poles)
    coarse_normals = search_normals(settings.coarse_normals, settings.ring)
    sub = _subsample(data, settings.subsample)
    P, C = periods.size, lam_c.numel()
    per = torch.as_tensor(periods * HOUR_S, dtype=torch.float64).repeat_interleave(C)
    rms = _screen(sub, coarse_normals, settings, lam_c.repeat(P), beta_c.repeat(P), per, torch.float32)
    rms = rms.reshape(P, C)
    best_per_period = rms.min(-1).values.numpy()
    # the best periods of each seed's window (a body fits at half its period too, sometimes better on few normals)
    per_window = max(1, settings.top_periods // len(windows))
    top = np.concatenate([np.nonzero(window_of == k)[0][np.argsort(best_per_period[window_of == k])[:per_window]]
                          for k in range(len(windows))])
    top = top[np.argsort(best_per_period[top])]
    seconds["coarse"] = time.perf_counter() - start
    say(f"coarse: {P} periods x {C} poles ({seconds['coarse']:.1f} s); best periods "
        f"{', '.join(f'{periods[i]:.6f}' for i in top[:3])} h")

    start = time.perf_counter()
    lam_f, beta_f = pole_grid(settings.fine_poles)
    fine_normals = search_normals(settings.fine_normals, settings.ring)
    F = lam_f.numel()
    fine_periods = periods[top]
    per = torch.as_tensor(fine_periods * HOUR_S, dtype=torch.float64).repeat_interleave(F)
    lam_all, beta_all = lam_f.repeat(top.size), beta_f.repeat(top.size)
    rms_f = _screen(data, fine_normals, settings, lam_all, beta_all, per, torch.float32).numpy()
    seconds["fine"] = time.perf_counter() - start
    order = np.argsort(rms_f)
    step_h = settings.step * fine_periods.max() ** 2 / (data.span_s / HOUR_S)
    cand_window = np.repeat(window_of[top], F)
    per_start = math.ceil(settings.starts / len(windows))              # every seed's window gets its starts
    picks = sorted((k for w in range(len(windows)) for k in distinct_solutions(
        order[cand_window[order] == w], lam_all.numpy(), beta_all.numpy(), per.numpy() / HOUR_S, per_start,
        settings.separation_deg, 0.5 * step_h)), key=lambda k: rms_f[k])
    say(f"fine: {top.size} periods x {F} poles ({seconds['fine']:.1f} s); best rms {rms_f[order[0]]:.4f}")

    start = time.perf_counter()
    normals = search_normals(settings.polish_normals, settings.ring)
    idx = torch.as_tensor(picks)
    G = design(data, normals, settings.scattering, lam=lam_all[idx], beta=beta_all[idx], period_s=per[idx])
    init = fit_areas(G, data, normals, closure=settings.closure, iterations=3 * settings.area_iterations,
                     refine=3 * settings.area_refine)
    polished = polish_starts(data, normals, settings, lam=lam_all[idx], beta=beta_all[idx], period_s=per[idx],
                             areas=init.areas)
    for _ in range(settings.refine_rounds if settings.refine_starts > 0 else 0):
        # around the best: starts on rings of refine_deg and twice that about its pole at its period (the screen's
        # grid is coarser than the polish's minima; a neighbouring minimum can be nats better); again while the
        # best moves
        rss = torch.where(torch.isfinite(polished.fit_rms), polished.fit_rms,
                          torch.full_like(polished.fit_rms, math.inf))
        b = int(rss.argmin())
        rings = [ring_poles(float(polished.lam[b]), float(polished.beta[b]), math.radians(k * settings.refine_deg),
                            settings.refine_starts) for k in (1, 2)]
        lam_r, beta_r = torch.cat([r[0] for r in rings]), torch.cat([r[1] for r in rings])
        per_r = polished.period_s[b].repeat(lam_r.numel())
        G = design(data, normals, settings.scattering, lam=lam_r, beta=beta_r, period_s=per_r)
        init = fit_areas(G, data, normals, closure=settings.closure, iterations=3 * settings.area_iterations,
                         refine=3 * settings.area_refine)
        more = polish_starts(data, normals, settings, lam=lam_r, beta=beta_r, period_s=per_r, areas=init.areas)
        polished = _joined(polished, more)
        if not bool((more.fit_rms < rss[b]).any()):
            break
    seconds["polish"] = time.perf_counter() - start
    fam, rho, n_eff = convex_families(polished, data, normals, scattering=settings.scattering,
                                      separation_deg=settings.separation_deg,
                                      max_log_ratio=settings.max_log_ratio, resolution_h=step_h)
    deg = lambda x: math.degrees(float(x))  # noqa: E731
    for i, k in enumerate(picks):
        say(f"  start {i + 1}: ({deg(lam_all[k]):.1f}, {deg(beta_all[k]):.1f}, {float(per[k]) / HOUR_S:.6f} h) "
            f"screen rms {rms_f[k]:.4f} -> ({deg(polished.lam[i]):.1f}, {deg(polished.beta[i]):.1f}, "
            f"{float(polished.period_s[i]) / HOUR_S:.8f} h) rms {float(polished.rms[i]):.5f}")
    say(f"polish: {len(picks)} starts ({seconds['polish']:.1f} s); {len(fam)} families (residual lag-1 correlation "
        f"{rho:.2f}: {n_eff:.0f} effective samples)")
    return ConvexSearch(periodogram=pg, families=fam, normals=normals, residual_correlation=rho,
                        effective_samples=n_eff, basis_names=settings.scattering.basis_names(),
                        screened={"coarse": P * C, "fine": int(per.numel()), "polish": int(polished.rms.numel())},
                        seconds=seconds, coarse_periods_h=periods, coarse_rms=best_per_period)
