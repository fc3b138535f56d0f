"""The one interface every observation model implements (paper Sec. 3.1, Eq. (49)).

An observation model maps an attitude ``q`` and the filter's running mean of past magnitudes ``m_past`` to a
predictive distribution of the apparent magnitude: ``m_app ~ N(mean, variance)``. The unscented filter only ever
calls it as ``model(q=..., m_past=..., variance=...)`` (:class:`ObservationModel`), so an exact GP, an
inducing-point GP and the parametric renderer are interchangeable.

The variance choice is passed with every call, never stored in the model:

* ``"none"``: the mean only; the variance is returned as ``None``;
* ``"fast"``: the cheapest variance the model offers that is never below the exact one — for the exact GP its
  local (nearest-neighbour) variance, for the other models their exact variance;
* ``"exact"``: the exact predictive variance of the latent function.

Batched inputs ``(..., S, 4)`` are sigma-point sets: the points along the last batch dimension may be treated as
one set (the exact GP's fast variance conditions a tight set on one shared neighbour set), so a point's fast
variance can depend on which points share its set. Means, exact variances and 1-D batches ``(P, 4)`` (sets of one
point) do not depend on the batch layout.
"""

from __future__ import annotations

import math
from typing import Literal, Protocol, runtime_checkable

import torch
from torch import Tensor, nn

__all__ = [
    "VARIANCES",
    "ObservationModel",
    "ObservationModule",
    "Prediction",
    "Variance",
    "check_inputs",
    "check_variance",
]

Prediction = tuple[Tensor, Tensor | None]
"""``(mean, variance)``; ``variance`` is ``None`` when the caller asked for ``variance="none"``."""

Variance = Literal["none", "fast", "exact"]
VARIANCES: tuple[str, ...] = ("none", "fast", "exact")


@runtime_checkable
class ObservationModel(Protocol):
    """What the filters need of an observation model (see the module docstring for the variance and set rules)."""

    #: whether the prediction depends on ``m_past`` (the parametric renderer ignores it)
    uses_m_past: bool

    def __call__(self, *, q: Tensor, m_past: Tensor, variance: Variance = "fast") -> Prediction:
        """``q (..., 4)`` scalar last, ``m_past (...)`` in mag → ``mean (...)`` in mag, ``variance (...)`` in mag²."""
        ...


def check_variance(variance: str) -> str:
    """Return ``variance`` when it is one of :data:`VARIANCES`; raise :class:`ValueError` otherwise."""
    if variance not in VARIANCES:
        raise ValueError(f"variance must be one of {', '.join(VARIANCES)}, got {variance!r}")
    return variance


def check_inputs(q: Tensor, m_past: Tensor) -> tuple[Tensor, Tensor]:
    """Validate and broadcast observation-model inputs.

    Args:
        q: quaternions ``(..., 4)``, scalar last (need not be normalised; sign matters to GP models).
        m_past: running mean of past magnitudes ``(...)`` (mag), broadcastable against ``q[..., 0]``.

    Returns:
        ``(q, m_past)`` broadcast to a common batch shape ``(...)``.

    Raises:
        ValueError: wrong last dimension, non-finite values or shapes that do not broadcast.
    """
    if not isinstance(q, Tensor) or not isinstance(m_past, Tensor):
        raise TypeError("q and m_past must be torch tensors")
    if q.ndim == 0 or q.shape[-1] != 4:
        raise ValueError(f"q must have shape (..., 4), got {tuple(q.shape)}")
    # hot path: one reduction and one device sync; a non-finite value makes the sum non-finite (a sum of finite
    # values can overflow too, which the exact check below then clears)
    # (left out inside a compiled step, which checks its posterior instead: lightcurve_gp.filters.compiled)
    if not torch.compiler.is_compiling() and not math.isfinite(float(q.sum() + m_past.sum())):
        for name, t in (("q", q), ("m_past", m_past)):
            if not bool(torch.isfinite(t).all()):
                raise ValueError(f"{name} contains non-finite values")
    batch = q.shape[:-1]
    if m_past.shape == batch:
        return q, m_past
    try:
        batch = torch.broadcast_shapes(batch, m_past.shape)
    except RuntimeError:
        raise ValueError(
            f"m_past of shape {tuple(m_past.shape)} does not broadcast against q of shape {tuple(q.shape)}"
        ) from None
    return q.expand(*batch, 4), m_past.expand(batch)


class ObservationModule(nn.Module):
    """Base class of the library's models: validates inputs and the variance choice, then calls :meth:`_predict`.

    Subclasses implement :meth:`_predict` on already validated, broadcast inputs and keep every tensor they need as
    buffers, so ``model.to(device, dtype)`` moves them like any ``nn.Module``.
    """

    uses_m_past: bool = True

    def forward(self, *, q: Tensor, m_past: Tensor, variance: Variance = "fast") -> Prediction:
        """Predict the apparent magnitude.

        Args:
            q: quaternions ``(..., 4)``, scalar last; the last batch dimension is a sigma-point set (module doc).
            m_past: running mean of past magnitudes ``(...)`` in mag, broadcast against ``q[..., 0]``.
            variance: ``"none"``, ``"fast"`` or ``"exact"`` (module docstring).

        Returns:
            ``mean (...)`` in mag and the latent ``variance (...)`` in mag² (``None`` for ``variance="none"``).
        """
        check_variance(variance)
        q, m_past = check_inputs(q, m_past)
        return self._predict(q, m_past, variance)

    def predict(self, q: Tensor, m_past: Tensor, *, variance: Variance = "fast") -> Prediction:
        """Positional-argument alias of :meth:`forward` for library users."""
        return self(q=q, m_past=m_past, variance=variance)

    def _predict(self, q: Tensor, m_past: Tensor, variance: Variance) -> Prediction:
        raise NotImplementedError
