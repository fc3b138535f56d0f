"""Exact GP observation model (paper sections 2.4 and 3.1–3.2): the cache and the predictions.

Conditioning on all ``N`` training points is one exact float64 Cholesky of ``K + σ²I``, built and factorised in
place (:func:`.kernels.cholesky_kernel`, peak memory ≈ one ``N × N`` matrix). Prediction is plain torch on cached
tensors (``α = (K + σ²I)⁻¹(y − μ)`` and the scaled training inputs): GPyTorch's own ``model(x)`` costs
milliseconds per call even when cached.

Predictive variance (of the latent function), chosen per call:

* ``"exact"``: ``k** − k*ᵀ (K + σ²I)⁻¹ k*`` with the full Cholesky factor (kept after fitting, recomputed lazily
  after loading; reading it costs ≳ 0.17 s per call at N = 19260).
* ``"fast"``: the same formula conditioned only on the ``neighbors`` training points nearest (in kernel-scaled
  distance) to the test point. The points along the last batch dimension of a ``(..., S, 4)`` input (a filter's
  sigma points) share one neighbour set when the set's diameter is within ``cluster_radius`` lengthscales, so such
  a set costs one ``k × k`` Cholesky — a point's fast variance therefore depends on the set it is batched with.
  Conditioning on a subset never lowers a GP's posterior variance, so the fast variance is an upper bound of the
  exact one (conservative for a filter); :func:`fast_variance_error` measures the gap.
* ``"none"``: mean only; ``variance`` is returned as ``None``.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from lightcurve_gp.config.load import config_to_dict
from lightcurve_gp.observation.base import Prediction, Variance
from lightcurve_gp.observation.fitting import fit_hyperparameters, seeded_subset
from lightcurve_gp.observation.gp_base import CachedGP, GPTrainingSet, cpu64
from lightcurve_gp.observation.inputs import InputMap
from lightcurve_gp.observation.kernels import (
    blocked_kernel_sum,
    cholesky_jittered,
    cholesky_kernel,
    cross_kernel_cache,
    exp_neg_sqdist,
    kernel_matrix,
    scaled,
    weighted_blocks,
)

__all__ = ["ExactGP", "fast_variance_error", "conditioning_bytes"]


def conditioning_bytes(n: int) -> int:
    """Peak memory (bytes) of conditioning the exact GP on ``n`` training points: the one ``n × n`` float64 matrix
    :func:`.kernels.cholesky_kernel` builds and factorises in place (measured: 1.07 × this at n = 6000, the rest
    being the training inputs and the solves)."""
    return 8 * n * n


class ExactGP(CachedGP):
    """Exact GP conditioned on all training points; plain-torch prediction from cached ``α``.

    Build with :meth:`from_data`. Buffers (move with ``.to()``): ``x_train`` (mapped inputs), ``alpha``, the
    hyperparameters of :class:`~.gp_base.CachedGP` and the derived scaled inputs.

    Args:
        inputs: the fitted input map.
        x_train: mapped training inputs ``(N, d)``.
        alpha: ``(K + σ²I)⁻¹ (y − μ)`` ``(N,)``.
        y_mean: constant mean ``μ``.
        outputscale, lengthscale, noise: ``θ1``, per-dimension ``ℓ`` ``(d,)``, ``σ²``.
        neighbors: neighbour count of the fast variance.
        config: the model config section it came from (plain dict, saved with the model).
        cluster_radius: largest diameter (in lengthscales) of a point set that shares one neighbour set.
    """

    kind = "exact"
    shares_sets = True

    def __init__(self, inputs: InputMap, x_train: Tensor, alpha: Tensor, y_mean: float | Tensor,
                 outputscale: float | Tensor, lengthscale: Tensor, noise: float | Tensor, *,
                 neighbors: int = 256, config: dict | None = None, cluster_radius: float = 1.0,
                 chol: Tensor | None = None):
        n, d = x_train.shape
        if d != inputs.dim or alpha.shape != (n,) or lengthscale.shape != (d,):
            raise ValueError(f"inconsistent GP state: x_train {tuple(x_train.shape)}, alpha {tuple(alpha.shape)}, "
                             f"lengthscale {tuple(lengthscale.shape)}, input dim {inputs.dim}")
        super().__init__(inputs, y_mean=y_mean, outputscale=outputscale, lengthscale=lengthscale, noise=noise,
                         config=config, device=x_train.device)
        self.neighbors = int(neighbors)
        self.cluster_radius = float(cluster_radius)
        f64 = {"dtype": torch.float64, "device": x_train.device}
        self.register_buffer("x_train", x_train.to(**f64))
        self.register_buffer("alpha", alpha.to(**f64))
        xs = scaled(self.x_train, self.lengthscale)
        self.register_buffer("xs_train", xs, persistent=False)
        self.register_buffer("xs_train_cache", cross_kernel_cache(xs), persistent=False)
        self.register_buffer("alpha_scaled", self.alpha * self.outputscale, persistent=False)  # θ1 α
        for name, t in zip(("xs_blocks", "alpha_blocks"), weighted_blocks(xs, self.alpha_scaled)):
            self.register_buffer(name, t, persistent=False)  # the compiled mean's layout (_predict_sets)
        self._chol = chol  # float64 lower factor of K + σ²I (not a buffer: 3 GB at N = 19260, never saved)

    @classmethod
    def from_data(cls, q: Tensor, m_past: Tensor, y: Tensor, cfg: Any, *, seed: int = 0,
                  keep_cholesky: bool = True, device: torch.device | str | None = None,
                  progress: bool = False) -> ExactGP:
        """Condition the paper's GP on training data ``q (N, 4)``, ``m_past (N,)``, ``y (N,)``.

        ``cfg`` is a :class:`~lightcurve_gp.config.load.ModelConfig` of kind ``exact``. Hyperparameters start at the
        paper's ``(θ1, θ2, σ)`` and are fitted by exact marginal likelihood on ``cfg.exact.fit_subset`` random
        points (seeded) when ``cfg.fit_hyperparameters``. Computation is float64 on ``device`` (default: that of
        ``q``); move the result with ``.to()``. ``fit_history`` holds the fit's log marginal likelihood per point;
        ``progress`` shows a bar during the fit.
        """
        ts = GPTrainingSet.prepare(q, m_past, y, cfg, device)
        x, r = ts.x, ts.r
        outputscale, lengthscale, noise = ts.outputscale, ts.lengthscale, ts.noise
        history: list[float] = []
        if cfg.fit_hyperparameters and cfg.exact.fit_iterations > 0:
            idx = seeded_subset(x.shape[0], cfg.exact.fit_subset, seed, x.device)
            outputscale, lengthscale, noise, history = fit_hyperparameters(
                x[idx], r[idx], outputscale, lengthscale, noise, ard=cfg.ard, iterations=cfg.exact.fit_iterations,
                lr=cfg.fit_lr, progress=progress)
        chol = cholesky_kernel(scaled(x, lengthscale), outputscale, noise)
        # two triangular solves: torch.cholesky_solve would copy the N x N factor
        v = torch.linalg.solve_triangular(chol, r.unsqueeze(-1), upper=False)
        alpha = torch.linalg.solve_triangular(chol.mT, v, upper=True).squeeze(-1)
        model = cls(ts.inputs, x, alpha, ts.y_mean, outputscale, lengthscale, noise,
                    neighbors=cfg.exact.fast_variance_neighbors, config=config_to_dict(cfg),
                    chol=chol if keep_cholesky else None)
        model.fit_history = history
        return model

    @property
    def num_train(self) -> int:
        return self.x_train.shape[0]

    def _reference_count(self) -> int:
        return self.x_train.shape[0]

    def _predict_sets(self, xs_sets: Tensor, variance: Variance) -> Prediction:
        """Mean ``k*ᵀα + μ`` (paper Eq. (25)) and the chosen variance of scaled test sets ``(C, S, d)``.

        Inside a compiled filter step (mean only) the mean is the blocked elementwise sum
        (:func:`.kernels.blocked_kernel_sum`), which the compiler fuses into one loop; eagerly it is one matrix
        product, one ``exp`` and one matrix-vector product, the fastest eager form."""
        if variance == "none" and torch.compiler.is_compiling():
            xs = xs_sets.reshape(-1, xs_sets.shape[-1])
            return blocked_kernel_sum(xs, self.xs_blocks, self.alpha_blocks) + self.y_mean, None
        e = exp_neg_sqdist(xs_sets.reshape(-1, xs_sets.shape[-1]), self.xs_train_cache)  # k*/θ1
        mean = torch.mv(e, self.alpha_scaled).add_(self.y_mean)
        if variance == "none":
            return mean, None
        if variance == "exact":
            return mean, self._exact_variance(e)
        return mean, self._fast_variance(e, _set_clusters(xs_sets, self.cluster_radius))

    def cholesky(self) -> Tensor:
        """Float64 Cholesky factor of ``K + σ²I``; recomputed (≈30 s at N = 19260) when not cached."""
        if self._chol is None or self._chol.device != self.x_train.device:
            if self._chol is not None:
                self._chol = self._chol.to(self.x_train.device)
            else:
                xs64 = scaled(self.x_train.double(), self.lengthscale.double())
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
        chol = cholesky_jittered(kmat, scale=self.outputscale, what=f"{k}x{k} neighbour kernels")
        ks = e_all.gather(1, nbr[cluster]).mul_(self.outputscale)  # (P, k)
        return (self.outputscale - _cluster_quadratic(chol, ks, cluster, n_cl)).clamp_min_(0.0)

    def _cache_state(self) -> dict[str, Any]:
        return {"x_train": cpu64(self.x_train), "alpha": cpu64(self.alpha), "neighbors": self.neighbors,
                "cluster_radius": self.cluster_radius}

    @classmethod
    def from_file_state(cls, inputs: InputMap, state: dict[str, Any], config: dict) -> ExactGP:
        """Rebuild from :meth:`file_state` (files written before the variance became a per-call choice also
        carry a ``variance_mode``, which is ignored)."""
        return cls(inputs, state["x_train"], state["alpha"], **cls._hyperparameters(state),
                   neighbors=state["neighbors"], cluster_radius=state["cluster_radius"], config=config)


def _cluster_quadratic(chol: Tensor, ks: Tensor, cluster: Tensor, n_cl: int) -> Tensor:
    """``k_iᵀ (K_c + σ²I)⁻¹ k_i`` ``(P,)`` of each point ``i`` against its cluster ``c``'s neighbour factor
    ``chol (C, k, k)``, with cross-covariances ``ks (P, k)``; the points of a cluster are solved together."""
    n_pts = ks.shape[0]
    if n_cl == n_pts:
        v = torch.linalg.solve_triangular(chol, ks.unsqueeze(-1), upper=False)
        return (v * v).sum((-2, -1))
    # cross-covariances of each point with its cluster's neighbours, padded into (C, k, m_max)
    counts = torch.bincount(cluster, minlength=n_cl)
    order = torch.argsort(cluster, stable=True)
    starts = torch.cumsum(counts, 0) - counts
    pos = torch.empty_like(cluster)
    pos[order] = torch.arange(n_pts, device=cluster.device) - starts[cluster[order]]
    rhs = torch.zeros(n_cl, int(counts.max()), ks.shape[1], dtype=ks.dtype, device=ks.device)
    rhs[cluster, pos] = ks
    v = torch.linalg.solve_triangular(chol, rhs.mT, upper=False)  # (C, k, m_max)
    return (v * v).sum(-2)[cluster, pos]


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


def fast_variance_error(model: ExactGP, q: Tensor, m_past: Tensor) -> dict[str, float]:
    """Compare the fast and exact predictive variances on (held-out) points.

    ``q (..., 4)``, ``m_past (...)`` are predicted as one batch, so clusters of nearby points (e.g. sigma-point
    sets shaped ``(B, 7, 4)``) share neighbour sets exactly as in the filter. Returns ``max_rel``/``median_rel``
    (``|fast − exact| / exact``), ``max_abs``, ``min_exact``, ``n``; uses the full Cholesky factor (computed if
    not cached).
    """
    with torch.no_grad():
        fast = model(q=q, m_past=m_past, variance="fast")[1].double().reshape(-1)
        exact = model(q=q, m_past=m_past, variance="exact")[1].double().reshape(-1)
    err = (fast - exact).abs()
    rel = err / exact.clamp_min(1e-300)
    return {"max_rel": float(rel.max()), "median_rel": float(rel.median()), "max_abs": float(err.max()),
            "min_exact": float(exact.min()), "n": int(exact.numel())}
