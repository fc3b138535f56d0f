"""Global start: a bank of filters from a grid over SO(3), ranked by their innovation likelihood (MMAE).

No initial guess is needed: ``N`` filters (:func:`bank_attitudes`: a scrambled Sobol' set, uniform on SO(3), with
``N = 1024`` the nearest member of 20 000 random attitudes was 12.5° away in the median, 19.2° at the 95th
percentile and 25.9° at most) start from the grid with the config's ``P0`` and run together in one batch
(:func:`lightcurve_gp.filters.setup.run_filter`) over the whole light curve. Each filter accumulates the Gaussian
log-likelihood ``ℓ_i`` of its innovations (:func:`lightcurve_gp.filters.selection.innovation_log_likelihood`), and
the bank's posterior weights under a uniform prior are ``w_i = exp(ℓ_i) / Σ_j exp(ℓ_j)`` — multiple-model
adaptive estimation (Magill 1965; for light curves, Linares et al. 2014). The bank is ranked by ``ℓ``; the best
``keep`` filters are run again alone with the config's own settings (the bank may leave out the GP's predictive
variance, ``bank_variance``: an ``M × M`` quadratic form per sigma point, about ``M/d`` times the arithmetic of the
mean) and returned.

With the offset state (``filter.estimate_offset``) each member starts from its own ``b0 = ỹ_0 − h(q_i)``.

Along a pass (``geometry``, a :class:`~lightcurve_gp.passes.geometry.PassGeometry` of the light curve's samples) every
filter predicts sample ``k`` with that sample's geometry (:class:`~lightcurve_gp.observation.along_pass.AlongPass`;
``b0`` with sample 0's).

Pruning (``prune_after``, ``prune_keep``): all ``N`` members run the first ``prune_after`` steps, the best
``prune_keep`` by ``ℓ`` so far continue from their posterior at that step (:func:`continue_filters`, the same filter
as an uninterrupted run) and the rest stop. The ranking is then the survivors by their ``ℓ`` over the whole light
curve, followed by the pruned members by their ``ℓ`` over the first steps; the weights are over the survivors (zero
for the pruned). Without pruning (``prune_after=None``) the run is the unpruned bank, unchanged.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.attitude.sampling import sobol_attitudes
from lightcurve_gp.filters.selection import innovation_log_likelihood
from lightcurve_gp.filters.setup import filter_params, run_filter, step_models
from lightcurve_gp.filters.state import FilterHistory
from lightcurve_gp.filters.usque import run_usque
from lightcurve_gp.observation.base import ObservationModel, Variance

__all__ = ["BankResult", "bank_attitudes", "continue_filters", "run_bank"]


@dataclass
class BankResult:
    """A bank run, ranked.

    Attributes:
        q0: the members' initial attitudes ``(N, 4)``.
        log_likelihood: accumulated innovation log-likelihood ``ℓ (N,)`` (nats); with pruning, a pruned member's
            over the first ``prune_after`` steps only.
        weights: posterior weights ``(N,)`` (sum 1; zero for pruned members).
        order: member indices best first ``(N,)`` (with pruning: the survivors first, module docstring).
        kept: histories of the best ``keep`` members rerun with the config's settings, best first (batch ``keep``).
        bank_history: the bank's own run (batch ``N``); with pruning its first ``prune_after`` steps only.
        seconds: wall time of the bank run (s); kept_seconds: of the rerun of the kept members (s).
        survivors: with pruning, the indices of the members that ran the whole light curve ``(prune_keep,)``, else
            ``None``.
    """

    q0: Tensor
    log_likelihood: Tensor
    weights: Tensor
    order: Tensor
    kept: FilterHistory
    bank_history: FilterHistory
    seconds: float
    kept_seconds: float
    survivors: Tensor | None = None


def bank_attitudes(n: int, *, seed: int = 0, dtype: torch.dtype = torch.float64, device=None) -> Tensor:
    """``n`` initial attitudes ``(n, 4)`` spread uniformly over SO(3): scrambled Sobol' points through Shoemake's
    map (:func:`lightcurve_gp.attitude.sampling.sobol_attitudes`); a power of two balances them best."""
    return sobol_attitudes(n, seed, dtype=dtype, device=device)


def continue_filters(cfg, model: ObservationModel, history: FilterHistory, members: Tensor, *,
                     observations: Tensor, increments: Tensor, R: Tensor | float | None = None,
                     variance: Variance | None = None, geometry=None) -> FilterHistory:
    """Continue the filters ``members (K,)`` of ``history`` from their last posterior (attitude, covariance, offset,
    running mean) on the next ``observations (K, T'+1)`` (column 0: the last sample ``history`` used, not used
    again), increments ``(T', 4)`` and ``R`` (as :func:`~lightcurve_gp.filters.setup.run_filter`; per-sample
    ``(K, T'+1)`` aligned with ``observations``; ``geometry``: of these ``T'+1`` samples, along a pass): the same
    filter as one uninterrupted run, to rounding. Adaptive measurement noise carries a running state of its own and
    is refused."""
    params = filter_params(cfg, model, R=R, variance=variance)
    if params.adaptive_noise != "none":
        raise ValueError("continue_filters: adaptive measurement noise (filter.adaptive_noise) is not carried over")
    pick = lambda t: None if t is None else t[members, -1]  # noqa: E731
    return run_usque(model=step_models(model, geometry=geometry)[1], q_est0=history.q_est[members, -1],
                     P0=history.P_full[members, -1], observations=observations,
                     m_past0=history.m_past_final[members], increments=increments,
                     params=params, offset0=pick(history.offset), theta0=pick(history.theta),
                     omega0=pick(history.omega))


def _rows(value: Tensor | float | None, n: int) -> Tensor | float | None:
    """A per-sample noise ``(T+1,)`` of one light curve repeated for ``n`` filters."""
    return value.expand(n, -1) if isinstance(value, Tensor) and value.ndim == 1 else value


def run_bank(cfg, model: ObservationModel, *, observations: Tensor, increments: Tensor, q0: Tensor,
             R: Tensor | float | None = None, keep: int = 5, bank_variance: Variance = "none",
             prune_after: int | None = None, prune_keep: int = 64, geometry=None) -> BankResult:
    """Run the bank ``q0 (N, 4)`` on one light curve ``observations (T+1,)`` (mag; ``R``: scalar or ``(T+1,)``
    mag², default ``filter.measurement_noise``) with increments ``(T, 4)``; rank it and rerun the best ``keep``
    members with the config's settings. With ``prune_after`` (steps, ``1 ≤ prune_after < T``) only the best
    ``prune_keep`` members run past that step; ``geometry`` (``T+1`` samples) runs them along the pass (module
    docstring)."""
    n, T = q0.shape[0], increments.shape[0]
    if observations.ndim != 1:
        raise ValueError(f"observations must be one light curve (T+1,), got {tuple(observations.shape)}")
    if not 1 <= keep <= n:
        raise ValueError(f"keep must be in [1, {n}], got {keep}")
    pruned = prune_after is not None and prune_after < T
    if pruned and (prune_after < 1 or not keep <= prune_keep <= n):
        raise ValueError(f"pruning needs prune_after >= 1 and keep <= prune_keep <= {n}, got prune_after "
                         f"{prune_after} and prune_keep {prune_keep} (keep {keep})")
    if pruned and cfg.filter.adaptive_noise != "none":
        raise ValueError("pruning: adaptive measurement noise (filter.adaptive_noise) is not carried over; run the "
                         "bank unpruned")
    start = time.perf_counter()
    if pruned:
        bank, ll, order, weights, survivors = _pruned_bank(cfg, model, observations, increments, q0, R, bank_variance,
                                                           prune_after, prune_keep, geometry)
    else:
        bank = run_filter(cfg, model, q_est0=q0, observations=observations.expand(n, -1), increments=increments,
                          R=_rows(R, n), variance=bank_variance, geometry=geometry)
        ll = innovation_log_likelihood(bank)
        order, weights, survivors = torch.argsort(ll, descending=True), torch.softmax(ll, 0), None
    seconds = time.perf_counter() - start
    best = order[:keep]
    start = time.perf_counter()
    kept = run_filter(cfg, model, q_est0=q0[best], observations=observations.expand(keep, -1),
                      increments=increments, R=_rows(R, keep), geometry=geometry)
    return BankResult(q0=q0, log_likelihood=ll, weights=weights, order=order, kept=kept, bank_history=bank,
                      seconds=seconds, kept_seconds=time.perf_counter() - start, survivors=survivors)


def _pruned_bank(cfg, model, observations, increments, q0, R, variance, prune_after: int, prune_keep: int,
                 geometry):
    """The pruned bank (module docstring): ``(first-phase history, ℓ (N,), order (N,), weights (N,), survivors)``."""
    n, s = q0.shape[0], prune_after
    part = lambda value, cols: value[cols] if isinstance(value, Tensor) and value.ndim == 1 else value  # noqa: E731
    first = run_filter(cfg, model, q_est0=q0, observations=observations[:s + 1].expand(n, -1),
                       increments=increments[:s], R=_rows(part(R, slice(None, s + 1)), n), variance=variance,
                       geometry=geometry)
    ll = innovation_log_likelihood(first)
    survivors = torch.argsort(ll, descending=True)[:prune_keep]
    rest = continue_filters(cfg, model, first, survivors, observations=observations[s:].expand(prune_keep, -1),
                            increments=increments[s:], R=_rows(part(R, slice(s, None)), prune_keep),
                            variance=variance, geometry=None if geometry is None else geometry.subset(slice(s, None)))
    ll = ll.index_add(0, survivors, innovation_log_likelihood(rest))
    alive = torch.zeros(n, dtype=torch.bool, device=ll.device)
    alive[survivors] = True
    ranked_alive = survivors[torch.argsort(ll[survivors], descending=True)]
    dropped = (~alive).nonzero().squeeze(-1)
    order = torch.cat([ranked_alive, dropped[torch.argsort(ll[dropped], descending=True)]])
    weights = torch.zeros_like(ll).index_put((survivors,), torch.softmax(ll[survivors], 0))
    return first, ll, order, weights, survivors
