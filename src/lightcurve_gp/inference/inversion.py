"""Global inversion of a light curve: the initial attitude, body rate and ρ with no initial guess.

Robinson & Frueh's recipe (dominant frequency first, then many independent local optimisations, every solution
within a likelihood ratio of the best kept) in batched tensors, on one :class:`.trajectory.TrajectoryProblem`:

1. **Rates.** The periodogram (:mod:`.periodogram`) proposes rate magnitudes; with a log-spaced grid over the rate
   range (below one turn over the arc the periodogram has no resolution) they make the shells of the rate starts,
   each shell with directions spread over the sphere (a Fibonacci lattice), more at larger rates
   (:func:`rate_starts`).
2. **Screening.** Every rate of the grid with every attitude of a scrambled Sobol' set over SO(3): ``R``
   propagations and ``R·A`` light curves over an arc, ρ profiled; the best grid points start. Each rate is
   screened on the first arc over which it turns by at least ``entry_turn_deg`` (:func:`entry_stages`) and its
   grid points enter the continuation at that arc; the starts are shared among the entry arcs in proportion to
   their grid points (measured on tuning seeds at 0.35–0.6 °/s, σ = 0.1 mag: on the 30 s arc a state of such a
   rate turns 10–18°, every one of the 4000 starts fitted that arc better than the truth, the truth's rows ranked
   600–1600th and the pruning to 1000 and 300 rows lost them: 3 search misses in 4 seeds, up to 2100 nats). Each
   rate is also screened on the arc before its entry arc (``early_arcs``): fast tumblers were found from a slower
   shell's start on the shorter arc (tuning seed 13, 1.47 °/s, from a 0.85 °/s start on 30 s), lost when that
   shell entered at 60 s alone.
3. **Continuation.** Levenberg–Marquardt (:func:`.solver.batch_least_squares`, the problem's closed-form
   Jacobian) on arcs of growing length (``arcs_s``), each stage on the best rows of the previous one (one row per
   solution modulo the exact group) and the rows entering at its arc; the rows screened on one arc (a cohort) are
   pruned among themselves to their quota (:func:`cohort_quotas`: the largest cohort a share of the starts,
   :meth:`InversionSettings.stage_keep`, the others in proportion to their starts), so rows entering later never
   crowd out those carried, and beyond it to every row within ``tie_nats`` of the cohort's best
   (:func:`tied_keep`): an arc that cannot tell rows apart by the reporting ratio does not prune them (measured on
   tuning seed 31 at 0.71 mag, 2.37 °/s, with every row carried: on the 30 s arc all of the ~6100 rows of the first
   cohort lay within 10 nats of its best, on 60 s 75 % of them, on 120 s 26 %, on 240 s 1.5 %; the quotas kept
   2500, 750, 250 and 125 rows, chosen by arcs that held no information, and the answer ended 117 nats above the
   truth's basin; with the ties kept it reaches the basin, as tuning seeds 34, 44 and 51 do, missed by 24–146 nats
   before (those three measured with no cap); at 0.05 mag on the benchmark's light curve no arc has more ties than
   its quota). The ties kept are at most :data:`TIE_CAP` times the quota: a slow tumbler's ridge ties thousands of
   rows on the long arcs (seed 1001 at 0.1 mag, 0.11 °/s: the whole answer took 558 s with no cap, 225 s capped at
   8×, 190 s at 4×, 110 s before the ties, on two busy cores), and at 4× tuning seed 31 is missed again (33 nats),
   at 8× it is reached. Each stage but the whole light curve's has a Gaussian prior of standard deviation
   ``turn_rad / arc`` on the change of the rate (a short arc cannot tell the rate better; without it the rate
   wanders along the short arc's flat directions).
4. The survivors, polished on the whole light curve, with their Laplace covariance, go to :mod:`.families`.

Everything is one set of tensors on the problem's device and dtype; ``progress`` (a callable of a message) reports
each stage.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import torch
from torch import Tensor

from lightcurve_gp.attitude.sampling import sobol_attitudes
from lightcurve_gp.inference.families import cluster
from lightcurve_gp.inference.periodogram import Periodogram, periodogram, resolution_rate_deg_s
from lightcurve_gp.inference.solver import GaussianPrior, LeastSquaresOptions, batch_least_squares
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup

__all__ = ["TIE_CAP", "InversionSettings", "Inversion", "rate_starts", "entry_stages", "screened_at", "cohort_quotas",
           "tied_keep", "prune_rows", "screen", "invert", "polish"]


#: the ties a cohort keeps beyond its quota are at most this many times the quota (:func:`tied_keep`)
TIE_CAP = 8.0


@dataclass(frozen=True)
class InversionSettings:
    """How :func:`invert` searches (module docstring).

    Attributes:
        starts: grid points that start the first Levenberg–Marquardt stage.
        screen_factor: grid points screened per start (the screening grid has ``starts · screen_factor`` points).
        attitudes: Sobol' attitudes of the screening grid (its rates: ``starts · screen_factor / attitudes``).
        rate_range_deg_s: the rates searched (°/s).
        shell_ratio: ratio of neighbouring rate shells of the log grid.
        arcs_s: arc length of each stage (s); 0 means the whole light curve.
        keep_share: rows entering each stage after the first, as a share of ``starts`` (one per stage after the
            first; :meth:`stage_keep`): 1000, 300, 100 and 50 rows of 4000 starts, so that more starts keep more
            of the rows screened on the short first arcs, where a wrong state fits as well as the truth.
        keep: rows entering each stage after the first as counts, which replace ``keep_share`` (``None``: the
            shares).
        iterations: Levenberg–Marquardt iterations per stage; final_iterations: on the whole light curve (few rows).
        turn_rad: the rate prior of a stage on an arc of ``L`` s has the standard deviation ``turn_rad / L``.
        entry_turn_deg: a screened rate enters at the first arc over which it turns by at least this (deg; 0: every
            rate at the first arc).
        early_arcs: a rate is also screened on, and enters at, this many arcs before its entry arc (0: its entry arc
            alone).
        cohort_quotas: the rows that entered at one arc (a cohort) are pruned among themselves, to
            :func:`cohort_quotas` of ``keep``, so rows entering later never crowd out those carried; False: all rows
            compete for ``keep``.
        tie_nats: a cohort keeps, beyond its quota, every row within this many nats of its best on the arc, at most
            ``tie_cap`` times its quota (:func:`tied_keep`; ``None``: the quota alone).
        cluster_angle_deg, cluster_rate_deg_s: solutions this close modulo the group are one.
        seed: of the Sobol' attitudes.
        nterms: Fourier terms of the periodogram.
    """

    starts: int = 10_000
    screen_factor: int = 4
    attitudes: int = 256
    rate_range_deg_s: tuple[float, float] = (0.05, 5.0)
    shell_ratio: float = 1.5
    arcs_s: tuple[float, ...] = (30.0, 60.0, 120.0, 240.0, 0.0)
    keep_share: tuple[float, ...] = (0.25, 0.075, 0.025, 0.0125)
    keep: tuple[int, ...] | None = None
    iterations: int = 5
    final_iterations: int = 8
    turn_rad: float = 0.35
    entry_turn_deg: float = 30.0
    early_arcs: int = 1
    cohort_quotas: bool = True
    tie_nats: float | None = 10.0
    tie_cap: float = TIE_CAP
    cluster_angle_deg: float = 5.0
    cluster_rate_deg_s: float = 0.05
    seed: int = 0
    nterms: int = 2

    def __post_init__(self) -> None:
        if self.starts < 1:
            raise ValueError(f"--starts: {self.starts} must be >= 1")
        lo, hi = self.rate_range_deg_s
        if not 0.0 < lo < hi:
            raise ValueError(f"rate range: need 0 < min < max (deg/s), got {lo:g} to {hi:g}")
        if self.early_arcs < 0:
            raise ValueError(f"early_arcs: {self.early_arcs} must be >= 0")
        keep = self.stage_keep()
        if len(keep) != len(self.arcs_s) - 1 or not self.arcs_s:
            raise ValueError(f"keep: {len(keep)} values for {len(self.arcs_s)} stages; need one per stage after "
                             "the first")
        if min(keep, default=1) < 1:
            raise ValueError(f"keep: {keep} must be >= 1 row per stage")

    def stage_keep(self) -> tuple[int, ...]:
        """Rows kept for each stage after the first: ``keep`` or ``round(share · starts)``, at least 1."""
        if self.keep is not None:
            return tuple(self.keep)
        return tuple(max(1, round(share * self.starts)) for share in self.keep_share)


@dataclass
class Inversion:
    """Converged solutions on the whole light curve (``M`` rows) and how the search went.

    Attributes:
        q0: initial attitudes ``(M, 4)``; omega0: initial body rates ``(M, 3)`` (rad/s); log_rho: ``ln ρ̂ (M,)``.
        cost: ``½ Σ r²`` on the whole light curve ``(M,)``; covariance: Laplace covariance ``(M, 7, 7)``.
        periodogram: the periodogram and its rate candidates.
        rate_grid: the screened rates ``(R, 3)`` (rad/s).
        seconds: wall time per phase.
    """

    q0: Tensor
    omega0: Tensor
    log_rho: Tensor
    cost: Tensor
    covariance: Tensor
    periodogram: Periodogram
    rate_grid: Tensor
    seconds: dict = field(default_factory=dict)


def _fibonacci_sphere(n: int, *, dtype: torch.dtype, device) -> Tensor:
    """``n`` near-uniform unit vectors ``(n, 3)`` (the golden-angle spiral)."""
    k = torch.arange(n, dtype=dtype, device=device) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = math.pi * (3.0 - math.sqrt(5.0)) * k
    r = torch.sqrt((1.0 - z * z).clamp_min(0.0))
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)


def rate_starts(candidates_deg_s, *, count: int, rate_range_deg_s: tuple[float, float], span_s: float,
                shell_ratio: float = 1.5, dtype: torch.dtype = torch.float64, device=None) -> Tensor:
    """About ``count`` start rates ``(R, 3)`` (rad/s): shells at the periodogram's candidates (those above its
    resolution, :func:`~.periodogram.resolution_rate_deg_s`) and at a log grid of ratio ``shell_ratio`` over the
    rate range, each with directions on the sphere in proportion to its magnitude squared (at least 6)."""
    lo, hi = rate_range_deg_s
    grid = [lo * shell_ratio ** k for k in range(int(math.log(hi / lo) / math.log(shell_ratio)) + 1)]
    floor = resolution_rate_deg_s(span_s)
    shells = sorted(set(grid) | {float(c) for c in candidates_deg_s if c >= floor})
    share = torch.tensor(shells, dtype=torch.float64) ** 2
    per = torch.clamp(torch.round(count * share / share.sum()), min=6).long().tolist()
    out = [math.radians(s) * _fibonacci_sphere(n, dtype=dtype, device=device) for s, n in zip(shells, per)]
    return torch.cat(out)


def entry_stages(rates: Tensor, *, arcs_s: tuple[float, ...], span_s: float, turn_deg: float) -> Tensor:
    """The stage ``(R,)`` at which each rate of ``rates (R, 3)`` (rad/s) enters the continuation: the first whose arc
    (``arcs_s``, 0 the whole ``span_s``) it turns over by at least ``turn_deg``; never the last stage (the whole
    light curve's polish, without the rate prior) unless it is the only one: the one before it when none turns
    enough."""
    length = torch.tensor([a if a > 0 else span_s for a in arcs_s], dtype=rates.dtype, device=rates.device)
    turned = torch.rad2deg(torch.linalg.vector_norm(rates, dim=-1))[:, None] * length >= turn_deg  # (R, S)
    last = max(len(arcs_s) - 2, 0)
    turned[:, last:] = True
    return turned.to(torch.int8).argmax(-1)


def screened_at(entry: Tensor, *, stages: int, early_arcs: int) -> Tensor:
    """Which rates are screened on each stage's arc ``(S, R)`` (bool), from their entry stages ``entry (R,)``
    (:func:`entry_stages`): the entry arc and the ``early_arcs`` arcs before it."""
    stage = torch.arange(stages, device=entry.device)[:, None]
    return (entry[None] >= stage) & (entry[None] <= stage + early_arcs)


def screen(problem: TrajectoryProblem, *, rates: Tensor, attitudes: Tensor, starts: int) -> tuple[Tensor, Tensor]:
    """The ``starts`` best points of the grid ``rates (R, 3)`` × ``attitudes (A, 4)`` on ``problem``'s arc, ρ
    profiled: their anchors ``(N, 4)`` and states ``x (N, 7)`` (``θ = 0``)."""
    cost, beta = problem.grid_cost(rates, attitudes)  # (R, A)
    best = torch.topk(cost.flatten(), min(starts, cost.numel()), largest=False).indices
    r, a = best // attitudes.shape[0], best % attitudes.shape[0]
    x = torch.cat([torch.zeros(best.numel(), 3, dtype=rates.dtype, device=rates.device), rates[r],
                   beta.flatten()[best].unsqueeze(-1)], -1)
    return attitudes[a], x


def _stage(problem: TrajectoryProblem, x: Tensor, *, prior_sd: float | None, iterations: int,
           covariance: str = "none"):
    """One Levenberg–Marquardt stage on ``problem`` (anchors set) from ``x (N, 7)``; the rate's prior is centred on
    the starting rates with standard deviation ``prior_sd`` (rad/s), none when ``None``."""
    prior = None
    if prior_sd is not None:
        precision = torch.zeros(7, dtype=x.dtype, device=x.device)
        precision[3:6] = prior_sd ** -2
        prior = GaussianPrior.independent(x.clone(), precision)
    tolerance = torch.tensor([1e-7] * 3 + [1e-10] * 3 + [1e-6], dtype=x.dtype, device=x.device)
    options = LeastSquaresOptions(method="levenberg_marquardt", iterations=iterations, jacobian="provided",
                                  tolerance=tolerance, covariance=covariance)
    return batch_least_squares(problem, x, prior=prior, options=options)


def _reanchor(problem: TrajectoryProblem, x: Tensor) -> tuple[Tensor, Tensor]:
    """Anchors ``q_0`` of the states and the states with ``θ = 0``."""
    anchors = problem.initial_attitudes(x, torch.arange(x.shape[0], device=x.device))
    return anchors, torch.cat([torch.zeros_like(x[:, :3]), x[:, 3:]], -1)


def cohort_quotas(keep: int, starts: list[int]) -> list[int]:
    """Rows kept of each cohort (the rows that entered at one arc, ``starts[c]`` of them screened in) when a stage
    keeps ``keep``: the largest cohort keeps ``keep``, each other its starts' share of it, ``⌈keep · n_c / max n⌉``
    (a cohort of no starts none)."""
    most = max(starts, default=0)
    return [math.ceil(keep * n / most) if n else 0 for n in starts]


def tied_keep(cost: Tensor, *, keep: int, tie_nats: float | None, tie_cap: float = TIE_CAP) -> int:
    """Rows to keep of ``cost (N,)``: ``keep``, or more where more rows lie within ``tie_nats`` of the best (the arc
    cannot tell them from it; ``None``: ``keep``), at most ``tie_cap · keep`` and never more than ``N``."""
    if tie_nats is None or not cost.numel():
        return min(keep, cost.numel())
    ties = int((cost <= cost.min() + tie_nats).sum())
    return min(max(keep, min(ties, math.ceil(tie_cap * keep))), cost.numel())


def prune_rows(group: AmbiguityGroup, anchors: Tensor, omega: Tensor, cost: Tensor, *, keep: int,
               cohort: Tensor | None = None, quotas: list[int] | None = None, angle_deg: float = 5.0,
               rate_deg_s: float = 0.05, tie_nats: float | None = None, tie_cap: float = TIE_CAP) -> Tensor:
    """Indices of the rows kept of ``anchors (N, 4)``, ``omega (N, 3)`` (rad/s), ``cost (N,)``: the best ``keep``
    (more with ``tie_nats``: :func:`tied_keep`), one per solution modulo ``group`` (the best ``4 keep`` by cost
    clustered within ``angle_deg`` and ``rate_deg_s``); with ``cohort (N,)`` (each row's cohort index) and
    ``quotas`` (rows per cohort), the same within each cohort on its own, ``quotas[c]`` rows of cohort ``c``."""
    if cohort is None:
        keep = tied_keep(cost, keep=keep, tie_nats=tie_nats, tie_cap=tie_cap)
        top = torch.topk(cost, min(4 * keep, cost.numel()), largest=False).indices
        _, heads = cluster(group, anchors[top], omega[top], cost[top], angle_deg=angle_deg, rate_deg_s=rate_deg_s)
        return top[heads[:keep]]
    parts = []
    for c, quota in enumerate(quotas):
        mine = torch.nonzero(cohort == c).flatten()
        if quota and mine.numel():
            parts.append(mine[prune_rows(group, anchors[mine], omega[mine], cost[mine], keep=quota,
                                         angle_deg=angle_deg, rate_deg_s=rate_deg_s, tie_nats=tie_nats,
                                         tie_cap=tie_cap)])
    return torch.cat(parts) if parts else cohort.new_zeros(0)


def _arc_samples(problem: TrajectoryProblem, arc_s: float) -> int:
    """Samples of ``problem`` within the first ``arc_s`` seconds (all of them for 0)."""
    if arc_s <= 0:
        return problem.samples
    return max(8, int((problem.times <= arc_s).sum()))


def invert(problem: TrajectoryProblem, group: AmbiguityGroup, *, settings: InversionSettings = InversionSettings(),
           rate_grid: Tensor | None = None, progress: Callable[[str], None] | None = None) -> Inversion:
    """Search ``problem`` (its anchors are ignored) from no initial guess (module docstring); ``rate_grid (R, 3)``
    (rad/s) replaces the rates of :func:`rate_starts` (e.g. a known spin)."""
    say = progress or (lambda message: None)
    seconds, tick = {}, time.perf_counter()
    t_s = problem.times.cpu().numpy()
    pg = periodogram(t_s, problem.y.cpu().numpy(), problem.sigma.cpu().numpy(),
                     rate_range_deg_s=settings.rate_range_deg_s, nterms=settings.nterms)
    n_rates = max(1, settings.starts * settings.screen_factor // settings.attitudes)
    rates = rate_starts(pg.rates_deg_s, count=n_rates, rate_range_deg_s=settings.rate_range_deg_s,
                        span_s=float(t_s[-1] - t_s[0]), shell_ratio=settings.shell_ratio, dtype=problem.y.dtype,
                        device=problem.y.device) if rate_grid is None else rate_grid
    attitudes = sobol_attitudes(settings.attitudes, settings.seed, dtype=problem.y.dtype, device=problem.y.device)
    seconds["periodogram"], tick = time.perf_counter() - tick, time.perf_counter()
    stage_keep = settings.stage_keep()
    entry = entry_stages(rates, arcs_s=settings.arcs_s, span_s=float(t_s[-1] - t_s[0]),
                         turn_deg=settings.entry_turn_deg)
    screened = screened_at(entry, stages=len(settings.arcs_s), early_arcs=settings.early_arcs)
    points = int(screened.sum())
    entering, cohort_starts = [], []
    for stage, arc_s in enumerate(settings.arcs_s):
        mine = screened[stage]
        n = int(mine.sum())
        if not n:
            entering.append(None)
            cohort_starts.append(0)
            continue
        part = problem.arc(_arc_samples(problem, arc_s))
        starts = max(1, round(settings.starts * n / points))
        say(f"screening {n} rates x {attitudes.shape[0]} attitudes on {part.samples} samples")
        entering.append(screen(part, rates=rates[mine], attitudes=attitudes, starts=starts))
        cohort_starts.append(entering[-1][0].shape[0])
    seconds["screening"], tick = time.perf_counter() - tick, time.perf_counter()
    anchors, x = problem.anchors.new_zeros(0, 4), problem.y.new_zeros(0, 7)
    cost, cohort = problem.y.new_zeros(0), torch.zeros(0, dtype=torch.long, device=x.device)
    for stage, arc_s in enumerate(settings.arcs_s):
        ties = 0
        if stage and x.shape[0]:
            keep = stage_keep[stage - 1]
            quotas = cohort_quotas(keep, cohort_starts[:stage])
            rows = prune_rows(group, anchors, x[:, 3:6], cost, keep=keep,
                              cohort=cohort if settings.cohort_quotas else None, quotas=quotas,
                              angle_deg=settings.cluster_angle_deg, rate_deg_s=settings.cluster_rate_deg_s,
                              tie_nats=settings.tie_nats, tie_cap=settings.tie_cap)
            ties = max(0, rows.numel() - (sum(quotas) if settings.cohort_quotas else keep))
            anchors, x, cohort = anchors[rows], x[rows], cohort[rows]
        if entering[stage] is not None:
            anchors, x = torch.cat([anchors, entering[stage][0]]), torch.cat([x, entering[stage][1]])
            cohort = torch.cat([cohort, cohort.new_full((entering[stage][0].shape[0],), stage)])
        if not x.shape[0]:
            continue
        part = problem.arc(_arc_samples(problem, arc_s))
        whole = part.samples == problem.samples
        say(f"stage {stage + 1}/{len(settings.arcs_s)}: {x.shape[0]} rows on {part.samples} samples"
            + (f" ({ties} beyond the quotas: the last arc cannot tell them from the best by {settings.tie_nats:g} "
               "nats)" if ties else ""))
        res = _stage(part.with_anchors(anchors), x, prior_sd=None if whole else settings.turn_rad / max(arc_s, 1e-9),
                     iterations=settings.final_iterations if whole else settings.iterations)
        anchors, x = _reanchor(part.with_anchors(anchors), res.x)
        cost = res.cost
        seconds[f"stage {stage + 1}"], tick = time.perf_counter() - tick, time.perf_counter()
    final = _stage(problem.with_anchors(anchors), x, prior_sd=None, iterations=0, covariance="solution")
    seconds["covariance"] = time.perf_counter() - tick
    return Inversion(q0=anchors, omega0=x[:, 3:6], log_rho=x[:, 6], cost=final.cost, covariance=final.covariance,
                     periodogram=pg, rate_grid=rates, seconds=seconds)


def polish(problem: TrajectoryProblem, q0: Tensor, x: Tensor, *, iterations: int = 12) -> Inversion:
    """Levenberg–Marquardt on the whole light curve from initial attitudes ``q0 (M, 4)`` and states ``x (M, 7)``
    (``θ`` about ``q0``; no prior), then the Laplace covariance about the solutions: the rows of an
    :class:`~.inversion.Inversion` (no periodogram, no rate grid); non-finite costs are ``inf``."""
    tolerance = torch.tensor([1e-7] * 3 + [1e-10] * 3 + [1e-6], dtype=x.dtype, device=x.device)
    options = LeastSquaresOptions(method="levenberg_marquardt", iterations=iterations, jacobian="provided",
                                  tolerance=tolerance, covariance="none")
    rows = torch.arange(x.shape[0], device=x.device)
    res = batch_least_squares(problem.with_anchors(q0), x, options=options)
    anchors = problem.with_anchors(q0).initial_attitudes(res.x, rows)
    x = torch.cat([torch.zeros_like(res.x[:, :3]), res.x[:, 3:]], -1)
    final = batch_least_squares(problem.with_anchors(anchors), x,
                                options=replace(options, iterations=0, covariance="solution"))
    cost = torch.where(torch.isfinite(final.cost), final.cost, torch.full_like(final.cost, math.inf))
    return Inversion(q0=anchors, omega0=x[:, 3:6], log_rho=x[:, 6], cost=cost, covariance=final.covariance,
                     periodogram=None, rate_grid=x.new_zeros(0, 3))
