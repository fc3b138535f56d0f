"""Sigma-point weights and robust batched matrix square roots of the unscented transform (paper section 2.5).

:func:`unscented_weights` gives ``(λ, wm, wc)`` with λ given directly (the paper's ``λ = 0``) or derived as
``λ = α² (n + κ) − n``; :func:`matrix_sqrt` the lower Cholesky factor of a symmetrised covariance with a
per-matrix eigendecomposition fallback (clipped eigenvalues) that is counted, never a silent NaN.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import torch
from torch import Tensor

__all__ = [
    "SqrtFallbackWarning",
    "UNROLLED_CHOLESKY_MAX",
    "cholesky_unrolled",
    "UnscentedWeights",
    "matrix_sqrt",
    "sqrt_psd",
    "sqrt_psd_with_zero_rows",
    "symmetrise",
    "unscented_weights",
    "warn_fallbacks",
]


class SqrtFallbackWarning(RuntimeWarning):
    """A covariance was not positive definite: its square root came from a clipped eigendecomposition."""


class UnscentedWeights(NamedTuple):
    """Scaling parameter and weights of the ``2n + 1`` sigma points (unpacks as ``lam, wm, wc``)."""

    lam: float
    wm: Tensor  #: mean weights ``(2n+1,)``
    wc: Tensor  #: covariance weights ``(2n+1,)``


def unscented_weights(n: int, alpha: float, beta: float, kappa: float, lam: float | None = None, *,
                      dtype: torch.dtype | None = None, device=None) -> UnscentedWeights:
    """Sigma-point weights (paper section 2.5).

    ``w0m = λ/(n+λ)``, ``w0c = λ/(n+λ) + (1 − α² + β)``, ``wim = wic = 1/(2(n+λ))`` for ``i = 1 … 2n``.

    Args:
        n: state dimension.
        alpha, beta, kappa: the usual tuning parameters (``kappa`` only enters a derived λ).
        lam: λ given directly (the paper uses ``λ = 0``, which no ``α, κ`` formula yields);
            ``None`` derives ``λ = α² (n + κ) − n`` (Merwe's scaled sigma points, filterpy).
        dtype, device: of the returned weight tensors (default dtype, CPU).

    Returns:
        ``UnscentedWeights(lam, wm (2n+1,), wc (2n+1,))``.

    Raises:
        ValueError: ``n + λ ≤ 0`` (no real sigma-point spread).
    """
    if n < 1:
        raise ValueError(f"state dimension must be >= 1, got {n}")
    lam = alpha * alpha * (n + kappa) - n if lam is None else float(lam)
    if not n + lam > 0:
        raise ValueError(f"n + lambda must be positive, got n={n}, lambda={lam:g}")
    dtype = dtype or torch.get_default_dtype()
    wm = torch.full((2 * n + 1,), 1.0 / (2.0 * (n + lam)), dtype=dtype, device=device)
    wc = wm.clone()
    wm[0] = lam / (n + lam)
    wc[0] = lam / (n + lam) + (1.0 - alpha * alpha + beta)
    return UnscentedWeights(lam, wm, wc)


def symmetrise(a: Tensor) -> Tensor:
    """``(A + Aᵀ) / 2`` of matrices ``(..., n, n)``."""
    return 0.5 * (a + a.transpose(-1, -2))


def matrix_sqrt(a: Tensor) -> tuple[Tensor, Tensor]:
    """Square roots ``S`` with ``S Sᵀ = A`` of symmetric matrices ``(..., n, n)``, batched and per matrix robust.

    ``A`` is symmetrised first. Matrices whose Cholesky factorisation succeeds get their lower factor (the same
    sigma points as filterpy's default ``scipy.linalg.cholesky``, whose upper factor's rows are these columns);
    the others get ``V diag(√max(λ_i, 0))`` from an eigendecomposition, so ``S Sᵀ`` is ``A`` with its negative
    eigenvalues clipped to zero. Non-finite matrices stay non-finite (they are the caller's bug to report).

    Returns:
        ``(S (..., n, n), failed (...) bool)`` — ``failed`` marks the matrices that took the fallback.

    Note:
        Checking whether any factorisation failed reads one boolean back from the device (one sync per call).
    """
    a = symmetrise(a)
    s, info = torch.linalg.cholesky_ex(a)
    failed = info != 0
    if bool(failed.any()):
        bad = a[failed]
        finite = torch.isfinite(bad).all(-1).all(-1)
        evals, evecs = torch.linalg.eigh(torch.where(finite[:, None, None], bad, torch.zeros_like(bad)))
        root = evecs * evals.clamp_min(0.0).sqrt().unsqueeze(-2)
        s = s.clone()
        s[failed] = torch.where(finite[:, None, None], root, torch.full_like(root, math.nan))
    return s, failed


#: largest matrix that :func:`sqrt_psd` factorises elementwise inside a compiled graph (the filters' states: 3–8)
UNROLLED_CHOLESKY_MAX = 8


def cholesky_unrolled(a: Tensor) -> tuple[Tensor, Tensor]:
    """Lower Cholesky factors of symmetric matrices ``(..., n, n)`` written out elementwise (``L_jj = √(a_jj −
    Σ_k L_jk²)``, ``L_ij = (a_ij − Σ_k L_ik L_jk) / L_jj``, the unblocked algorithm of LAPACK's ``potf2``), and
    ``(...)`` where a pivot is not positive or not finite (LAPACK's failure; that factor is not to be used).
    A compiled graph fuses it into a few loops where the library call costs ~15 µs for a 3 × 3 matrix."""
    n = a.shape[-1]
    L: list[list[Tensor | None]] = [[None] * n for _ in range(n)]
    failed = torch.zeros(a.shape[:-2], dtype=torch.bool, device=a.device)
    for j in range(n):
        pivot = a[..., j, j] - sum((L[j][k] ** 2 for k in range(j)), torch.zeros_like(a[..., j, j]))
        ok = pivot > 0  # False for NaN too
        failed = failed | ~ok
        L[j][j] = torch.sqrt(torch.where(ok, pivot, torch.ones_like(pivot)))
        for i in range(j + 1, n):
            L[i][j] = (a[..., i, j] - sum((L[i][k] * L[j][k] for k in range(j)), torch.zeros_like(pivot))) / L[j][j]
    zero = torch.zeros_like(a[..., 0, 0])
    rows = [torch.stack([L[i][j] if j <= i else zero for j in range(n)], -1) for i in range(n)]
    return torch.stack(rows, -2), failed


def sqrt_psd(a: Tensor) -> tuple[Tensor, Tensor]:
    """:func:`matrix_sqrt` for matrices already symmetric (the common path costs one Cholesky and one sync).

    Inside a compiled graph (:mod:`lightcurve_gp.filters.compiled`) the factor is returned without the fallback: a
    failed matrix is only flagged; a small one (``n ≤`` :data:`UNROLLED_CHOLESKY_MAX`) is factorised by
    :func:`cholesky_unrolled`, which the compiler fuses with the rest of the step."""
    if torch.compiler.is_compiling():  # no read-back inside a compiled step: it redoes a failed step eagerly
        if a.shape[-1] <= UNROLLED_CHOLESKY_MAX:
            return cholesky_unrolled(a)
        s, info = torch.linalg.cholesky_ex(a)
        return s, info != 0
    s, info = torch.linalg.cholesky_ex(a)
    failed = info != 0
    if bool(failed.any()):
        s, failed = matrix_sqrt(a)
    return s, failed


def sqrt_psd_with_zero_rows(a: Tensor) -> tuple[Tensor, Tensor]:
    """Lower square roots ``S (..., n, n)`` with ``S Sᵀ = a`` of symmetric PSD matrices, where components of exactly
    zero variance (a zero diagonal entry, hence a zero row and column) are left out of the factorisation: their
    column of ``S`` is zero and the other columns are the Cholesky factor of the rest (a state block known
    exactly). Other failures fall back as :func:`sqrt_psd` does; returns ``(S, failed (...))``."""
    zero = torch.diagonal(a, dim1=-2, dim2=-1) == 0
    s, failed = sqrt_psd(a + torch.diag_embed(zero.to(a.dtype)))
    return s * (~zero).unsqueeze(-2).to(a.dtype), failed


def warn_fallbacks(count: int, total: int, where: str) -> None:
    """Emit one :class:`SqrtFallbackWarning`: ``count`` of ``total`` filters needed the fallback in ``where``."""
    warnings.warn(
        f"{where}: covariance not positive definite for {count} of {total} filters; used the eigendecomposition "
        "square root with clipped eigenvalues",
        SqrtFallbackWarning,
        stacklevel=3,
    )
