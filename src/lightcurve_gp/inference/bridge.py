"""Carry the inversions of single passes across the long gaps between them to every light curve of the object.

An inversion grows its arcs from the first sample (:mod:`.inversion`), so the passes after a gap of an hour or a day
enter only its last stage, where the rate must already be right to a fraction of a turn over the gap: a rate known to
``σ_ω`` from one pass leaves ``σ_ω T`` radians of phase at a time ``T`` away, and the last stage's local search cannot
cross the wrong turns. :func:`bridge` searches that rate explicitly: around each of a pass's best solutions it screens
a grid of rates within ``±span`` standard deviations per axis, spaced so that no two neighbours differ by more than
``phase_rad`` of turn at the sample farthest from the pass (:func:`rate_offsets`), on every sample (the attitude at
the pass's first sample held, ρ profiled), and polishes the best few by Levenberg–Marquardt on every sample.

:func:`carry_across_gaps` does this from each of the (up to :data:`CARRIED_PASSES` longest) passes alone, not only
the first: a pass whose own search misses the truth's family leaves it to another pass that finds it, forwards or
backwards in time (the closed-form propagation runs both ways). Solutions found from a later pass are moved to the
first sample's epoch by the torque-free motion and polished there. All of them join the direct inversion's before
the families are formed.

Tensors: states ``x = [θ, ω_0, ln ρ]`` ``(M, 7)`` as in :mod:`.trajectory`; rates rad/s; times s.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Callable

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import quat_mul
from lightcurve_gp.attitude.torque_free import torque_free_motion
from lightcurve_gp.inference.families import cluster
from lightcurve_gp.inference.inversion import Inversion, InversionSettings, invert, polish
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup

__all__ = ["BRIDGED", "CARRIED_PASSES", "GAP_S", "first_pass_samples", "pass_bounds", "rate_offsets", "bridge",
           "carry_across_gaps"]

#: each pass's distinct solutions carried across a long gap (a single pass often fits a wrong family as well as the
#: truth's)
BRIDGED = 8
#: the passes searched alone and carried (the longest ones): each costs a search of its own samples
CARRIED_PASSES = 3
#: a gap longer than this (s) separates two passes
GAP_S = 600.0


def first_pass_samples(times: Tensor, *, gap_s: float = GAP_S) -> int:
    """The samples before the first gap longer than ``gap_s`` (all of them when there is none)."""
    return pass_bounds(times, gap_s=gap_s)[0][1]


def pass_bounds(times: Tensor, *, gap_s: float = GAP_S) -> list[tuple[int, int]]:
    """``[(start, stop), …]``: the sample ranges of the passes of ``times (K,)`` (increasing, s), split at every gap
    longer than ``gap_s``."""
    cuts = (torch.nonzero(torch.diff(times) > gap_s).flatten() + 1).tolist()
    edges = [0, *cuts, int(times.shape[0])]
    return list(zip(edges[:-1], edges[1:]))


def rate_offsets(sigma: Tensor, *, span_s: float, span: float = 3.0, phase_rad: float = 0.5,
                 max_points: int = 4096) -> Tensor:
    """Rate offsets ``(R, 3)`` (rad/s): a grid over ``±span σ_i`` per axis (``sigma (3,)``, rad/s) with steps of
    ``phase_rad / span_s`` (coarsened evenly until at most ``max_points``), the zero offset included."""
    step = phase_rad / max(span_s, 1e-9)
    counts = torch.ceil(span * sigma.clamp_min(0) / step).long()
    while int(torch.prod(2 * counts + 1)) > max_points:
        step *= 1.25
        counts = torch.ceil(span * sigma.clamp_min(0) / step).long()
    axes = [torch.arange(-int(n), int(n) + 1, dtype=sigma.dtype, device=sigma.device) * step for n in counts]
    return torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def bridge(problem: TrajectoryProblem, *, anchors: Tensor, x: Tensor, covariance: Tensor, keep: int = 4,
           iterations: int = 15) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The first pass's solutions (``anchors (M, 4)``, states ``x (M, 7)`` with ``θ = 0``, their Laplace covariances
    ``(M, 7, 7)`` on the first pass) carried to every sample of ``problem`` (module docstring): ``(anchors, x, cost,
    covariance)`` of the ``M·keep`` polished solutions, each re-anchored (``θ = 0``), with their Laplace
    covariances on every sample."""
    span_s = float(problem.times.abs().max())  # from the epoch (the anchors' time) to the farthest sample
    starts, rows = [], []
    for m in range(x.shape[0]):
        sigma = torch.diagonal(covariance[m, 3:6, 3:6]).clamp_min(0).sqrt()
        sigma = torch.where(torch.isfinite(sigma), sigma, torch.zeros_like(sigma))
        rates = x[m, 3:6] + rate_offsets(sigma, span_s=span_s)
        cost, beta = problem.grid_cost(rates, anchors[m:m + 1])  # (R, 1)
        best = torch.topk(cost[:, 0], min(keep, cost.shape[0]), largest=False).indices
        starts.append(torch.cat([torch.zeros(best.numel(), 3, dtype=x.dtype, device=x.device), rates[best],
                                 beta[best, 0].unsqueeze(-1)], -1))
        rows.append(torch.full((best.numel(),), m, dtype=torch.long, device=x.device))
    x0, row = torch.cat(starts), torch.cat(rows)
    solved = polish(problem, anchors[row], x0, iterations=iterations)
    return solved.q0, torch.cat([torch.zeros_like(solved.omega0), solved.omega0, solved.log_rho[:, None]], -1), \
        solved.cost, solved.covariance


def carry_across_gaps(problem: TrajectoryProblem, group: AmbiguityGroup, inv: Inversion, *,
                      settings: InversionSettings, search: Callable[[TrajectoryProblem], Inversion] | None = None,
                      progress: Callable[[str], None] | None = None) -> Inversion:
    """``inv`` (the direct inversion of ``problem``) joined by each long pass's best distinct solutions carried across
    the gaps (module docstring); ``inv`` itself when the samples have no gap longer than :data:`GAP_S`. ``search``
    inverts one pass alone (default :func:`~.inversion.invert` with ``settings``; the answer's search widens a pass
    whose best fit fails its test)."""
    passes = pass_bounds(problem.times)
    if len(passes) == 1:
        return inv
    say = progress or (lambda message: None)
    longest = sorted(sorted(range(len(passes)), key=lambda p: passes[p][1] - passes[p][0], reverse=True)
                     [:CARRIED_PASSES])
    seconds, joined = dict(inv.seconds), [inv]
    for p in longest:
        start, stop = passes[p]
        say(f"pass {p + 1} of {len(passes)} alone (samples {start + 1}-{stop} of {problem.samples}), then carried "
            f"across the gaps")
        part = problem.window(start, stop)
        alone = search(part) if search is not None else invert(part, group, settings=settings, progress=progress)
        _, heads = cluster(group, alone.q0, alone.omega0, alone.cost, angle_deg=settings.cluster_angle_deg,
                           rate_deg_s=settings.cluster_rate_deg_s)
        heads = heads[:BRIDGED]
        x = torch.cat([torch.zeros(heads.numel(), 3, dtype=alone.q0.dtype, device=alone.q0.device),
                       alone.omega0[heads], alone.log_rho[heads, None]], -1)
        tick = time.perf_counter()
        q0, x, cost, covariance = bridge(problem.with_epoch(start), anchors=alone.q0[heads], x=x,
                                         covariance=alone.covariance[heads])
        if start > 0:  # to the first sample's epoch, polished there (costs and covariances of that epoch)
            back = problem.times[:1] - problem.times[start]
            delta, omega = torque_free_motion(x[:, 3:6], inertia=problem.inertia, times=back)
            moved = torch.cat([torch.zeros_like(x[:, :3]), omega[:, 0], x[:, 6:]], -1)
            solved = polish(problem, quat_mul(delta[:, 0], q0), moved, iterations=5)
            q0, x = solved.q0, torch.cat([torch.zeros_like(solved.omega0), solved.omega0, solved.log_rho[:, None]], -1)
            cost, covariance = solved.cost, solved.covariance
        seconds.update({f"pass {p + 1} {k}": v for k, v in alone.seconds.items()})
        seconds[f"pass {p + 1} bridge"] = time.perf_counter() - tick
        joined.append(replace(inv, q0=q0, omega0=x[:, 3:6], log_rho=x[:, 6], cost=cost, covariance=covariance))
    return replace(inv, q0=torch.cat([j.q0 for j in joined]), omega0=torch.cat([j.omega0 for j in joined]),
                   log_rho=torch.cat([j.log_rho for j in joined]), cost=torch.cat([j.cost for j in joined]),
                   covariance=torch.cat([j.covariance for j in joined]), seconds=seconds)
