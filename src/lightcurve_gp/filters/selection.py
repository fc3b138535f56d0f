"""The innovation log-likelihood of a filter run, and the run of highest likelihood kept per light curve.

A filter's innovations ``ν_k`` with their predicted variances ``P_yy,k`` give the log-likelihood of the light curve
under that filter,

    ℓ = Σ_k log N(ν_k; 0, P_yy,k) = Σ_k −½ (ν_k² / P_yy,k + ln(2π P_yy,k))     (over the steps it updated):

a filter whose sigma points describe the light curve's nonlinearity badly predicts it badly. The global-start bank
ranks its members by ``ℓ`` (:mod:`lightcurve_gp.filters.bank`). Among ``K`` runs on the same observations, keeping
each seed's run of highest ``ℓ`` is multiple-model selection with equal prior weights; it needs no truth, so it is
what a user can do on their own light curve. Used for the unscented λ of the surface-state filter
(``surface_ukf_select`` in :mod:`lightcurve_gp.evaluation.registry`): neither the paper's ``λ = 0`` nor Julier's
``λ = 3 − n`` is better on every trajectory (experiments/README.md).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import torch
from torch import Tensor

from lightcurve_gp.filters.state import FilterHistory

__all__ = ["innovation_log_terms", "innovation_log_likelihood", "select_rows", "select_by_likelihood"]


def innovation_log_terms(history: FilterHistory) -> Tensor:
    """The log-density of each step's innovation ``(B, T+1)`` (nats): ``−½ (ν² / Pyy + ln(2π Pyy))`` where the
    filter updated, 0 elsewhere (step 0, missing or refused observations). ``cumsum(-1)`` gives ``ℓ`` so far."""
    nu, pyy = history.innovation, history.y_var
    terms = -0.5 * (nu * nu / pyy + torch.log(2.0 * math.pi * pyy))
    return torch.where(history.updated, terms, torch.zeros((), dtype=terms.dtype))


def innovation_log_likelihood(history: FilterHistory) -> Tensor:
    """``ℓ (B,)``: the summed Gaussian log-density of each filter's innovations over the steps it updated (nats)."""
    return innovation_log_terms(history).sum(-1)


def select_rows(histories: Sequence[FilterHistory], index: Tensor) -> FilterHistory:
    """The history whose row ``b`` is ``histories[index[b]]``'s row ``b`` (``index (B,)``, integers in
    ``[0, K)``); a field that is ``None`` in the first history is ``None`` in the result."""
    picked = {}
    for f in dataclasses.fields(FilterHistory):
        values = [getattr(h, f.name) for h in histories]
        if values[0] is None:
            picked[f.name] = None
            continue
        stacked = torch.stack(values)  # (K, B, ...)
        where = index.view(1, -1, *([1] * (stacked.ndim - 2))).expand(1, *stacked.shape[1:])
        picked[f.name] = torch.gather(stacked, 0, where)[0]
    return FilterHistory(**picked)


def select_by_likelihood(histories: Sequence[FilterHistory]) -> tuple[FilterHistory, Tensor]:
    """Each seed's run of highest innovation log-likelihood, and which run that was ``(B,)``."""
    ll = torch.stack([innovation_log_likelihood(h) for h in histories])  # (K, B)
    index = ll.argmax(0)
    return select_rows(histories, index), index
