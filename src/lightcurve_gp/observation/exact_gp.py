"""Exact GP observation model (paper sections 2.4 and 3.1–3.2).

Kernel ``k(x, x') = θ1 exp(−‖x − x'‖² / θ2)``; in GPyTorch terms ``ScaleKernel(RBFKernel)`` with outputscale ``θ1``
and lengthscale ``ℓ = √(θ2 / 2)`` (RBF is ``exp(−‖x − x'‖² / (2ℓ²))``). Likelihood noise ``σ²`` (``σ`` is
``model.noise_std``), constant mean ``μ = mean(y)`` (outputs centred).

Conditioning on all ``N`` training points is one exact float64 Cholesky of ``K + σ²I``, built and factorised in
place (peak memory ≈ one ``N × N`` matrix). Prediction is plain torch on cached tensors (``α = (K + σ²I)⁻¹(y − μ)``
and the scaled training inputs): GPyTorch's own ``model(x)`` costs milliseconds per call even when cached.

Predictive variance (of the latent function) — ``model.variance_mode``:

* ``"exact"``: ``k** − k*ᵀ (K + σ²I)⁻¹ k*`` with the full Cholesky factor (kept after fitting, recomputed lazily
  after loading; reading it costs ≳ 0.17 s per call at N = 19260).
* ``"fast"``: the same formula conditioned only on the ``fast_variance_neighbors`` training points nearest (in
  kernel-scaled distance) to the test point. The points along the last batch dimension of a ``(..., S, 4)`` input
  (a filter's sigma points) share one neighbour set when the set's diameter is within ``cluster_radius``
  lengthscales, so such a set costs one ``k × k`` Cholesky. Conditioning on a subset never lowers a GP's posterior
  variance, so the fast variance is an upper bound of the exact one (conservative for a filter);
  :func:`fast_variance_error` measures the gap.
* ``"none"``: mean only; ``variance`` is returned as ``None``.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import torch
from torch import Tensor

from ..config import ModelConfig, config_to_dict
from .base import ObservationModel, Prediction
from .inputs import InputMap

__all__ = [
    "ExactGP",
    "fast_variance_error",
    "theta2_to_lengthscale",
    "lengthscale_to_theta2",
    "gpytorch_exact_model",
    "fit_hyperparameters",
]

#: kernel exponents are clamped at −EXP_CLAMP: exp(−80) ≈ 2e−35 is numerically zero next to θ1, and float32 ``exp``
#: of arguments below about −87 takes a slow denormal path
EXP_CLAMP = 80.0
_JITTERS = (1e-10, 1e-8, 1e-6, 1e-4)


def theta2_to_lengthscale(theta2: float) -> float:
    """GPyTorch RBF lengthscale of the paper's ``θ2``: ``exp(−d²/θ2) = exp(−d²/(2ℓ²))`` ⇔ ``ℓ = √(θ2/2)``."""
    return math.sqrt(theta2 / 2.0)


def lengthscale_to_theta2(lengthscale: float) -> float:
    """Inverse of :func:`theta2_to_lengthscale`: ``θ2 = 2ℓ²``."""
    return 2.0 * lengthscale**2


# ----------------------------------------------------------------------------------------------- kernel helpers

def _scaled(x: Tensor, lengthscale: Tensor) -> Tensor:
    """Inputs divided by ``ℓ√2`` so that the kernel is ``θ1 exp(−‖xs − xs'‖²)``."""
    return x / (lengthscale.to(x) * math.sqrt(2.0))


def _sqdist(xs1: Tensor, xs2: Tensor, sq1: Tensor | None = None, sq2: Tensor | None = None) -> Tensor:
    """Squared distances ``(n1, n2)`` of scaled inputs, clamped to ``[0, EXP_CLAMP]``."""
    sq1 = (xs1 * xs1).sum(-1) if sq1 is None else sq1
    sq2 = (xs2 * xs2).sum(-1) if sq2 is None else sq2
    d2 = (xs1 @ xs2.mT).mul_(-2.0).add_(sq1.unsqueeze(-1)).add_(sq2.unsqueeze(-2))
    return d2.clamp_(0.0, EXP_CLAMP)


def cross_kernel_cache(xs_ref: Tensor) -> tuple[Tensor, Tensor]:
    """``(2 xs_refᵀ (d, R), −‖xs_ref‖² (R,))``: what :func:`exp_neg_sqdist` needs of fixed scaled inputs."""
    return (2.0 * xs_ref).T.contiguous(), -(xs_ref * xs_ref).sum(-1)


def exp_neg_sqdist(xs: Tensor, ref_t2: Tensor, ref_sq_neg: Tensor) -> Tensor:
    """``exp(−‖xs_i − r_j‖²)`` ``(P, R)`` of scaled inputs ``xs (P, d)`` against cached references
    (:func:`cross_kernel_cache`): one matrix product ``2 xs·r − ‖r‖²`` and three in-place passes."""
    e = torch.addmm(ref_sq_neg, xs, ref_t2)
    return e.sub_((xs * xs).sum(-1, keepdim=True)).clamp_(-EXP_CLAMP, 0.0).exp_()


def kernel_matrix(xs1: Tensor, xs2: Tensor, outputscale: float | Tensor) -> Tensor:
    """``θ1 exp(−‖xs1 − xs2‖²)`` of scaled inputs (see :func:`_scaled`), batched over leading dims."""
    return _sqdist(xs1, xs2).neg_().exp_().mul_(outputscale)


def _fill_kernel(out: Tensor, xs: Tensor, outputscale: float, diag: float, chunk: int = 2048) -> Tensor:
    """Write ``θ1 exp(−‖xs_i − xs_j‖²) + diag δ_ij`` into ``out (N, N)`` in row chunks (no other N×N temporary)."""
    sq = (xs * xs).sum(-1)
    n = xs.shape[0]
    for i0 in range(0, n, chunk):
        i1 = min(n, i0 + chunk)
        rows = out[i0:i1]
        torch.mm(xs[i0:i1], xs.T, out=rows)
        rows.mul_(-2.0).add_(sq[i0:i1].unsqueeze(1)).add_(sq.unsqueeze(0)).clamp_(0.0, EXP_CLAMP)
        rows.neg_().exp_().mul_(outputscale)
    out.diagonal().add_(diag)
    return out


def cholesky_kernel(xs: Tensor, outputscale: float, noise: float) -> Tensor:
    """Lower Cholesky factor of ``K + σ²I`` for scaled inputs ``xs (N, d)``, built and factorised in place.

    Peak memory is about one ``N × N`` matrix. On failure the matrix is rebuilt with growing jitter (relative to
    ``θ1``) and a :class:`RuntimeWarning` names the jitter used.
    """
    n = xs.shape[0]
    mat = torch.empty(n, n, dtype=xs.dtype, device=xs.device)
    info = torch.empty((), dtype=torch.int32, device=xs.device)
    for jitter in (0.0, *_JITTERS):
        _fill_kernel(mat, xs, outputscale, noise + jitter * outputscale)
        # the transposed view is column-major: LAPACK factorises it in place, leaving L in mat's lower triangle
        view = mat.mT
        torch.linalg.cholesky_ex(view, upper=True, out=(view, info))
        if int(info) == 0:
            if jitter:
                warnings.warn(f"Cholesky of the {n}x{n} GP kernel needed jitter {jitter:g}*theta1 on the diagonal",
                              RuntimeWarning, stacklevel=2)
            return mat
    raise RuntimeError(f"Cholesky of the {n}x{n} GP kernel failed even with jitter {_JITTERS[-1]:g}*theta1")


# ----------------------------------------------------------------------------------------------- GPyTorch side

def gpytorch_exact_model(x: Tensor, y_centred: Tensor, outputscale: float, lengthscale: Tensor | float,
                         noise: float, ard: bool = False):
    """The equivalent GPyTorch exact GP ``(model, likelihood)`` (zero mean on centred outputs).

    Used for marginal-likelihood fitting and to check the kernel mapping; never on the prediction path.
    """
    import gpytorch

    dim = x.shape[-1]

    class _Model(gpytorch.models.ExactGP):
        def __init__(self, train_x, train_y, likelihood):
            super().__init__(train_x, train_y, likelihood)
            self.mean_module = gpytorch.means.ZeroMean()
            self.covar_module = gpytorch.kernels.ScaleKernel(
                gpytorch.kernels.RBFKernel(ard_num_dims=dim if ard else None))

        def forward(self, xx):
            return gpytorch.distributions.MultivariateNormal(self.mean_module(xx), self.covar_module(xx))

    likelihood = gpytorch.likelihoods.GaussianLikelihood(
        noise_constraint=gpytorch.constraints.GreaterThan(1e-8)).to(x)
    model = _Model(x, y_centred, likelihood).to(x)
    likelihood.noise = torch.as_tensor(noise, dtype=x.dtype)
    model.covar_module.outputscale = torch.as_tensor(outputscale, dtype=x.dtype)
    ls = torch.as_tensor(lengthscale, dtype=x.dtype, device=x.device)
    if not ard and ls.numel() > 1 and not bool((ls == ls.reshape(-1)[0]).all()):
        raise ValueError("a shared (non-ARD) lengthscale needs equal per-dimension start values")
    model.covar_module.base_kernel.lengthscale = ls.expand(dim) if ard else ls.reshape(-1)[:1]
    return model, likelihood


def maximise_mll(model, likelihood, x: Tensor, y: Tensor, params: list, *, iterations: int, lr: float,
                 progress: bool = False, desc: str = "GP hyperparameters") -> list[float]:
    """Adam on ``params`` of a GPyTorch ``ExactGP`` model (exact Cholesky, any size) against its
    ``ExactMarginalLogLikelihood`` — the exact evidence, or the collapsed SGPR bound when the model's kernel is an
    ``InducingPointKernel``. Returns the objective per point before each step and after the last
    (``iterations + 1`` values); ``progress`` shows a bar with the current value."""
    import gpytorch
    from tqdm.auto import tqdm

    model.train()
    likelihood.train()
    mll = gpytorch.mlls.ExactMarginalLogLikelihood(likelihood, model)
    opt = torch.optim.Adam(params, lr=lr)
    history: list[float] = []
    with gpytorch.settings.max_cholesky_size(10**9), tqdm(total=iterations, desc=desc, disable=not progress,
                                                          leave=False) as bar:
        for _ in range(iterations):
            opt.zero_grad()
            loss = -mll(model(x), y)
            history.append(-loss.item())
            loss.backward()
            opt.step()
            bar.set_postfix(objective=f"{history[-1]:.4f}", refresh=False)
            bar.update()
        with torch.no_grad():
            history.append(float(mll(model(x), y)))
    return history


def fit_hyperparameters(x: Tensor, y_centred: Tensor, outputscale: float, lengthscale: Tensor | float, noise: float,
                        *, ard: bool, iterations: int, lr: float,
                        progress: bool = False) -> tuple[float, Tensor, float, list[float]]:
    """Maximise the exact log marginal likelihood (GPyTorch, Adam, exact Cholesky) from the given start.

    Returns ``(outputscale, lengthscale (d,), noise variance, mll per point history)``; the history has
    ``iterations + 1`` entries (before each step and after the last).
    """
    model, likelihood = gpytorch_exact_model(x, y_centred, outputscale, lengthscale, noise, ard)
    history = maximise_mll(model, likelihood, x, y_centred, list(model.parameters()), iterations=iterations, lr=lr,
                           progress=progress, desc="exact GP hyperparameters")
    ls = model.covar_module.base_kernel.lengthscale.detach().reshape(-1)
    ls = ls.expand(x.shape[-1]).clone()
    return (float(model.covar_module.outputscale.detach()), ls, float(likelihood.noise.detach()), history)


def _hyper_start(cfg: ModelConfig, dim: int) -> tuple[float, Tensor, float]:
    return cfg.theta1, torch.full((dim,), theta2_to_lengthscale(cfg.theta2), dtype=torch.float64), cfg.noise_std**2


# ----------------------------------------------------------------------------------------------- the model

class ExactGP(ObservationModel):
    """Exact GP conditioned on all training points; plain-torch prediction from cached ``α``.

    Build with :meth:`from_data`. Buffers (move with ``.to()``): ``x_train`` (standardised inputs), ``alpha``,
    ``lengthscale (d,)``, ``outputscale``, ``noise`` (variance), ``y_mean``, and the derived scaled inputs.

    Args:
        inputs: the fitted input map.
        x_train: mapped training inputs ``(N, d)``.
        alpha: ``(K + σ²I)⁻¹ (y − μ)`` ``(N,)``.
        y_mean: constant mean ``μ``.
        outputscale, lengthscale, noise: ``θ1``, per-dimension ``ℓ`` ``(d,)``, ``σ²``.
        variance_mode: ``"fast"``, ``"exact"`` or ``"none"``.
        neighbors: neighbour count of the fast variance.
        config: the model config section it came from (plain dict, saved with the model).
        cluster_radius: largest diameter (in lengthscales) of a point set that shares one neighbour set.
    """

    kind = "exact"
    #: largest kernel block ``(points × N)`` computed at once by a prediction (8 MB in float64)
    chunk_values: int = 1 << 20

    def __init__(self, inputs: InputMap, x_train: Tensor, alpha: Tensor, y_mean: float | Tensor,
                 outputscale: float | Tensor, lengthscale: Tensor, noise: float | Tensor, *,
                 variance_mode: str = "fast", neighbors: int = 256, config: dict | None = None,
                 cluster_radius: float = 1.0, chol: Tensor | None = None):
        super().__init__()
        if variance_mode not in ("fast", "exact", "none"):
            raise ValueError(f"variance_mode must be fast, exact or none, got {variance_mode!r}")
        n, d = x_train.shape
        if d != inputs.dim or alpha.shape != (n,) or lengthscale.shape != (d,):
            raise ValueError(f"inconsistent GP state: x_train {tuple(x_train.shape)}, alpha {tuple(alpha.shape)}, "
                             f"lengthscale {tuple(lengthscale.shape)}, input dim {inputs.dim}")
        self.inputs = inputs
        self.variance_mode = variance_mode
        self.neighbors = int(neighbors)
        self.cluster_radius = float(cluster_radius)
        self.config = dict(config or {})
        f64 = dict(dtype=torch.float64, device=x_train.device)
        self.register_buffer("x_train", x_train.to(**f64))
        self.register_buffer("alpha", alpha.to(**f64))
        self.register_buffer("y_mean", torch.as_tensor(y_mean, **f64))
        self.register_buffer("outputscale", torch.as_tensor(outputscale, **f64))
        self.register_buffer("lengthscale", lengthscale.to(**f64))
        self.register_buffer("noise", torch.as_tensor(noise, **f64))
        xs = _scaled(self.x_train, self.lengthscale)
        self.register_buffer("xs_train", xs, persistent=False)
        ref_t2, ref_sq_neg = cross_kernel_cache(xs)
        self.register_buffer("xs_train_t2", ref_t2, persistent=False)
        self.register_buffer("xs_sq_neg", ref_sq_neg, persistent=False)
        self.register_buffer("alpha_scaled", self.alpha * self.outputscale, persistent=False)  # θ1 α
        self._chol = chol  # float64 lower factor of K + σ²I (not a buffer: 3 GB at N = 19260, never saved)

    # ------------------------------------------------------------------ construction

    @classmethod
    def from_data(cls, q: Tensor, m_past: Tensor, y: Tensor, cfg: ModelConfig, *, seed: int = 0,
                  keep_cholesky: bool = True, device: torch.device | str | None = None,
                  progress: bool = False) -> "ExactGP":
        """Condition the paper's GP on training data ``q (N, 4)``, ``m_past (N,)``, ``y (N,)``.

        Inputs are mapped by ``cfg.inputs`` (standardised if ``cfg.standardize_inputs``); hyperparameters start
        at the paper's ``(θ1, θ2, σ)`` and are fitted by exact marginal likelihood on ``cfg.fit_subset`` random
        points (seeded) when ``cfg.fit_hyperparameters``. Computation is float64 on ``device`` (default: that of
        ``q``); move the result with ``.to()``. ``fit_history`` holds the fit's log marginal likelihood per point;
        ``progress`` shows a bar during the fit.
        """
        device = torch.device(device) if device is not None else q.device
        f64 = dict(dtype=torch.float64, device=device)
        q, m_past, y = q.to(**f64), m_past.to(**f64), y.to(**f64)
        _check_training(q, m_past, y)
        inputs = InputMap(cfg.inputs, cfg.standardize_inputs).to(device)
        x = inputs.fit(q, m_past)
        y_mean = y.mean()
        r = y - y_mean
        outputscale, lengthscale, noise = _hyper_start(cfg, x.shape[-1])
        lengthscale = lengthscale.to(device)
        history: list[float] = []
        if cfg.fit_hyperparameters and cfg.fit_iterations > 0:
            idx = _subset(x.shape[0], cfg.fit_subset, seed, device)
            outputscale, lengthscale, noise, history = fit_hyperparameters(
                x[idx], r[idx], outputscale, lengthscale, noise, ard=cfg.ard, iterations=cfg.fit_iterations,
                lr=cfg.fit_lr, progress=progress)
        chol = cholesky_kernel(_scaled(x, lengthscale), outputscale, noise)
        # two triangular solves: torch.cholesky_solve would copy the N x N factor
        v = torch.linalg.solve_triangular(chol, r.unsqueeze(-1), upper=False)
        alpha = torch.linalg.solve_triangular(chol.mT, v, upper=True).squeeze(-1)
        model = cls(inputs, x, alpha, y_mean, outputscale, lengthscale, noise, variance_mode=cfg.variance,
                    neighbors=cfg.fast_variance_neighbors, config=config_to_dict(cfg),
                    chol=chol if keep_cholesky else None)
        model.fit_history = history
        return model

    # ------------------------------------------------------------------ hyperparameters

    @property
    def theta1(self) -> float:
        return float(self.outputscale)

    @property
    def theta2(self) -> Tensor:
        """Per-dimension ``θ2 = 2ℓ²`` ``(d,)``."""
        return 2.0 * self.lengthscale**2

    @property
    def noise_std(self) -> float:
        return float(self.noise) ** 0.5

    @property
    def num_train(self) -> int:
        return self.x_train.shape[0]

    # ------------------------------------------------------------------ prediction

    def _predict(self, q: Tensor, m_past: Tensor, with_variance: bool) -> Prediction:
        """Mean ``k*ᵀα + μ`` (paper Eq. (25)) and the chosen variance, in chunks of at most :attr:`chunk_values`
        kernel values (a chunk's kernel block stays in the CPU cache between its passes).

        Points along the last batch dimension of a ``(..., S, 4)`` input form a set (a filter's sigma points);
        the fast variance shares one neighbour set among the points of a set whose diameter is within
        :attr:`cluster_radius` (in lengthscales). A 1-D batch ``(P, 4)`` has sets of one point.
        """
        batch = q.shape[:-1]
        dt, d, n_train = self.alpha.dtype, self.inputs.dim, self.x_train.shape[0]
        set_size = q.shape[-2] if q.ndim >= 3 else 1
        x = self.inputs(q.to(dt), m_past.to(dt)).reshape(-1, set_size, d)
        xs_sets = _scaled(x, self.lengthscale)
        want_var = with_variance and self.variance_mode != "none"
        sets_per_chunk = max(1, self.chunk_values // (set_size * n_train))
        means, variances = [], []
        for start in range(0, xs_sets.shape[0], sets_per_chunk):
            xs_chunk = xs_sets[start:start + sets_per_chunk]
            e = exp_neg_sqdist(xs_chunk.reshape(-1, d), self.xs_train_t2, self.xs_sq_neg)  # k*/θ1 (P, N)
            means.append(torch.mv(e, self.alpha_scaled).add_(self.y_mean))
            if want_var:
                if self.variance_mode == "exact":
                    variances.append(self._exact_variance(e))
                else:
                    variances.append(self._fast_variance(e, _set_clusters(xs_chunk, self.cluster_radius)))
        mean = torch.cat(means).reshape(batch)
        return mean, (torch.cat(variances).reshape(batch) if want_var else None)

    def predict_variance(self, q: Tensor, m_past: Tensor, mode: str) -> Tensor:
        """Latent variance by a given mode (``"fast"`` or ``"exact"``), whatever :attr:`variance_mode` is."""
        old = self.variance_mode
        try:
            self.variance_mode = mode
            return self.predict(q, m_past)[1]
        finally:
            self.variance_mode = old

    def cholesky(self) -> Tensor:
        """Float64 Cholesky factor of ``K + σ²I``; recomputed (≈30 s at N = 19260) when not cached."""
        if self._chol is None or self._chol.device != self.x_train.device:
            if self._chol is not None:
                self._chol = self._chol.to(self.x_train.device)
            else:
                xs64 = _scaled(self.x_train.double(), self.lengthscale.double())
                self._chol = cholesky_kernel(xs64, float(self.outputscale), float(self.noise))
        return self._chol

    def drop_cholesky(self) -> None:
        """Free the cached full Cholesky factor (it is recomputed if the exact variance is asked for)."""
        self._chol = None

    def _exact_variance(self, e: Tensor) -> Tensor:
        """``θ1 − θ1² eᵀ (K + σ²I)⁻¹ e`` for ``e = k*/θ1`` ``(P, N)`` with the full Cholesky factor."""
        chol = self.cholesky()
        v = torch.linalg.solve_triangular(chol, e.T.to(chol.dtype), upper=False)
        theta1 = float(self.outputscale)
        var = theta1 - theta1 * theta1 * (v * v).sum(0)
        return var.clamp_min(0.0).to(e.dtype)

    def _fast_variance(self, e_all: Tensor, cluster: Tensor) -> Tensor:
        """Local exact variance: each cluster of test points is conditioned on its ``neighbors`` training points
        of largest covariance (an upper bound of the exact variance: conditioning on fewer points never lowers it).

        Args:
            e_all: covariances of the test points with all training points, divided by ``θ1``, ``(P, N)``.
            cluster: cluster id of each test point ``(P,)``, numbered from 0.
        """
        n_pts, n_train = e_all.shape
        k = min(self.neighbors, n_train)
        n_cl = int(cluster.max()) + 1 if n_pts else 0
        # per cluster, each training point's covariance with its nearest member (the kernel decreases with
        # distance, so the largest covariances are the nearest points): (C, N)
        if n_cl == n_pts:
            kmax = e_all
        else:
            kmax = torch.zeros((n_cl, n_train), dtype=e_all.dtype, device=e_all.device)
            kmax.scatter_reduce_(0, cluster.unsqueeze(1).expand(-1, n_train), e_all, reduce="amax")
        nbr = torch.topk(kmax, k, dim=1, largest=True, sorted=False).indices  # (C, k)
        xn = self.xs_train[nbr]  # (C, k, d)
        kmat = kernel_matrix(xn, xn, self.outputscale)
        kmat.diagonal(dim1=-2, dim2=-1).add_(self.noise)
        chol, info = torch.linalg.cholesky_ex(kmat)
        if bool((info != 0).any()):
            jit = 1e-6 * self.outputscale
            chol = torch.linalg.cholesky(kmat + jit * torch.eye(k, dtype=kmat.dtype, device=kmat.device))
        # cross-covariances of each point with its cluster's neighbours, padded into (C, k, m_max)
        ks = e_all.gather(1, nbr[cluster]).mul_(self.outputscale)  # (P, k)
        if n_cl == n_pts:
            rhs = ks.unsqueeze(-1)
            v = torch.linalg.solve_triangular(chol, rhs, upper=False)
            quad = (v * v).sum((-2, -1))
        else:
            counts = torch.bincount(cluster, minlength=n_cl)
            order = torch.argsort(cluster, stable=True)
            starts = torch.cumsum(counts, 0) - counts
            pos = torch.empty_like(cluster)
            pos[order] = torch.arange(n_pts, device=cluster.device) - starts[cluster[order]]
            rhs = torch.zeros(n_cl, int(counts.max()), k, dtype=ks.dtype, device=ks.device)
            rhs[cluster, pos] = ks
            v = torch.linalg.solve_triangular(chol, rhs.mT, upper=False)  # (C, k, m_max)
            quad = (v * v).sum(-2)[cluster, pos]
        return (self.outputscale - quad).clamp_min_(0.0)

    # ------------------------------------------------------------------ file state

    def file_state(self) -> dict[str, Any]:
        """Plain tensors/python values for :func:`lightcurve_gp.observation.serialization.save_model`."""
        cpu64 = lambda t: t.detach().to("cpu", torch.float64).clone()  # noqa: E731
        return {
            "x_train": cpu64(self.x_train), "alpha": cpu64(self.alpha), "y_mean": float(self.y_mean),
            "outputscale": float(self.outputscale), "lengthscale": cpu64(self.lengthscale),
            "noise": float(self.noise), "variance_mode": self.variance_mode, "neighbors": self.neighbors,
            "cluster_radius": self.cluster_radius,
        }

    @classmethod
    def from_file_state(cls, inputs: InputMap, state: dict[str, Any], config: dict) -> "ExactGP":
        return cls(inputs, state["x_train"], state["alpha"], state["y_mean"], state["outputscale"],
                   state["lengthscale"], state["noise"], variance_mode=state["variance_mode"],
                   neighbors=state["neighbors"], cluster_radius=state["cluster_radius"], config=config)


# ----------------------------------------------------------------------------------------------- helpers

def _check_training(q: Tensor, m_past: Tensor, y: Tensor) -> None:
    if q.ndim != 2 or q.shape[1] != 4 or m_past.shape != (q.shape[0],) or y.shape != (q.shape[0],):
        raise ValueError(f"training data must be q (N, 4), m_past (N,), y (N,); got {tuple(q.shape)}, "
                         f"{tuple(m_past.shape)}, {tuple(y.shape)}")
    if q.shape[0] < 2:
        raise ValueError("training data needs at least 2 points")
    for name, t in (("q", q), ("m_past", m_past), ("y", y)):
        if not bool(torch.isfinite(t).all()):
            raise ValueError(f"training {name} contains non-finite values")


def _subset(n: int, size: int, seed: int, device: torch.device) -> Tensor:
    """A seeded random subset of ``min(size, n)`` indices (all of them, in order, when ``size ≥ n``)."""
    if size >= n:
        return torch.arange(n, device=device)
    gen = torch.Generator().manual_seed(seed)
    return torch.randperm(n, generator=gen)[:size].to(device)


def _set_clusters(xs_sets: Tensor, radius: float) -> Tensor:
    """Cluster ids ``(C·S,)`` of scaled test points ``(C, S, d)``: a set whose diameter is within ``radius`` is
    one cluster, the points of a wider set are clusters of their own; ids are numbered from 0."""
    n_sets, size, _ = xs_sets.shape
    point_ids = torch.arange(n_sets * size, device=xs_sets.device).view(n_sets, size)
    if size == 1:
        return point_ids.reshape(-1)
    shared = torch.cdist(xs_sets, xs_sets).amax((-2, -1)) <= radius
    ids = torch.where(shared.unsqueeze(-1), point_ids[:, :1].expand(n_sets, size), point_ids).reshape(-1)
    return torch.unique(ids, return_inverse=True)[1]


# ----------------------------------------------------------------------------------------------- validation

def fast_variance_error(model: ExactGP, q: Tensor, m_past: Tensor) -> dict[str, float]:
    """Compare the fast and exact predictive variances on (held-out) points.

    ``q (..., 4)``, ``m_past (...)`` are predicted as one batch, so clusters of nearby points (e.g. sigma-point
    sets shaped ``(B, 7, 4)``) share neighbour sets exactly as in the filter. Returns ``max_rel``/``median_rel``
    (``|fast − exact| / exact``), ``max_abs``, ``min_exact``, ``n``; uses the full Cholesky factor (computed if
    not cached).
    """
    with torch.no_grad():
        fast = model.predict_variance(q, m_past, "fast").double().reshape(-1)
        exact = model.predict_variance(q, m_past, "exact").double().reshape(-1)
    err = (fast - exact).abs()
    rel = err / exact.clamp_min(1e-300)
    return {"max_rel": float(rel.max()), "median_rel": float(rel.median()), "max_abs": float(err.max()),
            "min_exact": float(exact.min()), "n": int(exact.numel())}
