"""USQUE with a magnitude offset in the state: joint attitude and reflectance estimation.

The light curve of the paper's object is diffuse-dominated, so its magnitude at reflectance ρ is the magnitude at a
reference ``ρ0`` shifted by a constant (paper Eq. (8) with ``c_d ∝ ρ``, Eq. (4))::

    m(q; ρ) = m(q; ρ0) − 2.5 log10(ρ / ρ0)

An unknown ρ is therefore an unknown offset ``b`` on a reference light curve. This filter augments USQUE's GRP
attitude error ``δp`` (3) with ``b`` (1, mag, a random walk) and predicts

    y = h(q, m_past) + b

with any :class:`~lightcurve_gp.observation.base.ObservationModel` ``h`` of the reference curve: the renderer with
``ρ0`` (a conventional UKF that estimates ρ) or a GP trained on ρ-normalised magnitudes (the GPUKF with an offset).
:func:`lightcurve_gp.filters.usque.run_usque` given ``offset0`` runs on the 4-dimensional state ``x = [δp, b]``; the
attitude part is reset to zero after every update while ``b`` carries its estimate (Crassidis & Markley 2003, with the
bias-state pattern of their gyro-bias filter, here a measurement bias). This module holds the offset's prior and
its map to a reflectance (:func:`offset_to_rho`).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from lightcurve_gp.filters.usque import initial_covariance
from lightcurve_gp.observation.base import ObservationModel

__all__ = ["initial_offset", "offset_covariance", "offset_to_rho", "rho_to_offset"]


def rho_to_offset(rho: float | Tensor, rho_reference: float) -> float | Tensor:
    """Magnitude offset ``b = −2.5 log10(ρ / ρ0)`` of a diffuse-dominated light curve (mag)."""
    if isinstance(rho, Tensor):
        return -2.5 * torch.log10(rho / rho_reference)
    if not rho > 0 or not rho_reference > 0:
        raise ValueError(f"rho and rho_reference must be positive, got {rho!r} and {rho_reference!r}")
    return -2.5 * math.log10(rho / rho_reference)


def offset_to_rho(offset: Tensor, rho_reference: float) -> Tensor:
    """Inverse of :func:`rho_to_offset`: ``ρ = ρ0 · 10^(−b / 2.5)`` for offsets ``(...)`` in mag."""
    return rho_reference * torch.pow(10.0, -offset / 2.5)


def initial_offset(model: ObservationModel, q_est0: Tensor, y0: Tensor, m_past0: Tensor) -> Tensor:
    """Offset prior mean from the first observation: ``b0 = ỹ_0 − h(q̂_0, m_past0)`` ``(B,)`` (mag).

    A non-finite ``ỹ_0`` or prediction gives ``b0 = 0`` for that filter (the prior std then carries it).
    """
    with torch.no_grad():
        pred, _ = model(q=q_est0, m_past=m_past0.expand(q_est0.shape[:-1]), variance="none")
    b0 = y0.to(pred) - pred
    return torch.where(torch.isfinite(b0), b0, torch.zeros_like(b0))


def offset_covariance(p0_deg: float, offset_prior_std: float, *, dtype=None, device=None) -> Tensor:
    """``P0 = diag((p0_deg in rad)² I₃, offset_prior_std²)`` ``(4, 4)`` for the state ``[δp, b]``."""
    P0 = torch.zeros(4, 4, dtype=dtype or torch.get_default_dtype(), device=device)
    P0[:3, :3] = initial_covariance(p0_deg, dtype=P0.dtype, device=device)
    P0[3, 3] = offset_prior_std**2
    return P0
