"""Global start: a bank of filters from a grid over SO(3), ranked by their innovation likelihood (MMAE).

No initial guess is needed: ``N`` filters (:func:`bank_attitudes`: a scrambled Sobol' set, uniform on SO(3), with
``N = 1024`` the nearest member of 20 000 random attitudes was 12.5° away in the median, 19.2° at the 95th
percentile and 25.9° at most) start from the grid with the config's ``P0`` and run
together in one batch of :func:`lightcurve_gp.ukf.run_usque` over the whole light curve. Each filter accumulates
the Gaussian log-likelihood of its innovations,

    ℓ_i = Σ_k −½ (ν_ik² / Pyy_ik + ln(2π Pyy_ik))     (over the steps it updated),

and the bank's posterior weights under a uniform prior are ``w_i = exp(ℓ_i) / Σ_j exp(ℓ_j)`` — multiple-model
adaptive estimation (Magill 1965; for light curves, Linares et al. 2014). The bank is ranked by ``ℓ``; the best
``keep`` filters are run again alone with the config's own settings (the bank may leave out the GP's predictive
variance, ``bank_variance``: an ``M × M`` quadratic form per sigma point, about ``M/d`` times the arithmetic of the
mean) and returned.

With the offset state (``filter.estimate_offset``) each member starts from its own ``b0 = ỹ_0 − h(q_i)``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import torch
from torch import Tensor

from .attitudes import sobol_attitudes
from .observation.base import ObservationModel, Variance
from .ukf import FilterHistory, UsqueParams, initial_covariance, run_usque
from .ukf_offset import initial_offset, offset_covariance

__all__ = ["BankResult", "bank_attitudes", "innovation_log_likelihood", "run_filter", "run_bank"]


@dataclass
class BankResult:
    """A bank run, ranked.

    Attributes:
        q0: the members' initial attitudes ``(N, 4)``.
        log_likelihood: accumulated innovation log-likelihood ``ℓ (N,)`` (nats).
        weights: posterior weights ``(N,)`` (sum 1).
        order: member indices best first ``(N,)``.
        kept: histories of the best ``keep`` members rerun with the config's settings, best first (batch ``keep``).
        bank_history: the bank's own run (batch ``N``).
        seconds: wall time of the bank run (s); kept_seconds: of the rerun of the kept members (s).
    """

    q0: Tensor
    log_likelihood: Tensor
    weights: Tensor
    order: Tensor
    kept: FilterHistory
    bank_history: FilterHistory
    seconds: float
    kept_seconds: float


def bank_attitudes(n: int, *, seed: int = 0, dtype: torch.dtype = torch.float64, device=None) -> Tensor:
    """``n`` initial attitudes ``(n, 4)`` spread uniformly over SO(3): scrambled Sobol' points through Shoemake's
    map (:func:`lightcurve_gp.attitudes.sobol_attitudes`); a power of two balances them best."""
    return sobol_attitudes(n, seed, dtype=dtype, device=device)


def innovation_log_likelihood(history: FilterHistory) -> Tensor:
    """``ℓ (B,)``: the summed Gaussian log-density of each filter's innovations over the steps it updated (nats)."""
    nu, pyy = history.innovation, history.y_var
    terms = -0.5 * (nu * nu / pyy + torch.log(2.0 * math.pi * pyy))
    return torch.where(history.updated, terms, torch.zeros((), dtype=terms.dtype)).sum(-1)


def run_filter(cfg, model: ObservationModel, *, q_est0: Tensor, observations: Tensor, increments: Tensor,
               R: Tensor | float | None = None, variance: Variance | None = None) -> FilterHistory:
    """The GPUKF of ``cfg`` from ``q_est0 (B, 4)`` on ``observations (B, T+1)`` (mag) with increments ``(T, 4)``:
    ``P0`` from ``filter.p0_deg`` (and ``filter.offset_prior_std`` with the offset state, ``b0 = ỹ_0 − h(q̂_0)``),
    ``m_past0 = ỹ_0``; ``R`` (scalar, ``(B,)`` or ``(B, T+1)``, mag²) replaces ``filter.measurement_noise`` and
    ``variance`` the model variance the filter asks for, when given. The same run as
    :func:`lightcurve_gp.estimation.run_estimators`'s ``gpukf`` for the same inputs."""
    params = UsqueParams.from_config(cfg)
    if R is not None:
        params = dataclasses.replace(params, R=R)
    if variance is not None:
        params = dataclasses.replace(params, variance=variance)
    m_past0 = observations[:, 0]
    dtype, device = q_est0.dtype, q_est0.device
    if not cfg.filter.estimate_offset:
        return run_usque(model=model, q_est0=q_est0, P0=initial_covariance(cfg.filter.p0_deg, dtype=dtype,
                                                                           device=device),
                         observations=observations, m_past0=m_past0, increments=increments, params=params)
    b0 = initial_offset(model, q_est0, observations[:, 0], m_past0)
    P0 = offset_covariance(cfg.filter.p0_deg, cfg.filter.offset_prior_std, dtype=dtype, device=device)
    return run_usque(model=model, q_est0=q_est0, P0=P0, observations=observations, m_past0=m_past0,
                     increments=increments, params=params, offset0=b0)


def _rows(value: Tensor | float | None, n: int) -> Tensor | float | None:
    """A per-sample noise ``(T+1,)`` of one light curve repeated for ``n`` filters."""
    return value.expand(n, -1) if isinstance(value, Tensor) and value.ndim == 1 else value


def run_bank(cfg, model: ObservationModel, *, observations: Tensor, increments: Tensor, q0: Tensor,
             R: Tensor | float | None = None, keep: int = 5, bank_variance: Variance = "none") -> BankResult:
    """Run the bank ``q0 (N, 4)`` on one light curve ``observations (T+1,)`` (mag; ``R``: scalar or ``(T+1,)``
    mag², default ``filter.measurement_noise``) with increments ``(T, 4)``; rank it and rerun the best ``keep``
    members with the config's settings (module docstring)."""
    n = q0.shape[0]
    if observations.ndim != 1:
        raise ValueError(f"observations must be one light curve (T+1,), got {tuple(observations.shape)}")
    if not 1 <= keep <= n:
        raise ValueError(f"keep must be in [1, {n}], got {keep}")
    start = time.perf_counter()
    bank = run_filter(cfg, model, q_est0=q0, observations=observations.expand(n, -1), increments=increments,
                      R=_rows(R, n), variance=bank_variance)
    seconds = time.perf_counter() - start
    ll = innovation_log_likelihood(bank)
    order = torch.argsort(ll, descending=True)
    best = order[:keep]
    start = time.perf_counter()
    kept = run_filter(cfg, model, q_est0=q0[best], observations=observations.expand(keep, -1),
                      increments=increments, R=_rows(R, keep))
    return BankResult(q0=q0, log_likelihood=ll, weights=torch.softmax(ll, 0), order=order, kept=kept,
                      bank_history=bank, seconds=seconds, kept_seconds=time.perf_counter() - start)
