"""Inducing-point GP observation model: SGPR with Titsias' collapsed bound (paper section 3.2).

Same kernel, noise and centred outputs as :class:`~.exact_gp.ExactGP`. ``M = model.sparse.num_inducing`` inducing
inputs ``Z`` are initialised from the mapped training inputs by k-means (a few seeded Lloyd iterations) or a seeded
random subset, and optionally optimised (``model.sparse.optimize_inducing``) for ``model.sparse.iterations`` Adam
steps on the collapsed bound (:func:`.fitting.fit_sgpr`). Kernel hyperparameters stay the paper's unless
``model.fit_hyperparameters``. The fit may be made cheaper than the final model (``model.sparse``: ``optimizer``
L-BFGS, ``fit_dtype`` float32, a ``fit_subset`` of the points, ``fit_inducing`` fewer inducing inputs, ``fit_form``
gram: the same bound from ``K_uf K_fu``, :func:`.fitting.gram_bound`), or made on
the exact GP's evidence of a ``fit_subset`` instead of the bound (``fit_objective: exact_subset``: no Nyström
error term, which penalises short lengthscales on the bound); the conditioning below is float64 on all points with
all ``num_inducing`` inducing inputs either way.

Prediction is plain torch on a cache computed once (float64, Cholesky forms; ``L_uu L_uuᵀ = K_uu``,
``A = L_uu⁻¹ K_uf / σ``, ``B = I + A Aᵀ = L_B L_Bᵀ``, so that ``Λ = K_uu + σ⁻² K_uf K_fu = L_uu B L_uuᵀ``):

* mean ``μ + k_*uᵀ w``, ``w = σ⁻² Λ⁻¹ K_uf (y − μ) = L_uu⁻ᵀ L_B⁻ᵀ L_B⁻¹ A (y − μ) / σ``;
* variance ``k** − k_*uᵀ P k_*u``, ``P = K_uu⁻¹ − Λ⁻¹ = WᵀW − VᵀV`` with ``W = L_uu⁻¹``, ``V = L_B⁻¹ W``.

The variance is exact for this model and cheap, so ``"fast"`` and ``"exact"`` give the same; it does not depend on
the batch layout. Its quadratic form, ``(P × M)·(M × M)`` multiply-adds for ``P`` points, is most of a call's cost;
it is computed as ``‖k_*uᵀ F‖²`` with ``F`` the lower Cholesky factor of ``P`` (positive definite: ``Λ ≻ K_uu``)
in float32, whose matrix product runs at twice the float64 rate and whose sum of squares cancels nothing — when,
on the model's own inducing inputs (where the form is largest and the variance smallest), it agrees with the
float64 form to :data:`FLOAT32_VARIANCE_TOL` ``· θ1``; otherwise (a ``P`` that is ill-conditioned or not
numerically positive definite) in float64 as ``k_*uᵀ (P k_*u)``.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from lightcurve_gp.config.load import config_to_dict
from lightcurve_gp.observation.base import Prediction, Variance
from lightcurve_gp.observation.fitting import fit_hyperparameters, fit_sgpr, seeded_subset
from lightcurve_gp.observation.gp_base import CachedGP, GPTrainingSet, cpu64
from lightcurve_gp.observation.inputs import InputMap
from lightcurve_gp.observation.kernels import (
    cholesky_jittered,
    cross_kernel_cache,
    exp_neg_sqdist,
    kernel_matrix,
    scaled,
)

__all__ = ["FLOAT32_VARIANCE_TOL", "SparseGP", "kmeans", "sgpr_cache", "variance_factor", "conditioning_bytes"]

#: largest |float32 − float64| variance, relative to ``θ1``, on the inducing inputs for which the variance's
#: quadratic form is computed in float32 (:func:`variance_factor`)
FLOAT32_VARIANCE_TOL = 1e-5
#: inducing inputs (the first ones) on which :func:`variance_factor` checks the float32 form
VARIANCE_CHECK_POINTS = 256


def conditioning_bytes(n: int, m: int) -> int:
    """Peak memory (bytes) of fitting and conditioning the inducing-point GP on ``n`` training points with ``m``
    inducing inputs: four ``m × n`` float64 matrices (:func:`sgpr_cache` holds two, a fit's kernel and its gradient
    more; measured: 3.1 of them at n = 60000, m = 512 without a fit) and a few ``m × m``."""
    return 8 * (4 * m * n + 4 * m * m)


def kmeans(x: Tensor, m: int, *, iterations: int = 10, seed: int = 0) -> Tensor:
    """``m`` k-means centres of ``x (N, d)``: a seeded random subset of the distinct rows, then Lloyd iterations
    (an emptied cluster keeps its centre). ``m`` at least the number of distinct rows returns those rows.

    Starting from distinct rows matters for data with repeated inputs (the paper's grid repeats the identity
    attitude 642 times): two equal centres never separate, and an inducing set with repeats wastes inducing points
    and makes ``K_uu`` singular.
    """
    distinct = torch.unique(x, dim=0)
    n = distinct.shape[0]
    if m >= n:
        return distinct
    centres = distinct[seeded_subset(n, m, seed, x.device)].clone()
    for _ in range(iterations):
        d2 = (centres * centres).sum(-1) - 2.0 * x @ centres.T  # ‖x‖² is the same for every centre
        assign = d2.argmin(dim=1)
        sums = torch.zeros_like(centres).index_add_(0, assign, x)
        counts = torch.bincount(assign, minlength=m)
        filled = counts > 0
        centres[filled] = sums[filled] / counts[filled].unsqueeze(-1).to(x.dtype)
    return centres


def sgpr_cache(x: Tensor, r: Tensor, z: Tensor, outputscale: float, lengthscale: Tensor, noise: float,
               *, jitter: float = 1e-8) -> tuple[Tensor, Tensor]:
    """SGPR prediction cache ``(w (M,), P (M, M))`` for mapped inputs ``x (N, d)``, centred outputs ``r (N,)``
    and inducing inputs ``z (M, d)`` (float64 recommended). ``K_uu`` gets ``jitter·θ1`` on its diagonal."""
    xs, zs = scaled(x, lengthscale), scaled(z, lengthscale)
    m = z.shape[0]
    kuu = kernel_matrix(zs, zs, outputscale)
    kuu.diagonal().add_(jitter * outputscale)
    luu = cholesky_jittered(kuu, scale=outputscale, what=f"the {m}x{m} inducing kernel")
    sigma = noise**0.5
    a = torch.linalg.solve_triangular(luu, kernel_matrix(zs, xs, outputscale), upper=False).div_(sigma)  # (M, N)
    b = torch.addmm(torch.eye(m, dtype=x.dtype, device=x.device), a, a.T)
    lb = cholesky_jittered(b, scale=1.0, what=f"the {m}x{m} SGPR matrix B", scale_name="1")
    c = torch.linalg.solve_triangular(lb, (a @ r).div_(sigma).unsqueeze(-1), upper=False)
    w = torch.linalg.solve_triangular(luu.T, torch.linalg.solve_triangular(lb.T, c, upper=True), upper=True)
    winv = torch.linalg.solve_triangular(luu, torch.eye(m, dtype=x.dtype, device=x.device), upper=False)
    v = torch.linalg.solve_triangular(lb, winv, upper=False)
    p = winv.T @ winv - v.T @ v
    return w.squeeze(-1), 0.5 * (p + p.T)


def variance_factor(p_scaled: Tensor, e_check: Tensor, outputscale: float | Tensor,
                    *, tol: float = FLOAT32_VARIANCE_TOL) -> Tensor | None:
    """Float32 lower Cholesky factor ``F (M, M)`` of ``θ1² P`` (so that ``eᵀ θ1² P e = ‖eᵀ F‖²``), or ``None`` when
    the factorisation fails or the float32 form differs from the float64 one ``eᵀ(θ1² P)e`` by more than
    ``tol · θ1`` on the rows ``e_check (C, M)`` (kernel rows divided by ``θ1``)."""
    chol, info = torch.linalg.cholesky_ex(p_scaled)
    if int(info) != 0:
        return None
    factor = chol.to(torch.float32).contiguous()  # row-major: its GEMM is ~20 % faster than on LAPACK's layout
    exact = (e_check @ p_scaled * e_check).sum(-1)
    y = e_check.to(torch.float32) @ factor
    worst = float((y.mul_(y).sum(-1).to(exact.dtype) - exact).abs().max())
    return factor if worst <= tol * float(outputscale) else None


def _initial_inducing(x: Tensor, num: int, init: str, seed: int, kmeans_iterations: int,
                      inducing_points: Tensor | None) -> Tensor:
    """Inducing inputs ``(M, d)``: given ones, or ``num`` k-means centres or random rows of ``x (N, d)``."""
    if inducing_points is not None:
        z = inducing_points.to(x)
        if z.ndim != 2 or z.shape[1] != x.shape[1]:
            raise ValueError(f"inducing_points must be (M, {x.shape[1]}), got {tuple(z.shape)}")
        return z
    if init == "kmeans":
        return kmeans(x, num, iterations=kmeans_iterations, seed=seed)
    if init == "random":
        return x[seeded_subset(x.shape[0], num, seed, x.device)].clone()
    raise ValueError(f"init must be kmeans or random, got {init!r}")


def _fit(ts: GPTrainingSet, z: Tensor, cfg: Any, *, seed: int, kmeans_iterations: int,
         progress: bool) -> tuple[Tensor, float, Tensor, float, list[float]]:
    """The fit ``cfg.sparse`` asks for, on ``fit_subset`` seeded random training points (all when null), in
    ``fit_dtype``, by ``optimizer``: ``fit_objective`` ``sparse_bound``, :func:`~.fitting.fit_sgpr` with
    ``fit_inducing`` k-means inducing inputs (``z (M, d)`` when null), in ``fit_form``; ``exact_subset``,
    :func:`~.fitting.fit_hyperparameters` on the exact evidence of the subset (no inducing inputs).

    Returns ``(Z, θ1, ℓ (d,), σ², objective-per-point history)`` for the float64 conditioning on all points: ``Z``
    is ``z`` unless ``optimize_inducing`` moved it, ``ℓ`` float64.
    """
    sp = cfg.sparse
    x, r = ts.x, ts.r
    if sp.fit_subset is not None:
        keep = seeded_subset(x.shape[0], sp.fit_subset, seed, x.device)
        x, r = x[keep], r[keep]
    dtype = getattr(torch, sp.fit_dtype)
    if sp.fit_objective == "exact_subset":
        outputscale, lengthscale, noise, history = fit_hyperparameters(
            x.to(dtype), r.to(dtype), ts.outputscale, ts.lengthscale.to(dtype), ts.noise, ard=cfg.ard,
            iterations=sp.iterations, lr=cfg.fit_lr, progress=progress, optimizer=sp.optimizer)
        return z, outputscale, lengthscale.to(torch.float64), noise, history
    z_fit = z if sp.fit_inducing is None else kmeans(ts.x, sp.fit_inducing, iterations=kmeans_iterations, seed=seed)
    z_fitted, outputscale, lengthscale, noise, history = fit_sgpr(
        x.to(dtype), r.to(dtype), z_fit.to(dtype), ts.outputscale, ts.lengthscale.to(dtype), ts.noise,
        optimize_inducing=sp.optimize_inducing, fit_hyper=cfg.fit_hyperparameters, ard=cfg.ard,
        iterations=sp.iterations, lr=cfg.fit_lr, progress=progress, optimizer=sp.optimizer,
        gram=sp.fit_form == "gram")
    z = z_fitted.to(z) if sp.optimize_inducing else z
    return z, outputscale, lengthscale.to(torch.float64), noise, history


class SparseGP(CachedGP):
    """Inducing-point GP; plain-torch prediction from the cached ``w`` and ``P`` (see the module docstring).

    Build with :meth:`from_data`. Buffers (move with ``.to()``): ``z`` (mapped inducing inputs), ``w``, ``p`` and the
    hyperparameters of :class:`~.gp_base.CachedGP`; derived (not saved): ``p_factor``, the float32 factor of the
    variance (:func:`variance_factor`), ``None`` when the variance is computed in float64.
    """

    kind = "sparse"

    def __init__(self, inputs: InputMap, z: Tensor, w: Tensor, p: Tensor, y_mean: float | Tensor,
                 outputscale: float | Tensor, lengthscale: Tensor, noise: float | Tensor, *,
                 config: dict | None = None):
        m, d = z.shape
        if d != inputs.dim or w.shape != (m,) or p.shape != (m, m) or lengthscale.shape != (d,):
            raise ValueError(f"inconsistent SGPR state: z {tuple(z.shape)}, w {tuple(w.shape)}, p {tuple(p.shape)}, "
                             f"lengthscale {tuple(lengthscale.shape)}, input dim {inputs.dim}")
        super().__init__(inputs, y_mean=y_mean, outputscale=outputscale, lengthscale=lengthscale, noise=noise,
                         config=config, device=z.device)
        f64 = {"dtype": torch.float64, "device": z.device}
        self.register_buffer("z", z.to(**f64))
        self.register_buffer("w", w.to(**f64))
        self.register_buffer("p", p.to(**f64))
        # derived prediction buffers (not saved): the scaled inducing inputs as exp_neg_sqdist needs them, θ1 w and
        # θ1² P, so that e = exp(−‖xs − zs‖²) = k*u / θ1 gives the mean e·(θ1 w) and the quadratic form eᵀ(θ1² P)e
        self.register_buffer("zs_cache", cross_kernel_cache(scaled(self.z, self.lengthscale)), persistent=False)
        self.register_buffer("w_scaled", self.w * self.outputscale, persistent=False)
        self.register_buffer("p_scaled", self.p * self.outputscale**2, persistent=False)
        e_z = exp_neg_sqdist(scaled(self.z[:VARIANCE_CHECK_POINTS], self.lengthscale), self.zs_cache)
        self.register_buffer("p_factor", variance_factor(self.p_scaled, e_z, self.outputscale), persistent=False)

    @classmethod
    def from_data(cls, q: Tensor, m_past: Tensor, y: Tensor, cfg: Any, *, seed: int = 0,
                  init: str = "kmeans", kmeans_iterations: int = 10, inducing_points: Tensor | None = None,
                  jitter: float = 1e-8, device: torch.device | str | None = None,
                  progress: bool = False) -> SparseGP:
        """Fit the SGPR model to ``q (N, 4)``, ``m_past (N,)``, ``y (N,)`` (float64 on ``device``).

        ``cfg`` is a :class:`~lightcurve_gp.config.load.ModelConfig` of kind ``sparse``. ``inducing_points`` (mapped
        inputs ``(M, d)``) overrides the ``init`` (``"kmeans"`` or ``"random"``) of ``cfg.sparse.num_inducing``
        points. ``fit_history`` holds the fit's objective per point (the bound, or the subset's evidence) during
        optimisation; ``progress`` shows a bar.
        """
        ts = GPTrainingSet.prepare(q, m_past, y, cfg, device)
        x, r, sp = ts.x, ts.r, cfg.sparse
        z = _initial_inducing(x, sp.num_inducing, init, seed, kmeans_iterations, inducing_points)
        outputscale, lengthscale, noise = ts.outputscale, ts.lengthscale, ts.noise
        history: list[float] = []
        if (sp.optimize_inducing or cfg.fit_hyperparameters) and sp.iterations > 0:
            z, outputscale, lengthscale, noise, history = _fit(ts, z, cfg, seed=seed,
                                                               kmeans_iterations=kmeans_iterations, progress=progress)
        w, p = sgpr_cache(x, r, z, outputscale, lengthscale, noise, jitter=jitter)
        model = cls(ts.inputs, z, w, p, ts.y_mean, outputscale, lengthscale, noise, config=config_to_dict(cfg))
        model.fit_history = history
        return model

    @property
    def num_inducing(self) -> int:
        return self.z.shape[0]

    def _reference_count(self) -> int:
        return self.z.shape[0]

    def _predict_sets(self, xs_sets: Tensor, variance: Variance) -> Prediction:
        """Mean and variance (module docstring) of scaled test points ``(P, 1, d)``."""
        e = exp_neg_sqdist(xs_sets.reshape(-1, xs_sets.shape[-1]), self.zs_cache)  # k*u / θ1 (P, M)
        mean = torch.mv(e, self.w_scaled).add_(self.y_mean)
        if variance == "none":
            return mean, None
        if self.p_factor is None:
            quad = (torch.mm(e, self.p_scaled).mul_(e)).sum(-1)
        else:
            y = torch.mm(e.to(self.p_factor.dtype), self.p_factor)
            quad = y.mul_(y).sum(-1).to(e.dtype)
        return mean, quad.neg_().add_(self.outputscale).clamp_min_(0.0)

    def _cache_state(self) -> dict[str, Any]:
        return {"z": cpu64(self.z), "w": cpu64(self.w), "p": cpu64(self.p)}

    @classmethod
    def from_file_state(cls, inputs: InputMap, state: dict[str, Any], config: dict) -> SparseGP:
        """Rebuild from :meth:`file_state` (files written before the variance became a per-call choice also
        carry a ``with_variance``, which is ignored)."""
        return cls(inputs, state["z"], state["w"], state["p"], **cls._hyperparameters(state), config=config)
