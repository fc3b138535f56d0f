"""Batched unscented Kalman filtering: a generic UKF for vector states and USQUE for attitudes.

Paper section 2.5 (UKF) and 3.3 (GPUKF); USQUE after Crassidis & Markley (2003), "Unscented filtering for
spacecraft attitude estimation". Many independent filters advance together: every tensor carries a leading
batch dimension ``B`` and one step of all filters is a handful of batched tensor operations.

Generic pieces (any state dimension ``n``):

* :func:`unscented_weights` — ``(λ, wm, wc)`` with λ given directly (the paper's ``λ = 0``) or derived as
  ``λ = α² (n + κ) − n``;
* :func:`matrix_sqrt` / :func:`sigma_points` — lower Cholesky factor of the symmetrised ``(n + λ) P``, with a
  per-filter eigendecomposition fallback (clipped eigenvalues) that is counted, never a silent NaN;
* :func:`ukf_predict` / :func:`ukf_update` — the additive-noise UKF of the paper's Sec. 2.5, Eqs. (31)–(47); the
  update redraws sigma points from the prior like the paper ("computed again") and filterpy.

USQUE (:func:`run_usque`): the state is the GRP attitude error ``δp`` (3) about reference quaternions ``q̂``;
ω is known, so the prediction model enters only through per-step kinematic increments ``δ_k`` with
``q_{k+1} = normalise(δ_k ⊗ q_k)`` for every attitude (torque-free ω(t) does not depend on q).

Conventions (docs/design.md): scalar-last quaternions, paper product ``⊗``, error ``q_err = q_true ⊗ q_est⁻¹``,
GRP ``p = f q̄ / (a + q4)``. The sign of ``q̂`` is never canonicalised inside the filter: it stays continuous
along a run, because ``q`` and ``−q`` are different inputs to a GP observation model.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Callable, NamedTuple

import torch
from torch import Tensor

from .rotations import attitude_matrix, grp_to_quat

__all__ = [
    "UnscentedWeights",
    "unscented_weights",
    "matrix_sqrt",
    "sigma_points",
    "unscented_mean_cov",
    "UkfPrediction",
    "UkfUpdate",
    "ukf_predict",
    "ukf_update",
    "UsqueParams",
    "FilterHistory",
    "initial_covariance",
    "run_usque",
    "SqrtFallbackWarning",
]


class SqrtFallbackWarning(RuntimeWarning):
    """A covariance was not positive definite: its square root came from a clipped eigendecomposition."""


# ----------------------------------------------------------------------------------------------- generic pieces

class UnscentedWeights(NamedTuple):
    """Scaling parameter and weights of the ``2n + 1`` sigma points (unpacks as ``lam, wm, wc``)."""

    lam: float
    wm: Tensor  #: mean weights ``(2n+1,)``
    wc: Tensor  #: covariance weights ``(2n+1,)``


def unscented_weights(n: int, alpha: float, beta: float, kappa: float, lam: float | None = None, *,
                      dtype: torch.dtype | None = None, device=None) -> UnscentedWeights:
    """Sigma-point weights (paper eqs. after priori_predicted_cov).

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


def _symmetrise(a: Tensor) -> Tensor:
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
    a = _symmetrise(a)
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


def _warn_fallbacks(count: int, total: int, where: str) -> None:
    warnings.warn(
        f"{where}: covariance not positive definite for {count} of {total} filters; used the eigendecomposition "
        "square root with clipped eigenvalues",
        SqrtFallbackWarning,
        stacklevel=3,
    )


def sigma_points(x: Tensor, P: Tensor, lam: float, *, warn: bool = True) -> tuple[Tensor, Tensor]:
    """Sigma points ``[x, x + cols(√((n+λ)P)), x − cols(√((n+λ)P))]`` (paper Eqs. (31)–(33)).

    Args:
        x: means ``(B, n)`` (any leading batch shape ``(...)``).
        P: covariances ``(B, n, n)``.
        lam: scaling parameter λ.
        warn: emit :class:`SqrtFallbackWarning` when some covariance needed the eigendecomposition fallback.

    Returns:
        ``(sigmas (B, 2n+1, n), fallbacks (B,) int64)`` with ``fallbacks`` 1 where the fallback was used.
        Ordering ``0, +1 … +n, −1 … −n`` matches filterpy's ``MerweScaledSigmaPoints``.
    """
    n = x.shape[-1]
    s, failed = matrix_sqrt((n + lam) * P)
    cols = s.transpose(-1, -2)  # row j = column j of S
    xs = x.unsqueeze(-2)
    sig = torch.cat([xs, xs + cols, xs - cols], dim=-2)
    if warn and bool(failed.any()):
        _warn_fallbacks(int(failed.sum()), failed.numel(), "sigma_points")
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


def ukf_predict(x: Tensor, P: Tensor, fx: Callable[[Tensor], Tensor], Q: Tensor | float,
                weights: UnscentedWeights) -> UkfPrediction:
    """Additive-noise UKF prediction for batched vector states.

    Args:
        x: ``(B, n)``; P: ``(B, n, n)``.
        fx: maps sigma points ``(B, 2n+1, n)`` to propagated ones of the same shape.
        Q: process noise ``(n, n)``, ``(B, n, n)`` or a scalar (× I).
        weights: from :func:`unscented_weights`.
    """
    n = x.shape[-1]
    sig, fb = sigma_points(x, P, weights.lam)
    sig_f = fx(sig)
    Q = _as_cov(Q, n, x)
    xp, Pp = unscented_mean_cov(sig_f, weights.wm, weights.wc, Q)
    return UkfPrediction(xp, _symmetrise(Pp), sig_f, fb)


def ukf_update(x: Tensor, P: Tensor, z: Tensor, hx: Callable[[Tensor], Tensor], R: Tensor | float,
               weights: UnscentedWeights, sigmas: Tensor | None = None) -> UkfUpdate:
    """Additive-noise UKF measurement update for batched vector states.

    Args:
        x: a priori means ``(B, n)``; P: a priori covariances ``(B, n, n)``.
        z: measurements ``(B, m)``.
        hx: maps sigma points ``(B, 2n+1, n)`` to predicted measurements ``(B, 2n+1, m)``.
        R: measurement noise ``(m, m)``, ``(B, m, m)`` or a scalar (× I).
        weights: from :func:`unscented_weights`.
        sigmas: sigma points to use; ``None`` redraws them from ``(x, P)`` (paper, filterpy).

    Returns:
        :class:`UkfUpdate`; ``P⁺ = P⁻ − K S Kᵀ`` symmetrised.
    """
    fb = torch.zeros(x.shape[:-1], dtype=torch.int64, device=x.device)
    if sigmas is None:
        sigmas, fb = sigma_points(x, P, weights.lam)
    zs = hx(sigmas)
    m = zs.shape[-1]
    zp, S = unscented_mean_cov(zs, weights.wm, weights.wc, _as_cov(R, m, x))
    dx = sigmas - x.unsqueeze(-2)
    dz = zs - zp.unsqueeze(-2)
    Pxz = torch.matmul(dx.transpose(-1, -2) * weights.wc, dz)
    S = _symmetrise(S)
    K = torch.linalg.solve(S, Pxz.transpose(-1, -2)).transpose(-1, -2)  # Pxz S⁻¹ (S symmetric)
    nu = z - zp
    xn = x + (K @ nu.unsqueeze(-1)).squeeze(-1)
    Pn = _symmetrise(P - K @ S @ K.transpose(-1, -2))
    return UkfUpdate(xn, Pn, zp, S, K, nu, fb)


def _as_cov(c: Tensor | float, n: int, like: Tensor) -> Tensor:
    """Scalar → ``c I``; tensors ``(n, n)`` / ``(B, n, n)`` are cast to ``like``'s dtype and device."""
    if isinstance(c, Tensor):
        c = c.to(dtype=like.dtype, device=like.device)
        if c.ndim == 0:
            return c * torch.eye(n, dtype=like.dtype, device=like.device)
        return c
    return float(c) * torch.eye(n, dtype=like.dtype, device=like.device)


# ----------------------------------------------------------------------------------------------- USQUE

@dataclass(frozen=True, eq=False)
class UsqueParams:
    """USQUE tuning (defaults: the paper's filter, Sec. 4.1; docs/design.md).

    Attributes:
        alpha, beta, kappa: unscented tuning parameters.
        lam: λ given directly; ``None`` derives ``α² (3 + κ) − 3``.
        grp_a, grp_f: GRP parameters ``a`` and ``f``.
        Q: process noise on the GRP error per step (rad²): scalar (× I), ``(3, 3)`` or ``(B, 3, 3)``.
        R: measurement noise variance (mag²): scalar or ``(B,)``.
        add_model_variance: add the observation model's mean predictive variance ``Σ wm var_i`` to ``Pyy``.
        t_span_past: ``T`` of the running mean ``m_past ← (T m_past + ỹ) / (T + 1)`` (paper Sec. 3.3, Eq. (54)).
    """

    alpha: float = 1e-4
    beta: float = 2.0
    kappa: float = 0.0
    lam: float | None = 0.0
    grp_a: float = 1.0
    grp_f: float = 4.0
    Q: float | Tensor = 1e-4
    R: float | Tensor = 0.5
    add_model_variance: bool = True
    t_span_past: float = 20.0

    @classmethod
    def from_config(cls, filter_cfg, t_span_past: float) -> "UsqueParams":
        """Parameters from a :class:`~lightcurve_gp.config.FilterConfig` (``Q = process_noise · I``)."""
        return cls(
            alpha=float(filter_cfg.alpha), beta=float(filter_cfg.beta), kappa=float(filter_cfg.kappa),
            lam=None if filter_cfg.lam is None else float(filter_cfg.lam),
            grp_a=float(filter_cfg.grp_a), grp_f=float(filter_cfg.grp_f),
            Q=float(filter_cfg.process_noise), R=float(filter_cfg.measurement_noise),
            add_model_variance=bool(filter_cfg.add_model_variance), t_span_past=float(t_span_past),
        )

    def weights(self, *, dtype: torch.dtype | None = None, device=None) -> UnscentedWeights:
        """Sigma-point weights for the 3-dimensional GRP error state."""
        return unscented_weights(3, self.alpha, self.beta, self.kappa, self.lam, dtype=dtype, device=device)


def initial_covariance(p0_deg: float, *, dtype: torch.dtype | None = None, device=None) -> Tensor:
    """``P0 = (p0_deg in rad)² I₃`` (config ``filter.p0_deg``)."""
    return math.radians(p0_deg) ** 2 * torch.eye(3, dtype=dtype or torch.get_default_dtype(), device=device)


@dataclass
class FilterHistory:
    """Everything a batched USQUE run records, indexed by filter ``b`` and time index ``k = 0 … T``.

    Attributes:
        q_est: posterior attitude estimates ``(B, T+1, 4)`` (``k = 0``: the initial estimate).
        P: posterior GRP-error covariances ``(B, T+1, 3, 3)`` (rad², GRP ≈ rotation vector to first order).
        y_pred: predicted magnitude ``ŷ_k`` ``(B, T+1)``; NaN at ``k = 0``.
        y_var: innovation variance ``Pyy`` (incl. R and model variance) ``(B, T+1)``; NaN at ``k = 0``.
        model_var: mean model variance ``Σ wm var_i`` ``(B, T+1)``; NaN at ``k = 0`` or when not requested.
        innovation: ``ỹ_k − ŷ_k`` ``(B, T+1)`` (NaN where ``ỹ_k`` is NaN and at ``k = 0``).
        m_past: the running mean fed to the model at step ``k`` (before ``ỹ_k`` is folded in) ``(B, T+1)``.
        updated: whether step ``k`` applied a measurement update ``(B, T+1)`` (False at ``k = 0``).
        fallbacks: number of steps whose sigma-point square root fell back ``(B,)``.
        rejected: number of steps with a finite observation whose update was refused because the prediction
            was not finite or ``Pyy ≤ 0`` ``(B,)`` (the prior became the posterior).
        m_past_final: the running mean after the last observation ``(B,)``.
    """

    q_est: Tensor
    P: Tensor
    y_pred: Tensor
    y_var: Tensor
    model_var: Tensor
    innovation: Tensor
    m_past: Tensor
    updated: Tensor
    fallbacks: Tensor
    rejected: Tensor
    m_past_final: Tensor

    def nis(self) -> Tensor:
        """Normalised innovation squared ``ν² / Pyy`` ``(B, T+1)`` (NaN where no innovation)."""
        return self.innovation ** 2 / self.y_var


def _check_run_inputs(q_est0: Tensor, P0: Tensor, b0: Tensor | None, observations: Tensor, m_past0: Tensor,
                      increments: Tensor) -> tuple[int, int]:
    """Shapes and finiteness of a run's inputs; ``b0`` is ``None`` for the attitude-only filter."""
    if q_est0.ndim != 2 or q_est0.shape[-1] != 4:
        raise ValueError(f"q_est0 must have shape (B, 4), got {tuple(q_est0.shape)}")
    B = q_est0.shape[0]
    if observations.ndim != 2 or observations.shape[0] != B:
        raise ValueError(f"observations must have shape (B={B}, T+1), got {tuple(observations.shape)}")
    T = observations.shape[1] - 1
    if T < 0:
        raise ValueError("observations must hold at least t_0")
    n = 3 if b0 is None else 4
    if P0.shape not in ((n, n), (B, n, n)):
        state = "" if b0 is None else " for the state [dp, b]"
        raise ValueError(f"P0 must have shape ({n}, {n}) or (B={B}, {n}, {n}){state}, got {tuple(P0.shape)}")
    if b0 is not None and b0.shape not in ((B,), ()):
        raise ValueError(f"b0 must have shape (B={B},) or (), got {tuple(b0.shape)}")
    if m_past0.shape not in ((B,), ()):
        raise ValueError(f"m_past0 must have shape (B={B},), got {tuple(m_past0.shape)}")
    if increments.shape not in ((T, 4), (B, T, 4)):
        raise ValueError(f"increments must have shape (T={T}, 4) or (B={B}, T={T}, 4), got {tuple(increments.shape)}")
    named = [("q_est0", q_est0), ("P0", P0), ("b0", b0), ("m_past0", m_past0), ("increments", increments)]
    for name, t in named:
        if t is not None and not bool(torch.isfinite(t).all()):
            raise ValueError(f"{name} contains non-finite values")
    return B, T


# Quaternion products as 4×4 matrices (paper product, scalar last): q ⊗ p = L(q) p = R(p) q.
# Each matrix is a signed gather of the four components, built in two tensor operations.
_L_IDX = [3, 2, 1, 0, 2, 3, 0, 1, 1, 0, 3, 2, 0, 1, 2, 3]
_L_SGN = [1, 1, -1, 1, -1, 1, 1, 1, 1, -1, 1, 1, -1, -1, -1, 1]
_R_IDX = [3, 2, 1, 0, 2, 3, 0, 1, 1, 0, 3, 2, 0, 1, 2, 3]
_R_SGN = [1, -1, 1, 1, 1, 1, -1, 1, -1, 1, 1, 1, -1, -1, -1, 1]
_CONST_CACHE: dict = {}


def _consts(name: str, like: Tensor) -> Tensor:
    key = (name, like.dtype, like.device)
    c = _CONST_CACHE.get(key)
    if c is None:
        if name == "L_idx" or name == "R_idx":
            c = torch.tensor(_L_IDX if name == "L_idx" else _R_IDX, device=like.device)
        else:
            c = torch.tensor(_L_SGN if name == "L_sgn" else _R_SGN, dtype=like.dtype, device=like.device)
        _CONST_CACHE[key] = c
    return c


def _left_matrix(q: Tensor) -> Tensor:
    """``L(q)`` with ``q ⊗ p = L(q) p``, ``(..., 4, 4)``."""
    return (q.index_select(-1, _consts("L_idx", q)) * _consts("L_sgn", q)).unflatten(-1, (4, 4))


def _right_matrix(p: Tensor) -> Tensor:
    """``R(p)`` with ``q ⊗ p = R(p) q``, ``(..., 4, 4)``."""
    return (p.index_select(-1, _consts("R_idx", p)) * _consts("R_sgn", p)).unflatten(-1, (4, 4))


def _sqrt_psd(a: Tensor) -> tuple[Tensor, Tensor]:
    """:func:`matrix_sqrt` for matrices already symmetric (the common path costs one Cholesky and one sync)."""
    s, info = torch.linalg.cholesky_ex(a)
    failed = info != 0
    if bool(failed.any()):
        s, failed = matrix_sqrt(a)
    return s, failed


def _usque_loop(model, q_est0: Tensor, P0: Tensor, b0: Tensor | None, observations: Tensor, m_past0: Tensor,
                increments: Tensor, params: UsqueParams, offset_process_noise: float = 0.0) -> dict[str, Tensor]:
    """The batched USQUE recursion shared by :func:`run_usque` (``b0 is None``, state ``δp``) and
    :func:`lightcurve_gp.ukf_offset.run_usque_offset` (state ``[δp, b]``, ``y = h(q, m_past) + b``).

    Returns the stacked history (``q_est, P, y_pred, y_var, model_var, innovation, m_past, updated``, and
    ``offset`` when ``b0`` is given) and the counters ``fallbacks, rejected, m_past_final``. Inputs are checked.
    """
    B, T = _check_run_inputs(q_est0, P0, b0, observations, m_past0, increments)
    dtype, device = q_est0.dtype, q_est0.device
    n = 3 if b0 is None else 4
    n_sig = 2 * n + 1
    a, f = float(params.grp_a), float(params.grp_f)
    with torch.no_grad():
        lam, wm, wc = unscented_weights(n, params.alpha, params.beta, params.kappa, params.lam, dtype=dtype,
                                        device=device)
        scale = n + lam
        w_pair = float(wc[1])  # weight of each of the 2n outer sigma points, 1 / (2 (n + λ))
        Q_att = _as_cov(params.Q if isinstance(params.Q, Tensor) else float(params.Q), 3, q_est0)
        if Q_att.shape not in ((3, 3), (B, 3, 3)):
            raise ValueError(f"Q must be a scalar, (3, 3) or (B={B}, 3, 3), got {tuple(Q_att.shape)}")
        Q = torch.zeros(B, n, n, dtype=dtype, device=device)
        Q[:, :3, :3] = _symmetrise(Q_att)
        if b0 is not None:
            Q[:, 3, 3] = float(offset_process_noise)
        R = torch.as_tensor(params.R, dtype=dtype, device=device)
        if R.shape not in ((), (B,)):
            raise ValueError(f"R must be a scalar or (B={B},), got {tuple(R.shape)}")
        R = R.expand(B)
        tsp = float(params.t_span_past)
        if not tsp >= 0:
            raise ValueError(f"t_span_past must be >= 0, got {tsp}")

        obs = observations.to(dtype=dtype, device=device)
        obs_ok = torch.isfinite(obs)
        obs_filled = torch.where(obs_ok, obs, torch.zeros_like(obs))
        # normalise(δ ⊗ q) = (δ/|δ|) ⊗ q: normalise the increments once; keep their left-product matrices L(δ)
        # and √(n+λ) G(δ), G = A(δ) on the attitude block (identity on b), which carries the sigma offsets
        inc = increments.to(dtype=dtype, device=device)
        inc = inc / torch.linalg.vector_norm(inc, dim=-1, keepdim=True)
        inc = inc.unsqueeze(0) if inc.ndim == 2 else inc  # (1 | B, T, 4)
        G = torch.zeros(*inc.shape[:-1], n, n, dtype=dtype, device=device)
        G[..., :3, :3] = attitude_matrix(inc)
        if b0 is not None:
            G[..., 3, 3] = 1.0
        # per-step views, batch dimension B (stride 0 when shared)
        L_steps = _left_matrix(inc).expand(B, -1, -1, -1).unbind(1)
        G_steps = (G * math.sqrt(scale)).expand(B, -1, -1, -1).unbind(1)
        ok_steps, obs_steps = obs_ok.unbind(1), obs_filled.unbind(1)

        q_hat = q_est0.to(dtype=dtype).clone()
        q_hat = q_hat / torch.linalg.vector_norm(q_hat, dim=-1, keepdim=True)
        b_hat = None if b0 is None else b0.to(dtype=dtype, device=device).expand(B).clone()
        P = _symmetrise(P0.to(dtype=dtype, device=device).expand(B, n, n)).clone()
        m_past = m_past0.to(dtype=dtype, device=device).expand(B).clone()
        fallbacks = torch.zeros(B, dtype=torch.int64, device=device)
        rejected = torch.zeros(B, dtype=torch.int64, device=device)
        want_var = bool(params.add_model_variance)
        nan_b = torch.full((B,), math.nan, dtype=dtype, device=device)
        zero_row = torch.zeros(B, 1, n, dtype=dtype, device=device)
        zero = torch.zeros((), dtype=dtype, device=device)

        hist = {name: [] for name in ("q_est", "P", "y_pred", "y_var", "model_var", "innovation", "m_past",
                                      "updated", "offset")}

        def record(q, cov, y, yv, mv, nu, mp, up, b):
            for name, value in zip(hist, (q, cov, y, yv, mv, nu, mp, up, b)):
                hist[name].append(value)

        record(q_hat, P, nan_b, nan_b, nan_b, nan_b, m_past, torch.zeros(B, dtype=torch.bool, device=device), b_hat)
        for k in range(1, T + 1):
            # 1-5. sigma offsets ±√(n+λ) cols √(P⁺ + Q) about x̂⁺ = [0, b̂]; propagating q_i = δq(χ_i) ⊗ q̂ to
            # δ ⊗ q_i and re-expressing it about the propagated centre δ ⊗ q̂ conjugates δq(χ_i) by δ, which keeps
            # its scalar part and rotates its vector part by A(δ), so the GRP becomes A(δ) χ_i (b is unchanged):
            # the propagated offsets are the columns of S⁻ = √(n+λ) G S, x̂⁻ = x̂⁺ and P⁻ = S⁻ S⁻ᵀ/(n+λ) + Q
            # exactly (Crassidis & Markley 2003, Q in both places)
            s, failed = _sqrt_psd(P + Q)
            fallbacks += failed
            S_m = torch.bmm(G_steps[k - 1], s)  # (B, n, n): column j = propagated sigma offset j
            P_m = torch.baddbmm(Q, S_m, S_m.mT, alpha=1.0 / scale)
            offsets = S_m.mT
            chi = torch.cat([zero_row, offsets, -offsets], dim=1)  # (B, 2n+1, n)
            # 6. sigma attitudes q_i⁻ = δq(χ_i⁻) ⊗ q_0⁻, q_0⁻ = δ ⊗ q̂; one model call for all of them
            q_m = torch.bmm(L_steps[k - 1], q_hat.unsqueeze(-1)).squeeze(-1)
            R_qm = _right_matrix(q_m)
            q_sig = torch.bmm(grp_to_quat(chi[..., :3], a, f), R_qm.mT)  # (B, 2n+1, 4)
            y_sig, var_sig = model(q=q_sig, m_past=m_past.unsqueeze(1).expand(B, n_sig), with_variance=want_var)
            if b_hat is not None:
                y_sig = y_sig + (b_hat.unsqueeze(1) + chi[..., 3])
            y_hat = y_sig @ wm
            dy = y_sig - y_hat.unsqueeze(1)
            P_yy = (dy * dy) @ wc + R
            if want_var and var_sig is not None:
                m_var = var_sig @ wm
                P_yy = P_yy + m_var
            else:
                m_var = nan_b
            # Pxy = Σ wc (χ_i⁻ − x̂⁻)(Y_i − ŷ): the centre contributes nothing, pair j gives col_j (dy₊ⱼ − dy₋ⱼ)
            P_xy = torch.bmm(S_m, (dy[:, 1:n + 1] - dy[:, n + 1:]).unsqueeze(-1)).squeeze(-1).mul_(w_pair)
            # 7. update where the observation exists and the prediction is usable
            ok_k = ok_steps[k]
            good = ((P_xy.sum(-1) + y_hat + P_yy).abs() < math.inf) & (P_yy > 0)  # finite, usable
            upd = ok_k & good
            rejected += ok_k & ~good
            nu = obs_steps[k] - y_hat
            K = P_xy / P_yy.unsqueeze(-1)
            # where() keeps inf/NaN of refused steps out of the state: the prior becomes the posterior
            dx = torch.where(upd.unsqueeze(-1), K * nu.unsqueeze(-1), zero)
            P_post = _symmetrise(P_m - P_yy.view(B, 1, 1) * (K.unsqueeze(-1) * K.unsqueeze(-2)))
            P = torch.where(upd.view(B, 1, 1), P_post, P_m)
            # 8. reset q̂ ← δq(δp⁺) ⊗ q_0⁻ (the attitude error returns to zero); b̂ keeps its estimate
            q_hat = torch.bmm(R_qm, grp_to_quat(dx[:, :3], a, f).unsqueeze(-1)).squeeze(-1)
            q_hat = q_hat / torch.linalg.vector_norm(q_hat, dim=-1, keepdim=True)
            if b_hat is not None:
                b_hat = b_hat + dx[:, 3]
            # record (m_past as used for this prediction), then 9. fold the observation into m_past
            record(q_hat, P, y_hat, P_yy, m_var, nu, m_past, upd, b_hat)
            m_past = torch.where(ok_k, (tsp * m_past + obs_steps[k]) / (tsp + 1.0), m_past)

        out = {name: torch.stack(values, 1) for name, values in hist.items() if values[0] is not None}
        out["innovation"] = torch.where(obs_ok, out["innovation"], math.nan)
        out.update(fallbacks=fallbacks, rejected=rejected, m_past_final=m_past)
    return out


def run_usque(model, q_est0: Tensor, P0: Tensor, observations: Tensor, m_past0: Tensor, increments: Tensor,
              params: UsqueParams | None = None) -> FilterHistory:
    """Run ``B`` independent USQUE filters over ``T`` steps in one set of tensors.

    Step ``k = 1 … T`` (Crassidis & Markley 2003, Q added to the sigma-point covariance and again to ``P⁻``):

    1. ``χ_i = 0 ± cols √((n+λ)(P⁺ + Q))``; 2. ``q_i = grp_to_quat(χ_i) ⊗ q̂``;
    3. ``q_i⁻ = normalise(δ_{k−1} ⊗ q_i)``; 4. ``χ_i⁻ = quat_to_grp(q_i⁻ ⊗ (q_0⁻)⁻¹)``;
    5. ``x̂⁻ = Σ wm χ_i⁻``, ``P⁻ = Σ wc (χ_i⁻ − x̂⁻)(·)ᵀ + Q``;
    6. ``Y_i = model(q_i⁻, m_past)``, ``ŷ = Σ wm Y_i``, ``Pyy = Σ wc (Y_i − ŷ)² + R (+ Σ wm var_i)``,
       ``Pxy = Σ wc (χ_i⁻ − x̂⁻)(Y_i − ŷ)``;
    7. ``K = Pxy / Pyy``, ``x̂⁺ = x̂⁻ + K (ỹ_k − ŷ)``, ``P⁺ = P⁻ − K Pyy Kᵀ``;
    8. reset ``q̂ ← grp_to_quat(x̂⁺) ⊗ q_0⁻``; 9. ``m_past ← (T m_past + ỹ_k) / (T + 1)``.

    With ω known, steps 2–5 are a rotation: ``q_i⁻ ⊗ (q_0⁻)⁻¹ = δ ⊗ δq(χ_i) ⊗ δ⁻¹`` has the GRP ``A(δ) χ_i``
    (conjugation by ``δ`` rotates a quaternion's vector part by ``A(δ)``), so ``χ_i⁻ = A(δ) χ_i``, ``x̂⁻ = 0`` and
    ``P⁻ = A (P⁺ + Q) Aᵀ + Q``. The loop computes them that way: the same filter with a fraction of the work.

    A NaN observation skips steps 7 and 9 for that filter only (the prior becomes the posterior). A finite
    observation whose prediction is not finite or whose ``Pyy ≤ 0`` is refused the same way and counted in
    ``rejected``; its ``m_past`` recursion still happens (the observation is real).

    Args:
        model: an :class:`~lightcurve_gp.observation.base.ObservationModel` (called once per step with
            ``q (B, 2n+1, 4)`` and ``m_past (B, 2n+1)``).
        q_est0: initial estimates ``(B, 4)`` (their sign is kept; the run stays sign-continuous).
        P0: initial covariances ``(B, 3, 3)`` or ``(3, 3)`` (rad²).
        observations: ``ỹ_0 … ỹ_T`` ``(B, T+1)`` in mag (NaN = missing); ``ỹ_0`` is not used by the filter.
        m_past0: running mean at ``t_0`` ``(B,)``, chosen by the caller.
        increments: ``δ_0 … δ_{T−1}`` ``(T, 4)`` shared by all filters or ``(B, T, 4)``.
        params: :class:`UsqueParams` (default: the paper's filter).

    Returns:
        :class:`FilterHistory`. Emits :class:`SqrtFallbackWarning` once when any filter needed the square-root
        fallback (counts in ``fallbacks``).
    """
    out = _usque_loop(model, q_est0, P0, None, observations, m_past0, increments, params or UsqueParams())
    n_fb = int((out["fallbacks"] > 0).sum())
    if n_fb:
        _warn_fallbacks(n_fb, q_est0.shape[0], "run_usque")
    return FilterHistory(**out)
