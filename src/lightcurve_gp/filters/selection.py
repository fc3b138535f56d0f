"""The same light curves filtered under several settings, the run of highest innovation likelihood kept per seed.

A filter's innovations ``ν_k`` with their predicted variances ``P_yy,k`` give the log-likelihood of the light curve
under that filter, ``ℓ = Σ_k log N(ν_k; 0, P_yy,k)`` (:func:`lightcurve_gp.filters.bank.innovation_log_likelihood`,
the bank's ranking): a filter whose sigma points describe the light curve's nonlinearity badly predicts it badly.
Among ``K`` runs on the same observations, keeping each seed's run of highest ``ℓ`` is multiple-model selection
with equal prior weights; it needs no truth, so it is what a user can do on their own light curve.

Used for the unscented λ of the surface-state filter
(:func:`lightcurve_gp.evaluation.estimators.run_surface_filter_selected`): neither the paper's ``λ = 0`` nor Julier's
``λ = 3 − n`` is better on every trajectory (experiments/README.md).
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import torch
from torch import Tensor

from lightcurve_gp.filters.bank import innovation_log_likelihood
from lightcurve_gp.filters.state import FilterHistory

__all__ = ["select_rows", "select_by_likelihood"]


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
