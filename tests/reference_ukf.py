"""A generic additive-noise UKF for batched vector states: the reference the tests check USQUE against.

The paper's UKF (section 2.5) for any state dimension ``n``, with the update redrawing sigma points from
the prior like the paper ("computed again") and filterpy. The library's USQUE (:mod:`lightcurve_gp.filters.usque`) is a
specialised, faster form of it for attitudes; this module shares only the weights and square roots with it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import torch
from torch import Tensor

from lightcurve_gp.filters.unscented import (
    UnscentedWeights,
    matrix_sqrt,
    symmetrise,
    warn_fallbacks,
)


def sigma_points(x: Tensor, P: Tensor, lam: float, *, warn: bool = True) -> tuple[Tensor, Tensor]:
    """Sigma points ``[x, x + cols(√((n+λ)P)), x − cols(√((n+λ)P))]`` ``(B, 2n+1, n)`` of means ``x (B, n)`` and
    covariances ``P (B, n, n)``, and ``(B,)`` 1 where the square root fell back. Ordering ``0, +1 … +n, −1 … −n``
    matches filterpy's ``MerweScaledSigmaPoints``."""
    n = x.shape[-1]
    s, failed = matrix_sqrt((n + lam) * P)
    cols = s.transpose(-1, -2)  # row j = column j of S
    xs = x.unsqueeze(-2)
    sig = torch.cat([xs, xs + cols, xs - cols], dim=-2)
    if warn and bool(failed.any()):
        warn_fallbacks(int(failed.sum()), failed.numel(), "sigma_points")
    return sig, failed.to(torch.int64)


def unscented_mean_cov(sigmas: Tensor, wm: Tensor, wc: Tensor, noise: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Weighted mean ``(…, m)`` and covariance ``(…, m, m)`` of transformed sigma points ``(…, S, m)`` (+ noise)."""
    mean = torch.einsum("s,...sm->...m", wm, sigmas)
    d = sigmas - mean.unsqueeze(-2)
    cov = torch.matmul(d.transpose(-1, -2) * wc, d)
    if noise is not None:
        cov = cov + noise
    return mean, cov


class UkfPrediction(NamedTuple):
    x: Tensor  #: a priori means ``(B, n)``
    P: Tensor  #: a priori covariances ``(B, n, n)``
    sigmas_f: Tensor  #: propagated sigma points ``(B, 2n+1, n)``
    fallbacks: Tensor  #: ``(B,)`` 1 where the square root fell back


class UkfUpdate(NamedTuple):
    x: Tensor  #: posterior means ``(B, n)``
    P: Tensor  #: posterior covariances ``(B, n, n)``
    z_pred: Tensor  #: predicted measurements ``(B, m)``
    S: Tensor  #: innovation covariances ``(B, m, m)``
    K: Tensor  #: gains ``(B, n, m)``
    innovation: Tensor  #: ``z − z_pred`` ``(B, m)``
    fallbacks: Tensor  #: ``(B,)`` 1 where the square root fell back


def _as_cov(c: Tensor | float, n: int, like: Tensor) -> Tensor:
    """Scalar → ``c I``; tensors ``(n, n)`` / ``(B, n, n)`` are cast to ``like``'s dtype and device."""
    if isinstance(c, Tensor):
        c = c.to(dtype=like.dtype, device=like.device)
        if c.ndim == 0:
            return c * torch.eye(n, dtype=like.dtype, device=like.device)
        return c
    return float(c) * torch.eye(n, dtype=like.dtype, device=like.device)


def ukf_predict(x: Tensor, P: Tensor, fx: Callable[[Tensor], Tensor], Q: Tensor | float,
                weights: UnscentedWeights) -> UkfPrediction:
    """Prediction: ``fx`` maps sigma points ``(B, 2n+1, n)`` to propagated ones; ``Q`` is ``(n, n)``,
    ``(B, n, n)`` or a scalar (× I)."""
    n = x.shape[-1]
    sig, fb = sigma_points(x, P, weights.lam)
    sig_f = fx(sig)
    xp, Pp = unscented_mean_cov(sig_f, weights.wm, weights.wc, _as_cov(Q, n, x))
    return UkfPrediction(xp, symmetrise(Pp), sig_f, fb)


def ukf_update(x: Tensor, P: Tensor, z: Tensor, hx: Callable[[Tensor], Tensor], R: Tensor | float,
               weights: UnscentedWeights, sigmas: Tensor | None = None) -> UkfUpdate:
    """Update with measurements ``z (B, m)``: ``hx`` maps sigma points ``(B, 2n+1, n)`` to ``(B, 2n+1, m)``;
    ``sigmas=None`` redraws them from ``(x, P)``; ``P⁺ = P⁻ − K S Kᵀ`` symmetrised."""
    fb = torch.zeros(x.shape[:-1], dtype=torch.int64, device=x.device)
    if sigmas is None:
        sigmas, fb = sigma_points(x, P, weights.lam)
    zs = hx(sigmas)
    m = zs.shape[-1]
    zp, S = unscented_mean_cov(zs, weights.wm, weights.wc, _as_cov(R, m, x))
    dx = sigmas - x.unsqueeze(-2)
    dz = zs - zp.unsqueeze(-2)
    Pxz = torch.matmul(dx.transpose(-1, -2) * weights.wc, dz)
    S = symmetrise(S)
    K = torch.linalg.solve(S, Pxz.transpose(-1, -2)).transpose(-1, -2)  # Pxz S⁻¹ (S symmetric)
    nu = z - zp
    xn = x + (K @ nu.unsqueeze(-1)).squeeze(-1)
    Pn = symmetrise(P - K @ S @ K.transpose(-1, -2))
    return UkfUpdate(xn, Pn, zp, S, K, nu, fb)
