"""Inducing-point GP observation model: SGPR with Titsias' collapsed bound (paper section 3.2).

Same kernel, noise and centred outputs as :class:`~.exact_gp.ExactGP`. ``M = model.num_inducing`` inducing inputs
``Z`` are initialised from the mapped training inputs by k-means (a few seeded Lloyd iterations) or a seeded random
subset, and optionally optimised (``model.optimize_inducing``) for ``model.sparse_iterations`` Adam steps on the
collapsed bound — GPyTorch's ``InducingPointKernel`` under ``ExactMarginalLogLikelihood`` (its added loss term is
the bound's trace term). Kernel hyperparameters stay the paper's unless ``model.fit_hyperparameters``.

Prediction is plain torch on a cache computed once (float64, Cholesky forms; ``L_uu L_uuᵀ = K_uu``,
``A = L_uu⁻¹ K_uf / σ``, ``B = I + A Aᵀ = L_B L_Bᵀ``, so that ``Λ = K_uu + σ⁻² K_uf K_fu = L_uu B L_uuᵀ``):

* mean ``μ + k_*uᵀ w``, ``w = σ⁻² Λ⁻¹ K_uf (y − μ) = L_uu⁻ᵀ L_B⁻ᵀ L_B⁻¹ A (y − μ) / σ``;
* variance ``k** − k_*uᵀ P k_*u``, ``P = K_uu⁻¹ − Λ⁻¹ = WᵀW − VᵀV`` with ``W = L_uu⁻¹``, ``V = L_B⁻¹ W``.
"""

from __future__ import annotations

import warnings
from typing import Any

import torch
from torch import Tensor

from ..config import ModelConfig, config_to_dict
from .base import ObservationModel, Prediction
from .exact_gp import (
    _check_training,
    _hyper_start,
    _scaled,
    _subset,
    cross_kernel_cache,
    exp_neg_sqdist,
    kernel_matrix,
    maximise_mll,
)
from .inputs import InputMap

__all__ = ["SparseGP", "kmeans", "sgpr_cache"]

_JITTERS = (1e-10, 1e-8, 1e-6, 1e-4)


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
    centres = distinct[_subset(n, m, seed, x.device)].clone()
    for _ in range(iterations):
        d2 = (centres * centres).sum(-1) - 2.0 * x @ centres.T  # ‖x‖² is the same for every centre
        assign = d2.argmin(dim=1)
        sums = torch.zeros_like(centres).index_add_(0, assign, x)
        counts = torch.bincount(assign, minlength=m)
        filled = counts > 0
        centres[filled] = sums[filled] / counts[filled].unsqueeze(-1).to(x.dtype)
    return centres


def _chol_jitter(mat: Tensor, scale: float, what: str) -> Tensor:
    """Cholesky of ``mat`` with growing diagonal jitter (relative to ``scale``) on failure, with a warning."""
    eye = torch.eye(mat.shape[-1], dtype=mat.dtype, device=mat.device)
    for jitter in (0.0, *_JITTERS):
        chol, info = torch.linalg.cholesky_ex(mat + (jitter * scale) * eye if jitter else mat)
        if int(info) == 0:
            if jitter:
                warnings.warn(f"Cholesky of {what} needed jitter {jitter:g}*theta1", RuntimeWarning, stacklevel=3)
            return chol
    raise RuntimeError(f"Cholesky of {what} failed even with jitter {_JITTERS[-1]:g}*theta1")


def sgpr_cache(x: Tensor, r: Tensor, z: Tensor, outputscale: float, lengthscale: Tensor, noise: float,
               *, jitter: float = 1e-8) -> tuple[Tensor, Tensor]:
    """SGPR prediction cache ``(w (M,), P (M, M))`` for mapped inputs ``x (N, d)``, centred outputs ``r (N,)``
    and inducing inputs ``z (M, d)`` (float64 recommended). ``K_uu`` gets ``jitter·θ1`` on its diagonal."""
    xs, zs = _scaled(x, lengthscale), _scaled(z, lengthscale)
    m = z.shape[0]
    kuu = kernel_matrix(zs, zs, outputscale)
    kuu.diagonal().add_(jitter * outputscale)
    luu = _chol_jitter(kuu, outputscale, f"the {m}x{m} inducing kernel")
    sigma = noise**0.5
    a = torch.linalg.solve_triangular(luu, kernel_matrix(zs, xs, outputscale), upper=False).div_(sigma)  # (M, N)
    b = torch.addmm(torch.eye(m, dtype=x.dtype, device=x.device), a, a.T)
    lb = _chol_jitter(b, 1.0, f"the {m}x{m} SGPR matrix B")
    c = torch.linalg.solve_triangular(lb, (a @ r).div_(sigma).unsqueeze(-1), upper=False)
    w = torch.linalg.solve_triangular(luu.T, torch.linalg.solve_triangular(lb.T, c, upper=True), upper=True)
    winv = torch.linalg.solve_triangular(luu, torch.eye(m, dtype=x.dtype, device=x.device), upper=False)
    v = torch.linalg.solve_triangular(lb, winv, upper=False)
    p = winv.T @ winv - v.T @ v
    return w.squeeze(-1), 0.5 * (p + p.T)


def _optimise_sgpr(x: Tensor, r: Tensor, z: Tensor, outputscale: float, lengthscale: Tensor, noise: float, *,
                   optimize_inducing: bool, fit_hyper: bool, ard: bool, iterations: int, lr: float,
                   progress: bool = False) -> tuple[Tensor, float, Tensor, float, list[float]]:
    """Adam on GPyTorch's collapsed SGPR bound; returns ``(Z, θ1, ℓ (d,), σ², bound-per-point history)``."""
    import gpytorch

    dim = x.shape[-1]
    likelihood = gpytorch.likelihoods.GaussianLikelihood(
        noise_constraint=gpytorch.constraints.GreaterThan(1e-8)).to(x)

    class _SGPR(gpytorch.models.ExactGP):
        def __init__(self):
            super().__init__(x, r, likelihood)
            self.mean_module = gpytorch.means.ZeroMean()
            self.base_covar = gpytorch.kernels.ScaleKernel(
                gpytorch.kernels.RBFKernel(ard_num_dims=dim if ard else None))
            self.covar_module = gpytorch.kernels.InducingPointKernel(
                self.base_covar, inducing_points=z.clone(), likelihood=likelihood)

        def forward(self, xx):
            return gpytorch.distributions.MultivariateNormal(self.mean_module(xx), self.covar_module(xx))

    model = _SGPR().to(x)
    likelihood.noise = torch.as_tensor(noise, dtype=x.dtype)
    model.base_covar.outputscale = torch.as_tensor(outputscale, dtype=x.dtype)
    ls = lengthscale.to(x)
    model.base_covar.base_kernel.lengthscale = ls if ard else ls[:1]
    params = []
    if optimize_inducing:
        params.append(model.covar_module.inducing_points)
    if fit_hyper:
        params += list(model.base_covar.parameters()) + list(likelihood.parameters())
    history: list[float] = []
    if params and iterations > 0:
        history = maximise_mll(model, likelihood, x, r, params, iterations=iterations, lr=lr, progress=progress,
                               desc="SGPR bound")
    ls_out = model.base_covar.base_kernel.lengthscale.detach().reshape(-1).expand(dim).clone()
    return (model.covar_module.inducing_points.detach().clone(), float(model.base_covar.outputscale.detach()), ls_out,
            float(likelihood.noise.detach()), history)


class SparseGP(ObservationModel):
    """Inducing-point GP; plain-torch prediction from the cached ``w`` and ``P`` (see the module docstring).

    Build with :meth:`from_data`. Buffers (move with ``.to()``): ``z`` (mapped inducing inputs), ``w``, ``p``,
    ``lengthscale (d,)``, ``outputscale``, ``noise`` (variance), ``y_mean``.
    """

    kind = "sparse"
    #: largest kernel block ``(points × M)`` computed at once by a prediction (8 MB in float64)
    chunk_values: int = 1 << 20

    def __init__(self, inputs: InputMap, z: Tensor, w: Tensor, p: Tensor, y_mean: float | Tensor,
                 outputscale: float | Tensor, lengthscale: Tensor, noise: float | Tensor, *,
                 config: dict | None = None, with_variance: bool = True):
        super().__init__()
        m, d = z.shape
        if d != inputs.dim or w.shape != (m,) or p.shape != (m, m) or lengthscale.shape != (d,):
            raise ValueError(f"inconsistent SGPR state: z {tuple(z.shape)}, w {tuple(w.shape)}, p {tuple(p.shape)}, "
                             f"lengthscale {tuple(lengthscale.shape)}, input dim {inputs.dim}")
        self.inputs = inputs
        self.config = dict(config or {})
        #: ``False`` for ``model.variance = none`` (mean only, variance returned as ``None``)
        self.variance_enabled = bool(with_variance)
        f64 = dict(dtype=torch.float64, device=z.device)
        self.register_buffer("z", z.to(**f64))
        self.register_buffer("w", w.to(**f64))
        self.register_buffer("p", p.to(**f64))
        self.register_buffer("y_mean", torch.as_tensor(y_mean, **f64))
        self.register_buffer("outputscale", torch.as_tensor(outputscale, **f64))
        self.register_buffer("lengthscale", lengthscale.to(**f64))
        self.register_buffer("noise", torch.as_tensor(noise, **f64))
        # derived prediction buffers (not saved): the scaled inducing inputs as exp_neg_sqdist needs them, θ1 w and
        # θ1² P, so that e = exp(−‖xs − zs‖²) = k*u / θ1 gives the mean e·(θ1 w) and the quadratic form eᵀ(θ1² P)e
        zs = _scaled(self.z, self.lengthscale)
        zs_t2, zs_sq_neg = cross_kernel_cache(zs)
        self.register_buffer("zs_t2", zs_t2, persistent=False)
        self.register_buffer("zs_sq_neg", zs_sq_neg, persistent=False)
        self.register_buffer("w_scaled", self.w * self.outputscale, persistent=False)
        self.register_buffer("p_scaled", self.p * self.outputscale**2, persistent=False)

    @classmethod
    def from_data(cls, q: Tensor, m_past: Tensor, y: Tensor, cfg: ModelConfig, *, seed: int = 0,
                  init: str = "kmeans", kmeans_iterations: int = 10, inducing_points: Tensor | None = None,
                  jitter: float = 1e-8, device: torch.device | str | None = None,
                  progress: bool = False) -> "SparseGP":
        """Fit the SGPR model to ``q (N, 4)``, ``m_past (N,)``, ``y (N,)`` (float64 on ``device``).

        ``inducing_points`` (mapped inputs ``(M, d)``) overrides the ``init`` (``"kmeans"`` or ``"random"``)
        of ``cfg.num_inducing`` points. ``fit_history`` holds the collapsed bound per point during optimisation;
        ``progress`` shows a bar meanwhile.
        """
        device = torch.device(device) if device is not None else q.device
        f64 = dict(dtype=torch.float64, device=device)
        q, m_past, y = q.to(**f64), m_past.to(**f64), y.to(**f64)
        _check_training(q, m_past, y)
        inputs = InputMap(cfg.inputs, cfg.standardize_inputs).to(device)
        x = inputs.fit(q, m_past)
        y_mean = y.mean()
        r = y - y_mean
        if inducing_points is not None:
            z = inducing_points.to(**f64)
            if z.ndim != 2 or z.shape[1] != x.shape[1]:
                raise ValueError(f"inducing_points must be (M, {x.shape[1]}), got {tuple(z.shape)}")
        elif init == "kmeans":
            z = kmeans(x, cfg.num_inducing, iterations=kmeans_iterations, seed=seed)
        elif init == "random":
            z = x[_subset(x.shape[0], cfg.num_inducing, seed, device)].clone()
        else:
            raise ValueError(f"init must be kmeans or random, got {init!r}")
        outputscale, lengthscale, noise = _hyper_start(cfg, x.shape[-1])
        lengthscale = lengthscale.to(device)
        history: list[float] = []
        if (cfg.optimize_inducing or cfg.fit_hyperparameters) and cfg.sparse_iterations > 0:
            z, outputscale, lengthscale, noise, history = _optimise_sgpr(
                x, r, z, outputscale, lengthscale, noise, optimize_inducing=cfg.optimize_inducing,
                fit_hyper=cfg.fit_hyperparameters, ard=cfg.ard, iterations=cfg.sparse_iterations, lr=cfg.fit_lr,
                progress=progress)
        w, p = sgpr_cache(x, r, z, outputscale, lengthscale, noise, jitter=jitter)
        model = cls(inputs, z, w, p, y_mean, outputscale, lengthscale, noise, config=config_to_dict(cfg),
                    with_variance=cfg.variance != "none")
        model.fit_history = history
        return model

    @property
    def num_inducing(self) -> int:
        return self.z.shape[0]

    def _predict(self, q: Tensor, m_past: Tensor, with_variance: bool) -> Prediction:
        """Mean and variance (module docstring) in chunks of at most :attr:`chunk_values` kernel values."""
        batch = q.shape[:-1]
        dt = self.w.dtype
        x = self.inputs(q.to(dt), m_past.to(dt)).reshape(-1, self.inputs.dim)
        xs = _scaled(x, self.lengthscale)
        want_var = with_variance and self.variance_enabled
        rows = max(1, self.chunk_values // self.num_inducing)
        means, variances = [], []
        for start in range(0, xs.shape[0], rows):
            e = exp_neg_sqdist(xs[start:start + rows], self.zs_t2, self.zs_sq_neg)  # k*u / θ1 (P, M)
            means.append(torch.mv(e, self.w_scaled))
            if want_var:
                quad = (torch.mm(e, self.p_scaled).mul_(e)).sum(-1)
                variances.append(quad.neg_().add_(self.outputscale).clamp_min_(0.0))
        mean = (means[0] if len(means) == 1 else torch.cat(means)).add_(self.y_mean).reshape(batch)
        if not want_var:
            return mean, None
        return mean, (variances[0] if len(variances) == 1 else torch.cat(variances)).reshape(batch)

    def file_state(self) -> dict[str, Any]:
        """Plain tensors/python values for :func:`lightcurve_gp.observation.serialization.save_model`."""
        cpu64 = lambda t: t.detach().to("cpu", torch.float64).clone()  # noqa: E731
        return {"z": cpu64(self.z), "w": cpu64(self.w), "p": cpu64(self.p), "y_mean": float(self.y_mean),
                "outputscale": float(self.outputscale), "lengthscale": cpu64(self.lengthscale),
                "noise": float(self.noise), "with_variance": self.variance_enabled}

    @classmethod
    def from_file_state(cls, inputs: InputMap, state: dict[str, Any], config: dict) -> "SparseGP":
        return cls(inputs, state["z"], state["w"], state["p"], state["y_mean"], state["outputscale"],
                   state["lengthscale"], state["noise"], config=config, with_variance=state["with_variance"])
