"""The convex shape profiled out: non-negative areas on fixed normals for many spin states at once.

The data are relative intensities: each light curve ``c`` is divided by its mean, ``ỹ_i = I_i / Ī_c``, since its
scale is unknown (:class:`ConvexData`). For a spin state the model is linear in the areas, ``L = G a``
(:func:`~lightcurve_gp.photometry.convex.facet_brightness`), and each curve has its own unknown scale ``t_c``.

**Linear fit** (:func:`fit_areas`, the screen). Minimise ``Σ_i ((G a)_i − t_c ỹ_i)²`` over ``a ≥ 0`` and the scales.
The scales are profiled in closed form, ``t_c = w_cᵀ a`` with ``w_c = G_cᵀ ỹ_c / |ỹ_c|²``, leaving the quadratic
form ``aᵀ M a``, ``M = GᵀG − Σ_c |ỹ_c|² w_c w_cᵀ``, homogeneous in ``a``; it is normalised by the mean scale,
``cᵀ a = 1`` with ``c = mean_c w_c``, so that a model on the data's scale is compared. A closure term
``κ |Σ_k a_k n_k|²`` (the Gaussian image of a closed body sums to zero; convexinv's "dark facet") is added to ``M``.
Minimising ``aᵀ M a − 2 cᵀ a`` over ``a ≥ 0`` has the same minimiser up to scale (the ratio
``aᵀ M a / (cᵀ a)²`` is scale-free and at the optimum ``aᵀ M a = cᵀ a``), so the problem is a plain
non-negative quadratic program, solved batched by a projected Newton iteration with a fixed count (see
:func:`fit_areas`). Its residual sum of squares is ``aᵀ M a / (cᵀ a)²``.
The nonlinear polish of (pole, period, areas) is :mod:`.convex_polish`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from lightcurve_gp.observations.observations import Observations
from lightcurve_gp.photometry.convex import (
    SatelliteScattering,
    Scattering,
    body_vectors,
    facet_brightness,
    phase_angle,
)

__all__ = ["ConvexData", "AreaFit", "glint_samples", "convex_data", "design", "fit_areas", "relative_residuals",
           "magnitude_rss"]


@dataclass(frozen=True)
class ConvexData:
    """Observations prepared for convex inversion (float64, CPU or one device).

    Attributes:
        t_s: sample times ``(N,)`` (s from the epoch).
        sun, observer: unit vectors object → Sun and → observer ``(N, 3)`` (ecliptic J2000).
        alpha: phase angles ``(N,)`` (rad).
        y: intensities, each curve divided by its mean ``(N,)``.
        curve: light curve of each sample ``(N,)`` (int64); curves: their number ``C``.
        counts: samples per curve ``(C,)``.
        span_s: time from the first to the last sample (s).
        weight: per-sample weights ``(N,)`` on the intensity residuals of the fits (:func:`fit_areas`, the polish),
            or ``None`` (all 1): ``1/ỹ`` (:meth:`magnitude_weighted`) makes them magnitude residuals to first
            order, ``Δm ≈ −1.0857 Δỹ/ỹ``, the scale of magnitude noise.
    """

    t_s: Tensor
    sun: Tensor
    observer: Tensor
    alpha: Tensor
    y: Tensor
    curve: Tensor
    curves: int
    counts: Tensor
    span_s: float
    weight: Tensor | None = None

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def with_dtype(self, dtype: torch.dtype) -> ConvexData:
        """The same data with ``y``, ``alpha`` and the vectors in ``dtype`` (times stay float64)."""
        return replace(self, y=self.y.to(dtype), alpha=self.alpha.to(dtype), sun=self.sun.to(dtype),
                       observer=self.observer.to(dtype), weight=None if self.weight is None else self.weight.to(dtype))

    def magnitude_weighted(self) -> ConvexData:
        """The same data with the weights ``1/ỹ`` (``weight``): intensity residuals ``Δỹ`` weighted into relative
        ones ``Δỹ/ỹ ≈ −Δm/1.0857``, so that a fit minimises what magnitude noise makes Gaussian."""
        return replace(self, weight=1.0 / self.y)

    def weights(self) -> Tensor:
        """The weights ``(N,)`` (ones when ``weight`` is ``None``)."""
        return torch.ones_like(self.y) if self.weight is None else self.weight

    def curve_mean(self, values: Tensor) -> Tensor:
        """Per-curve means ``(…, C)`` of per-sample values ``(…, N)``."""
        sums = torch.zeros(*values.shape[:-1], self.curves, dtype=values.dtype, device=values.device)
        return sums.index_add_(-1, self.curve, values) / self.counts.to(values.dtype)


def glint_samples(obs: Observations, clip: float) -> Tensor:
    """The samples ``(N,)`` (bool) brighter than ``clip`` times their light curve's median intensity: a satellite's
    specular glints, flashes a few degrees of rotation wide that a model on fixed normals cannot time."""
    intensity = torch.pow(10.0, -0.4 * obs.mag.to(torch.float64))
    median = torch.stack([intensity[obs.curve == c].median() if bool((obs.curve == c).any())
                          else intensity.new_tensor(math.inf) for c in range(len(obs.curves))])
    return intensity > clip * median[obs.curve]


def convex_data(obs: Observations, *, glint_clip: float | None = None) -> ConvexData:
    """:class:`ConvexData` from observations with per-sample geometry (magnitudes → relative intensities: every
    curve is treated as relative, its scale unknown), without the samples :func:`glint_samples` finds when
    ``glint_clip`` is given. Raises ``ValueError`` without geometry."""
    if not obs.has_geometry:
        raise ValueError("convex inversion needs per-sample Sun and observer directions (none given)")
    obs = obs.to(dtype=torch.float64)
    if glint_clip is not None:
        obs = obs.select(torch.nonzero(~glint_samples(obs, glint_clip)).flatten())
    intensity = torch.pow(10.0, -0.4 * obs.mag)
    counts = obs.counts().to(obs.t.device)
    curves = len(obs.curves)
    mean = torch.zeros(curves, dtype=torch.float64, device=obs.t.device).index_add_(0, obs.curve, intensity)
    mean = mean / counts
    return ConvexData(t_s=obs.t, sun=obs.sun, observer=obs.observer, alpha=phase_angle(obs.sun, obs.observer),
                      y=intensity / mean[obs.curve], curve=obs.curve, curves=curves, counts=counts,
                      span_s=obs.span_s)


def design(data: ConvexData, normals: Tensor, scattering: Scattering | SatelliteScattering, *, lam: Tensor,
           beta: Tensor, period_s: Tensor, phi0: Tensor | None = None, dtype: torch.dtype | None = None) -> Tensor:
    """``G`` ``(B, N, M·K)`` of ``B`` spin states (``lam``, ``beta`` rad, ``period_s`` s, ``phi0`` rad, each
    ``(B,)``; ``phi0`` 0 by default): the brightness of a unit area on each normal ``(K, 3)`` and basis of the law
    (``M`` of them, basis-major) at each sample. The rotation is
    formed in ``lam``'s dtype (float64 over decades), the scattering in ``dtype`` (default: ``lam``'s; float32 is
    six times faster on a CPU and enough for a screen)."""
    phi0 = torch.zeros_like(lam) if phi0 is None else phi0
    dtype = dtype or lam.dtype
    spin = dict(lam=lam, beta=beta, period_s=period_s, phi0=phi0, t_s=data.t_s)
    sun = body_vectors(data.sun, **spin).to(dtype)
    obs = body_vectors(data.observer, **spin).to(dtype)
    return facet_brightness(normals.to(dtype), sun, obs, data.alpha.to(dtype), scattering)


@dataclass(frozen=True)
class AreaFit:
    """The linear fit of :func:`fit_areas` for ``B`` spin states.

    Attributes:
        areas: ``(B, K)`` non-negative areas, scaled so that the mean curve scale is 1.
        rss: residual sum of squares ``(B,)`` (relative intensity², closure term included).
        rms: ``sqrt(rss / N)`` ``(B,)``.
    """

    areas: Tensor
    rss: Tensor
    rms: Tensor


def _quadratic(G: Tensor, data: ConvexData, normals: Tensor, closure: float) -> tuple[Tensor, Tensor]:
    """``M`` ``(B, K, K)`` and ``c`` ``(B, K)`` of the profiled problem (module docstring), each residual
    weighted by ``data.weight`` (its rows of ``G`` and ``ỹ`` scaled)."""
    B, _, K = G.shape
    y = data.y
    if data.weight is not None:
        G, y = G * data.weight[:, None], y * data.weight
    U = torch.zeros(B, data.curves, K, dtype=G.dtype, device=G.device)
    U.index_add_(1, data.curve, G * y[:, None])                                 # Σ_{i∈c} ỹ_i G_ik
    yy = torch.zeros(data.curves, dtype=G.dtype, device=G.device).index_add_(0, data.curve, y * y)
    W = U / yy[:, None]
    M = G.transpose(1, 2) @ G - U.transpose(1, 2) @ W
    if closure > 0:
        scale = torch.diagonal(M, dim1=1, dim2=2).mean(-1)
        M = M + closure * scale[:, None, None] * (normals @ normals.T)
    return M, W.mean(1)


def _refine(M: Tensor, c: Tensor, a: Tensor, steps: int) -> Tensor:
    """``steps`` accelerated projected-gradient steps (FISTA with adaptive restart, Jacobi-preconditioned) on
    ``min aᵀ M a − 2 cᵀ a, a ≥ 0`` from ``a`` ``(B, K)``: they keep descending where the Newton iteration stalls on a
    near-singular ``M`` (close normals, several bases per normal)."""
    d = torch.sqrt(torch.diagonal(M, dim1=1, dim2=2).clamp_min(1e-300))
    Ms, cs = M / (d[:, :, None] * d[:, None, :]), c / d
    lipschitz = torch.linalg.eigvalsh(Ms)[:, -1:].clamp_min(1e-300)
    b = a * d
    y, t = b.clone(), torch.ones_like(lipschitz)
    for _ in range(steps):
        nxt = (y - ((Ms @ y[..., None])[..., 0] - cs) / lipschitz).clamp_min(0.0)
        t_next = 0.5 * (1.0 + torch.sqrt(1.0 + 4.0 * t * t))
        restart = ((y - nxt) * (nxt - b)).sum(-1, keepdim=True) > 0
        y = torch.where(restart, nxt, nxt + (t - 1.0) / t_next * (nxt - b))
        t = torch.where(restart, torch.ones_like(t), t_next)
        b = nxt
    return b / d


def fit_areas(G: Tensor, data: ConvexData, normals: Tensor, *, closure: float = 0.1,
              iterations: int = 12, refine: int = 0) -> AreaFit:
    """Non-negative areas of ``B`` spin states at once (module docstring; each residual times ``data.weight``
    when it is given: ``Σ_i w_i² ((G a)_i − t_c ỹ_i)²``), from their ``G`` ``(B, N, M·K)`` (float32
    or float64; the quadratic program is solved in float64) on ``normals`` ``(K, 3)``, ``M`` the law's bases (the
    closure term sums every basis's areas).

    The program ``min aᵀ M a − 2 cᵀ a, a ≥ 0`` is solved by a batched projected Newton iteration with a fixed count:
    the free set is every area that is positive or whose gradient is negative; the areas on it solve
    ``M_FF a_F = c_F`` (the rest are 0), then are clipped at 0. A few iterations fix the active set of a screen's
    candidate; the returned rss is that of the returned (feasible) areas, so an unconverged candidate only looks
    worse than it is. ``refine`` > 0 adds that many accelerated projected-gradient steps (:func:`_refine`), for
    near-singular programs (the satellite law's close ring normals and bases), where the Newton iteration stalls far
    from the optimum."""
    normals = normals.repeat(G.shape[-1] // normals.shape[0], 1)
    M, c = _quadratic(G, data.with_dtype(G.dtype), normals.to(G.dtype), closure)
    M, c = M.to(torch.float64), c.to(torch.float64)
    B, K = c.shape
    eye = torch.eye(K, dtype=M.dtype, device=M.device)
    jitter = 1e-9 * torch.diagonal(M, dim1=1, dim2=2).mean(-1)[:, None, None] * eye
    free = torch.ones(B, K, dtype=torch.bool, device=M.device)
    a = torch.zeros(B, K, dtype=M.dtype, device=M.device)
    steps = torch.tensor([1.0, 0.5, 0.25, 0.125, 1 / 16, 1 / 64, 0.0], dtype=M.dtype, device=M.device)
    for _ in range(iterations):
        both = free[:, :, None] & free[:, None, :]
        system = torch.where(both, M, torch.zeros_like(M)) + torch.where(free[:, None, :], 0.0, 1.0) * eye + jitter
        L, info = torch.linalg.cholesky_ex(system)
        if bool((info > 0).any()):                   # rounding made a near-singular system indefinite: more jitter
            L, _ = torch.linalg.cholesky_ex(system + 1e3 * jitter)
        x = torch.nan_to_num(torch.cholesky_solve(torch.where(free, c, 0.0)[..., None], L)[..., 0], nan=0.0)
        trial = (a[:, None, :] + steps[None, :, None] * (x - a)[:, None, :]).clamp_min(0.0)   # (B, T, K)
        # and the exact minimiser on the feasible segment from a to the clipped Newton point
        d = trial[:, 0] - a
        curvature = (d * (M * d[:, None, :]).sum(-1)).sum(-1)
        slope = (d * ((M * a[:, None, :]).sum(-1) - c)).sum(-1)
        t_star = (-slope / curvature.clamp_min(1e-300)).clamp(0.0, 1.0)
        trial = torch.cat([trial, (a + t_star[:, None] * d)[:, None, :]], 1)
        value = (trial * (trial @ M)).sum(-1) - 2.0 * (trial * c[:, None, :]).sum(-1)       # M symmetric
        a = trial[torch.arange(B, device=M.device), value.argmin(-1)]
        grad = (M * a[:, None, :]).sum(-1) - c
        free = (a > 0) | (grad < 0)
    if refine > 0:
        a = _refine(M, c, a, refine)
    ca = (c * a).sum(-1)
    quad = (a * (M * a[:, None, :]).sum(-1)).sum(-1)
    good = ca > 0
    # the best scale of the feasible a: rss = min_s (s² aᵀMa − 2 s cᵀa + …) normalised, i.e. aᵀMa / (cᵀa)²
    rss = torch.where(good, quad.clamp_min(0.0) / ca.clamp_min(1e-300) ** 2, torch.full_like(ca, math.inf))
    areas = a / torch.where(good, ca, torch.ones_like(ca))[:, None]
    return AreaFit(areas=areas, rss=rss, rms=torch.sqrt(rss / len(data)))


def relative_residuals(data: ConvexData, normals: Tensor, scattering: Scattering | SatelliteScattering, *,
                       lam: Tensor, beta: Tensor, period_s: Tensor, areas: Tensor) -> Tensor:
    """convexinv's residuals ``ỹ_i − L_i / L̄_c`` ``(B, N)`` of ``B`` models (areas ``(B, M·K)``)."""
    G = design(data, normals, scattering, lam=lam, beta=beta, period_s=period_s)
    L = (G * areas[:, None, :]).sum(-1)
    return data.y - L / data.curve_mean(L)[:, data.curve]


def magnitude_rss(data: ConvexData, normals: Tensor, scattering: Scattering, *, lam: Tensor, beta: Tensor,
                  period_s: Tensor, areas: Tensor) -> Tensor:
    """Residual sum of squares in magnitudes (mag², over all samples) of ``B`` models (areas ``(B, K)``), each
    curve's zero point profiled (its mean residual removed): ``Σ_i (d_i − d̄_c)²`` with
    ``d_i = −2.5 log10 ỹ_i + 2.5 log10 L_i``. With the noise's σ (mag), ``rss / (2σ²)`` is a negative
    log-likelihood in nats up to a constant: what tells two fits apart on the data's own scale ``(B,)``."""
    G = design(data, normals, scattering, lam=lam, beta=beta, period_s=period_s)
    L = (G * areas[:, None, :]).sum(-1)
    d = 2.5 * torch.log10(L.clamp_min(1e-300)) - 2.5 * torch.log10(data.y)
    d = d - data.curve_mean(d)[:, data.curve]
    return (d * d).sum(-1)
