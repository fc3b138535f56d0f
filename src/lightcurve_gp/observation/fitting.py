"""Hyperparameter fitting of the GP observation models with GPyTorch (paper section 3.2).

The exact GP maximises its log marginal likelihood (the evidence) on a seeded subset of the training points; the
inducing-point GP maximises Titsias' collapsed bound — GPyTorch's ``InducingPointKernel`` under
``ExactMarginalLogLikelihood`` (its added loss term is the bound's trace term) — over its inducing inputs and/or
hyperparameters. With fixed inducing inputs and one shared lengthscale the same bound can be computed from the Gram
matrix ``K_uf K_fu`` (:func:`gram_bound`): one ``M × N × M`` product forward and one backward, the rest ``M × M``
algebra — about half the arithmetic of GPyTorch's form, whose ``L⁻¹ K_uf`` solve and ``A Aᵀ`` product both scale as
``M²N``. It needs float64: ``K_uu + K_uf K_fu/σ²``
adds a matrix of entries up to ``N θ1²/σ²`` to one whose small eigenvalues carry the bound, and float32 rounding of
the first (about 1e-7 of each entry) already makes the sum indefinite on the robust config's data.
Both run :func:`maximise_mll` (Adam, or L-BFGS for the sparse GP's ``model.sparse.optimizer``)
with a progress bar. GPyTorch is used for fitting only; predictions are plain torch on cached tensors
(:mod:`.exact_gp`, :mod:`.sparse_gp`). That is why ``gpytorch`` (and tqdm) are imported inside the functions that
fit: a command that only loads a trained model, simulates or filters never pays gpytorch's import (0.3–0.8 s).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from lightcurve_gp.observation.kernels import theta2_to_lengthscale

__all__ = [
    "fit_hyperparameters",
    "fit_sgpr",
    "gpytorch_exact_model",
    "gpytorch_sgpr_model",
    "gram_bound",
    "hyper_start",
    "inducing_sqdist",
    "maximise_mll",
    "seeded_subset",
    "sgpr_bound",
]


def hyper_start(cfg: Any, dim: int) -> tuple[float, Tensor, float]:
    """The paper's ``(θ1, ℓ (dim,), σ²)`` of a model config section (float64, CPU)."""
    return cfg.theta1, torch.full((dim,), theta2_to_lengthscale(cfg.theta2), dtype=torch.float64), cfg.noise_std**2


def seeded_subset(n: int, size: int, seed: int, device: torch.device) -> Tensor:
    """A seeded random subset of ``min(size, n)`` indices (all of them, in order, when ``size ≥ n``)."""
    if size >= n:
        return torch.arange(n, device=device)
    gen = torch.Generator().manual_seed(seed)
    return torch.randperm(n, generator=gen)[:size].to(device)


def _rbf(dim: int, ard: bool):
    import gpytorch

    return gpytorch.kernels.ScaleKernel(gpytorch.kernels.RBFKernel(ard_num_dims=dim if ard else None))


def _set_hyperparameters(scale_kernel, likelihood, x: Tensor, outputscale: float, lengthscale: Tensor | float,
                         noise: float, ard: bool) -> None:
    likelihood.noise = torch.as_tensor(noise, dtype=x.dtype)
    scale_kernel.outputscale = torch.as_tensor(outputscale, dtype=x.dtype)
    ls = torch.as_tensor(lengthscale, dtype=x.dtype, device=x.device)
    if not ard and ls.numel() > 1 and not bool((ls == ls.reshape(-1)[0]).all()):
        raise ValueError("a shared (non-ARD) lengthscale needs equal per-dimension start values")
    scale_kernel.base_kernel.lengthscale = ls.expand(x.shape[-1]) if ard else ls.reshape(-1)[:1]


def _exact_gp_class():
    import gpytorch

    class _Model(gpytorch.models.ExactGP):
        def __init__(self, train_x, train_y, likelihood, covar_module):
            super().__init__(train_x, train_y, likelihood)
            self.mean_module = gpytorch.means.ZeroMean()
            self.covar_module = covar_module

        def forward(self, xx):
            return gpytorch.distributions.MultivariateNormal(self.mean_module(xx), self.covar_module(xx))

    return _Model


def _likelihood(x: Tensor):
    import gpytorch

    return gpytorch.likelihoods.GaussianLikelihood(noise_constraint=gpytorch.constraints.GreaterThan(1e-8)).to(x)


def gpytorch_exact_model(x: Tensor, y_centred: Tensor, outputscale: float, lengthscale: Tensor | float,
                         noise: float, ard: bool = False):
    """The equivalent GPyTorch exact GP ``(model, likelihood)`` (zero mean on centred outputs) for mapped inputs
    ``x (N, d)``. Used for marginal-likelihood fitting and to check the kernel mapping; never on the prediction
    path."""
    likelihood = _likelihood(x)
    model = _exact_gp_class()(x, y_centred, likelihood, _rbf(x.shape[-1], ard)).to(x)
    _set_hyperparameters(model.covar_module, likelihood, x, outputscale, lengthscale, noise, ard)
    return model, likelihood


def gpytorch_sgpr_model(x: Tensor, r: Tensor, z: Tensor, outputscale: float, lengthscale: Tensor, noise: float,
                        ard: bool):
    """GPyTorch's SGPR ``(model, likelihood)``: an exact GP whose kernel is an ``InducingPointKernel`` on the
    inducing inputs ``z (M, d)`` (its marginal likelihood is the collapsed bound); ``model.base_covar`` holds
    ``θ1`` and ``ℓ``."""
    import gpytorch

    likelihood = _likelihood(x)
    base = _rbf(x.shape[-1], ard)
    covar = gpytorch.kernels.InducingPointKernel(base, inducing_points=z.clone(), likelihood=likelihood)
    model = _exact_gp_class()(x, r, likelihood, covar).to(x)
    model.base_covar = base
    _set_hyperparameters(base, likelihood, x, outputscale, lengthscale.to(x), noise, ard)
    return model, likelihood


class _RbfGram(torch.autograd.Function):
    """``(E Eᵀ (M, M), E r (M,))`` of ``E = exp(−D / (2ℓ²))`` for fixed squared distances ``D (M, N)``, constant
    ``r (N,)`` and one shared lengthscale ``ℓ`` (0-d), built over blocks of :data:`GRAM_BLOCK` columns: ``E`` is never
    stored whole (each block is taken again in the backward, ``∂/∂ℓ = Σ Ē ⊙ E ⊙ D / ℓ³`` with
    ``Ē = (Ḡ + Ḡᵀ) E + b̄ rᵀ``), so no ``M × N`` temporary is allocated per evaluation."""

    @staticmethod
    def forward(sqdist: Tensor, lengthscale: Tensor, r: Tensor) -> tuple[Tensor, Tensor]:
        m, n = sqdist.shape
        c = -0.5 / lengthscale**2
        gram, b = sqdist.new_zeros(m, m), sqdist.new_zeros(m)
        for j in range(0, n, GRAM_BLOCK):
            e = torch.exp(sqdist[:, j:j + GRAM_BLOCK] * c)
            gram.addmm_(e, e.T)
            b.addmv_(e, r[j:j + GRAM_BLOCK])
        return gram, b

    @staticmethod
    def setup_context(ctx, inputs, output) -> None:
        ctx.save_for_backward(*inputs)

    @staticmethod
    def backward(ctx, grad_gram: Tensor | None, grad_b: Tensor | None) -> tuple[None, Tensor, None]:
        sqdist, lengthscale, r = ctx.saved_tensors
        m, n = sqdist.shape
        c = -0.5 / lengthscale**2
        sym = grad_gram + grad_gram.T if grad_gram is not None else sqdist.new_zeros(m, m)
        total = sqdist.new_zeros(())
        for j in range(0, n, GRAM_BLOCK):
            d = sqdist[:, j:j + GRAM_BLOCK]
            e = torch.exp(d * c)
            e_bar = sym @ e
            if grad_b is not None:
                e_bar.addr_(grad_b, r[j:j + GRAM_BLOCK])
            total += e_bar.mul_(e).mul_(d).sum()
        return None, total / lengthscale**3, None


#: columns per block of :class:`_RbfGram` (1500 × 2048 float64 is 24 MB, under glibc's largest mmap threshold, so
#: the blocks' memory is reused between evaluations instead of mapped and faulted in anew)
GRAM_BLOCK = 2048


def inducing_sqdist(x: Tensor, z: Tensor) -> Tensor:
    """Squared distances ``‖z_i − x_j‖²`` ``(M, N)`` of inducing inputs ``z (M, d)`` and inputs ``x (N, d)``
    (unscaled: :func:`gram_bound` divides by one shared ``2ℓ²``)."""
    return ((z * z).sum(-1)[:, None] + (x * x).sum(-1)[None, :] - 2.0 * z @ x.T).clamp_min_(0.0)


def gram_bound(x: Tensor, r: Tensor, z: Tensor, outputscale: Tensor, lengthscale: Tensor, noise: Tensor, *,
               sqdist: Tensor | None = None) -> Tensor:
    """Titsias' collapsed bound per point (nats), differentiable in ``outputscale`` (θ1), one shared ``lengthscale``
    (ℓ, one element) and ``noise`` (σ²), of centred outputs ``r (N,)`` at mapped inputs ``x (N, d)`` with fixed
    inducing inputs ``z (M, d)``, all float64:

    ``log N(r; 0, Q + σ²I) − tr(K − Q) / (2σ²)`` over ``N``, with ``Q = K_fu K_uu⁻¹ K_uf``, from ``G = K_uf K_fu``,
    ``b = K_uf r`` and ``B = K_uu + G/σ²``: ``log|Q + σ²I| = log|B| − log|K_uu| + N log σ²``,
    ``rᵀ(Q + σ²I)⁻¹r = rᵀr/σ² − bᵀB⁻¹b/σ⁴``, ``tr Q = tr(K_uu⁻¹ G)``. Equal to :func:`sgpr_bound` (GPyTorch's form)
    to rounding. ``G`` and ``b`` are built in column blocks from the squared distances ``sqdist``
    (:func:`inducing_sqdist`, computed here when not given; a fit computes them once), never a whole ``M × N``
    array (:class:`_RbfGram`)."""
    if x.dtype != torch.float64:
        raise ValueError(f"gram_bound needs float64 inputs (module docstring), got {x.dtype}")
    if lengthscale.numel() != 1:
        raise ValueError(f"gram_bound needs one shared lengthscale, got {lengthscale.numel()}")
    n = x.shape[0]
    ell = lengthscale.reshape(())
    sqdist = inducing_sqdist(x, z) if sqdist is None else sqdist
    k_uu = outputscale * torch.exp(inducing_sqdist(z, z) * (-0.5 / ell**2))
    gram_e, b_e = _RbfGram.apply(sqdist, ell, r)  # K_uf K_fu / θ1², K_uf r / θ1
    gram, b = outputscale**2 * gram_e, outputscale * b_e
    chol_uu, info_uu = torch.linalg.cholesky_ex(k_uu)
    chol_b, info_b = torch.linalg.cholesky_ex(k_uu + gram / noise)
    if int(info_uu) or int(info_b):
        which = "K_uu" if int(info_uu) else "K_uu + K_uf K_fu / sigma^2"
        raise ValueError(f"model.sparse.fit_form: gram: {which} is not positive definite at theta1 "
                         f"{float(outputscale.detach()):.4g}, sigma^2 {float(noise.detach()):.4g}; fit_form gpytorch "
                         "adds a jitter where this form cannot")
    logdet = 2.0 * (torch.log(torch.diagonal(chol_b)).sum() - torch.log(torch.diagonal(chol_uu)).sum()) \
        + n * torch.log(noise)
    quad = (r @ r) / noise - (b @ torch.cholesky_solve(b[:, None], chol_b)[:, 0]) / noise**2
    trace_q = torch.cholesky_solve(gram, chol_uu).diagonal().sum()
    return -0.5 * (logdet + quad + n * math.log(2.0 * math.pi) + (n * outputscale - trace_q) / noise) / n


def maximise_mll(model, likelihood, x: Tensor, y: Tensor, params: list, *, iterations: int, lr: float,
                 progress: bool = False, desc: str = "GP hyperparameters", optimizer: str = "adam",
                 objective: Callable[[], Tensor] | None = None) -> list[float]:
    """Maximise the ``ExactMarginalLogLikelihood`` of a GPyTorch ``ExactGP`` model (exact Cholesky, any size) over
    ``params`` — the exact evidence, or the collapsed SGPR bound when the model's kernel is an
    ``InducingPointKernel``.

    ``optimizer="adam"``: ``iterations`` Adam steps of learning rate ``lr``. ``optimizer="lbfgs"``: L-BFGS with a
    strong-Wolfe line search and at most ``iterations`` objective evaluations (``lr`` unused); it stops earlier when
    the gradient or the change of the objective vanishes. Returns the objective per point at each evaluation and
    after the last step (``iterations + 1`` values for Adam, at most that for L-BFGS); ``progress`` shows a bar
    with the current value. ``objective``, when given, is maximised instead of GPyTorch's
    ``ExactMarginalLogLikelihood`` (the same bound in another form, :func:`gram_bound`, over the same parameters)."""
    import gpytorch
    from tqdm.auto import tqdm

    if optimizer not in ("adam", "lbfgs"):
        raise ValueError(f"optimizer must be adam or lbfgs, got {optimizer!r}")
    model.train()
    likelihood.train()
    if objective is None:
        mll = gpytorch.mlls.ExactMarginalLogLikelihood(likelihood, model)
        objective = lambda: mll(model(x), y)  # noqa: E731
    history: list[float] = []
    with gpytorch.settings.max_cholesky_size(10**9), tqdm(total=iterations, desc=desc, disable=not progress,
                                                          leave=False) as bar:
        steps = _adam_steps if optimizer == "adam" else _lbfgs_steps
        steps(lambda: -objective(), params, iterations=iterations, lr=lr, history=history, bar=bar)
        with torch.no_grad():
            history.append(float(objective()))
    return history


def _adam_steps(loss_fn, params: list, *, iterations: int, lr: float, history: list[float], bar) -> None:
    """``iterations`` Adam steps on ``loss_fn()`` (the negative objective), recording the objective before each."""
    opt = torch.optim.Adam(params, lr=lr)
    for _ in range(iterations):
        opt.zero_grad()
        loss = loss_fn()
        history.append(-loss.item())
        loss.backward()
        opt.step()
        bar.set_postfix(objective=f"{history[-1]:.4f}", refresh=False)
        bar.update()


def _lbfgs_steps(loss_fn, params: list, *, iterations: int, lr: float, history: list[float], bar) -> None:
    """L-BFGS (strong-Wolfe line search, unit initial step) on ``loss_fn()`` with at most ``iterations``
    evaluations, recording the objective at each; ``lr`` is not used."""
    opt = torch.optim.LBFGS(params, lr=1.0, max_iter=iterations, max_eval=iterations, history_size=10,
                            line_search_fn="strong_wolfe")

    def closure() -> Tensor:
        opt.zero_grad()
        loss = loss_fn()
        history.append(-loss.item())
        loss.backward()
        bar.set_postfix(objective=f"{history[-1]:.4f}", refresh=False)
        bar.update()
        return loss

    if iterations > 0:
        opt.step(closure)


def _fitted_lengthscale(scale_kernel, dim: int) -> Tensor:
    return scale_kernel.base_kernel.lengthscale.detach().reshape(-1).expand(dim).clone()


def fit_hyperparameters(x: Tensor, y_centred: Tensor, outputscale: float, lengthscale: Tensor | float, noise: float,
                        *, ard: bool, iterations: int, lr: float, progress: bool = False,
                        optimizer: str = "adam") -> tuple[float, Tensor, float, list[float]]:
    """Maximise the exact log marginal likelihood (GPyTorch, exact Cholesky, :func:`maximise_mll` with
    ``optimizer``) of ``y_centred (N,)`` at ``x (N, d)`` from the given start, in the dtype of ``x``.

    Returns ``(θ1, ℓ (d,), σ², mll per point history)``; the history has ``iterations + 1`` entries for Adam
    (before each step and after the last), at most that for L-BFGS.
    """
    model, likelihood = gpytorch_exact_model(x, y_centred, outputscale, lengthscale, noise, ard)
    history = maximise_mll(model, likelihood, x, y_centred, list(model.parameters()), iterations=iterations, lr=lr,
                           progress=progress, desc="exact GP hyperparameters", optimizer=optimizer)
    return (float(model.covar_module.outputscale.detach()), _fitted_lengthscale(model.covar_module, x.shape[-1]),
            float(likelihood.noise.detach()), history)


def fit_sgpr(x: Tensor, r: Tensor, z: Tensor, outputscale: float, lengthscale: Tensor, noise: float, *,
             optimize_inducing: bool, fit_hyper: bool, ard: bool, iterations: int, lr: float,
             progress: bool = False, optimizer: str = "adam",
             gram: bool = False) -> tuple[Tensor, float, Tensor, float, list[float]]:
    """Maximise GPyTorch's collapsed SGPR bound (:func:`maximise_mll` with ``optimizer``) over the inducing inputs
    ``z (M, d)`` (``optimize_inducing``) and/or ``(θ1, ℓ, σ²)`` (``fit_hyper``), in the dtype of ``x``; returns
    ``(Z, θ1, ℓ (d,), σ², bound-per-point history)`` (``Z`` and ``ℓ`` in that dtype).

    ``gram``: the same bound in its Gram form (:func:`gram_bound`, float64; fixed inducing inputs and one shared
    lengthscale) over the same GPyTorch parameters, so Adam takes the same steps as on GPyTorch's form, to
    rounding."""
    model, likelihood = gpytorch_sgpr_model(x, r, z, outputscale, lengthscale, noise, ard)
    params = []
    if optimize_inducing:
        params.append(model.covar_module.inducing_points)
    if fit_hyper:
        params += list(model.base_covar.parameters()) + list(likelihood.parameters())
    objective = None
    if gram:
        if optimize_inducing or ard:
            raise ValueError("the Gram form fits one shared lengthscale with fixed inducing inputs")
        base, sqdist = model.base_covar, inducing_sqdist(x, z)  # the distances once for the whole fit
        objective = lambda: gram_bound(x, r, z, base.outputscale, base.base_kernel.lengthscale,  # noqa: E731
                                       likelihood.noise.reshape(()), sqdist=sqdist)
    history: list[float] = []
    if params and iterations > 0:
        history = maximise_mll(model, likelihood, x, r, params, iterations=iterations, lr=lr, progress=progress,
                               desc="SGPR bound", optimizer=optimizer, objective=objective)
    return (model.covar_module.inducing_points.detach().clone(), float(model.base_covar.outputscale.detach()),
            _fitted_lengthscale(model.base_covar, x.shape[-1]), float(likelihood.noise.detach()), history)


def sgpr_bound(x: Tensor, r: Tensor, z: Tensor, outputscale: float, lengthscale: Tensor, noise: float, *,
               ard: bool = False) -> float:
    """Titsias' collapsed bound per point (nats) of centred outputs ``r (N,)`` at mapped inputs ``x (N, d)`` with
    inducing inputs ``z (M, d)`` and hyperparameters ``θ1``, ``ℓ (d,)``, ``σ²`` (``ard``: per-dimension ``ℓ``):
    the objective :func:`fit_sgpr` maximises, evaluated once (GPyTorch, in the dtype of ``x``) to compare fits made
    on subsets, with fewer inducing inputs or in float32 on one footing."""
    import gpytorch

    model, likelihood = gpytorch_sgpr_model(x, r, z, outputscale, lengthscale, noise, ard)
    model.train()
    likelihood.train()
    mll = gpytorch.mlls.ExactMarginalLogLikelihood(likelihood, model)
    with torch.no_grad(), gpytorch.settings.max_cholesky_size(10**9):
        return float(mll(model(x), r))
