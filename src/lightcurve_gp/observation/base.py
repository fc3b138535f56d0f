"""The one interface every observation model implements (paper Sec. 3.1, Eq. (49)).

An observation model maps an attitude ``q`` and the filter's running mean of past magnitudes ``m_past``
to a predictive distribution of the apparent magnitude: ``m_app ~ N(mean, variance)``.
The unscented filter only ever calls :meth:`ObservationModel.predict` (or the module's ``forward``), so
an exact GP, an inducing-point GP and the parametric renderer are interchangeable.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

__all__ = ["ObservationModel", "Prediction", "check_inputs"]

Prediction = tuple[Tensor, Tensor | None]
"""``(mean, variance)``; ``variance`` is ``None`` when the caller asked for the mean only."""


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
    if not math.isfinite(float(q.sum() + m_past.sum())):
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


class ObservationModel(nn.Module):
    """Base class: predictive mean and variance of ``m_app`` given ``(q, m_past)``.

    Subclasses implement :meth:`_predict` on already validated, broadcast inputs and keep every tensor
    they need as buffers, so ``model.to(device, dtype)`` moves them like any ``nn.Module``.
    """

    #: whether the prediction depends on ``m_past`` (the parametric renderer ignores it)
    uses_m_past: bool = True

    def forward(self, *, q: Tensor, m_past: Tensor, with_variance: bool = True) -> Prediction:
        """Predict the apparent magnitude.

        Args:
            q: quaternions ``(..., 4)``, scalar last.
            m_past: running mean of past magnitudes ``(...)`` in mag, broadcast against ``q[..., 0]``.
            with_variance: also return the predictive variance (of the latent function, mag²).

        Returns:
            ``mean (...)`` in mag and ``variance (...)`` in mag² (``None`` when ``with_variance`` is false).
        """
        q, m_past = check_inputs(q, m_past)
        return self._predict(q, m_past, with_variance)

    def predict(self, q: Tensor, m_past: Tensor, *, with_variance: bool = True) -> Prediction:
        """Positional-argument alias of :meth:`forward` for library users."""
        return self(q=q, m_past=m_past, with_variance=with_variance)

    def _predict(self, q: Tensor, m_past: Tensor, with_variance: bool) -> Prediction:
        raise NotImplementedError
