"""The convex shape profiled out: non-negative areas on fixed normals for many spin states at once, and the
nonlinear polish of (pole, period, areas).

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

**Polish** (:func:`polish`): the convexinv objective itself, the relative-intensity residuals with each curve
normalised by its model mean, ``r_i = ỹ_i − L_i / L̄_c``, over ``x = (λ, β, P, log a)`` by the project's
Levenberg–Marquardt core (:func:`~lightcurve_gp.inference.solver.batch_least_squares`) with a Jacobian in closed
form, the closure term as three more residuals and a weak prior on the log areas. Its rms, ``sqrt(Σ r² / N)``, is
convexinv's "rms".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from lightcurve_gp.inference.solver import GaussianPrior, LeastSquaresOptions, batch_least_squares
from lightcurve_gp.observations.observations import Observations
from lightcurve_gp.photometry.convex import (
    SatelliteScattering,
    Scattering,
    area_normals,
    body_vectors,
    facet_brightness,
    facet_terms,
    phase_angle,
)

__all__ = ["ConvexData", "AreaFit", "Polished", "PolishResidual", "glint_samples", "convex_data", "design", "fit_areas",
           "relative_residuals", "magnitude_rss", "polish"]


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

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def with_dtype(self, dtype: torch.dtype) -> ConvexData:
        """The same data with ``y``, ``alpha`` and the vectors in ``dtype`` (times stay float64)."""
        return replace(self, y=self.y.to(dtype), alpha=self.alpha.to(dtype), sun=self.sun.to(dtype),
                       observer=self.observer.to(dtype))

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
    """``M`` ``(B, K, K)`` and ``c`` ``(B, K)`` of the profiled problem (module docstring)."""
    B, _, K = G.shape
    U = torch.zeros(B, data.curves, K, dtype=G.dtype, device=G.device)
    U.index_add_(1, data.curve, G * data.y[:, None])                            # Σ_{i∈c} ỹ_i G_ik
    yy = torch.zeros(data.curves, dtype=G.dtype, device=G.device).index_add_(0, data.curve, data.y * data.y)
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
    """Non-negative areas of ``B`` spin states at once (module docstring), from their ``G`` ``(B, N, M·K)`` (float32
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


@dataclass(frozen=True)
class Polished:
    """Spin states and shapes after :func:`polish`.

    Attributes:
        lam, beta: pole (rad) ``(B,)``; period_s: sidereal period (s) ``(B,)``.
        areas: ``(B, M·K)`` areas (relative units, summing to 1; basis-major).
        rms: convexinv's rms of the relative-intensity residuals ``(B,)``.
        period_sigma_s: the period's 1σ from the Laplace approximation with the residuals' rms as noise ``(B,)``.
        iterations: Levenberg–Marquardt iterations taken ``(B,)``.
    """

    lam: Tensor
    beta: Tensor
    period_s: Tensor
    areas: Tensor
    rms: Tensor
    period_sigma_s: Tensor
    iterations: Tensor


class PolishResidual:
    """Whitened residuals of :func:`polish` and their Jacobian (analytic in the shape, central differences in
    the spin); ``x = (λ, β, x_P, c)`` with ``log a = basis c`` (``basis`` ``(K, J)``; ``None``: the identity,
    ``c = log a``)."""

    def __init__(self, data: ConvexData, normals: Tensor, scattering: Scattering | SatelliteScattering,
                 period0_s: Tensor, sigma: float, closure: float, smoothness: float = 0.0, neighbours: int = 6,
                 basis: Tensor | None = None) -> None:
        if basis is not None and isinstance(scattering, SatelliteScattering):
            raise ValueError("convex.shape_degree: a spherical-harmonic shape needs the asteroid law (one area per "
                             "normal); the satellite law has an area per normal and basis")
        self.data, self.design_normals, self.scattering, self.p0 = data, normals, scattering, period0_s
        self.basis = basis
        normals = area_normals(normals, scattering)                  # (M·K, 3): closure and smoothness per area
        self.normals = normals
        self.sigma, self.weight = sigma, math.sqrt(closure * len(data))
        # smoothness: smoothness · (log a_i − log a_j) for each normal and its nearest neighbours (whitened rows)
        K = normals.shape[0]
        near = torch.topk(normals @ normals.T, min(neighbours + 1, K), dim=-1).indices[:, 1:]
        pairs = {(min(i, j), max(i, j)) for i in range(K) for j in near[i].tolist()}
        diff = torch.zeros(len(pairs) if smoothness > 0 else 0, K, dtype=normals.dtype, device=normals.device)
        for row, (i, j) in enumerate(sorted(pairs) if smoothness > 0 else []):
            diff[row, i], diff[row, j] = smoothness, -smoothness
        self.diff = diff
        self.diff_jac = diff if basis is None else diff @ basis          # the rows' Jacobian in x's shape part

    def log_areas(self, x: Tensor) -> Tensor:
        """``log a`` ``(A, K)`` of parameters ``x`` ``(A, 3 + J)``."""
        return x[:, 3:] if self.basis is None else x[:, 3:] @ self.basis.T

    def spin(self, x: Tensor, rows: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        period = 1.0 / (1.0 / self.p0[rows] - x[:, 2] / (2 * math.pi * self.data.span_s))
        return x[:, 0], x[:, 1], period

    def _parts(self, G: Tensor, a: Tensor) -> tuple[Tensor, Tensor]:
        L = (G * a[:, None, :]).sum(-1)
        mean = self.data.curve_mean(L)[:, self.data.curve]
        r = (self.data.y - L / mean) / self.sigma
        closing = self.weight * (a @ self.normals) / a.sum(-1, keepdim=True)
        return torch.cat([r, closing, torch.log(a) @ self.diff.T], -1), mean

    def _design(self, x: Tensor, rows: Tensor) -> Tensor:
        lam, beta, period = self.spin(x, rows)
        return design(self.data, self.design_normals, self.scattering, lam=lam, beta=beta, period_s=period)

    def __call__(self, x: Tensor, rows: Tensor) -> Tensor:
        return self._parts(self._design(x, rows), torch.exp(self.log_areas(x)))[0]

    def _vectors(self, x: Tensor, rows: Tensor) -> tuple[Tensor, Tensor]:
        lam, beta, period = self.spin(x, rows)
        spin = dict(lam=lam, beta=beta, period_s=period, phi0=torch.zeros_like(lam), t_s=self.data.t_s)
        return body_vectors(self.data.sun, **spin), body_vectors(self.data.observer, **spin)

    def linearize(self, x: Tensor, rows: Tensor) -> tuple[Tensor, Tensor]:
        """Residuals and Jacobian: the body-frame vectors' derivatives in the spin by central differences (cheap:
        ``(A, N, 3)``), the rest in closed form from the law's partial derivatives in ``μ``, ``μ0`` and ``ν``
        (:meth:`~lightcurve_gp.photometry.convex.Scattering.terms`)."""
        A = x.shape[0]
        h = torch.tensor([1e-6, 1e-6, 1e-6], dtype=x.dtype, device=x.device)
        shifts = torch.cat([torch.zeros(1, 3, dtype=x.dtype), torch.diag(h), -torch.diag(h)])   # (7, 3)
        xs = x[None, :, :3] + shifts[:, None, :]
        sun_all, obs_all = self._vectors(xs.reshape(7 * A, 3), rows.repeat(7))
        sun_all, obs_all = sun_all.reshape(7, A, -1, 3), obs_all.reshape(7, A, -1, 3)
        dsun = (sun_all[1:4] - sun_all[4:7]) / (2 * h[:, None, None, None])                     # (3, A, N, 3)
        dobs = (obs_all[1:4] - obs_all[4:7]) / (2 * h[:, None, None, None])
        terms, h, norm = facet_terms(self.design_normals, sun_all[0], obs_all[0], self.data.alpha, self.scattering,
                                     derivatives=True)
        G = terms.value.flatten(-2)                                                               # (A, N, M·K)
        a = torch.exp(self.log_areas(x))
        per_basis = a.reshape(A, 1, *terms.value.shape[-2:])                                      # (A, 1, M, K)
        d_mu, d_mu0 = (terms.d_mu * per_basis).sum(-2), (terms.d_mu0 * per_basis).sum(-2)        # ∂L/∂μ_k (A, N, K)
        grad_obs, grad_sun = d_mu @ self.design_normals, d_mu0 @ self.design_normals              # (A, N, 3)
        if terms.d_nu is not None:                  # ∂ν_k/∂v = ∂ν_k/∂s = (n_k − ν_k h)/|s + v|
            d_nu = (terms.d_nu * per_basis).sum(-2)
            nu = h @ self.design_normals.T
            via_h = (d_nu @ self.design_normals - (d_nu * nu).sum(-1, keepdim=True) * h) / norm
            grad_obs, grad_sun = grad_obs + via_h, grad_sun + via_h
        dL = ((grad_obs[None] * dobs).sum(-1) + (grad_sun[None] * dsun).sum(-1)).permute(1, 2, 0)  # (A, N, 3)
        r, mean = self._parts(G, a)
        L = (G * a[:, None, :]).sum(-1)
        ratio = (L / mean)[..., None]
        dL_mean = self.data.curve_mean(dL.transpose(1, 2)).transpose(1, 2)[:, self.data.curve]
        spin_jac = -(dL - ratio * dL_mean) / mean[..., None] / self.sigma
        spin_jac = torch.cat([spin_jac, torch.zeros(A, 3 + self.diff.shape[0], 3, dtype=x.dtype, device=x.device)], 1)
        # ∂(L_i / L̄_c)/∂log a_k = a_k (G_ik − (L_i / L̄_c) Ḡ_ck) / L̄_c, Ḡ_ck the curve mean of G_·k
        Gbar = self.data.curve_mean(G.transpose(1, 2)).transpose(1, 2)[:, self.data.curve]  # (A, N, K)
        dratio = (G - ratio * Gbar) * a[:, None, :] / mean[..., None]
        s = a.sum(-1, keepdim=True)
        centroid = (a @ self.normals) / s                                                   # (A, 3)
        dclose = self.weight * a[:, None, :] * (self.normals.T[None] - centroid[..., None]) / s[..., None]
        area_jac = torch.cat([-dratio / self.sigma, dclose], 1)
        if self.basis is not None:
            area_jac = area_jac @ self.basis
        area_jac = torch.cat([area_jac, self.diff_jac.expand(A, *self.diff_jac.shape)], 1)
        return r, torch.cat([spin_jac, area_jac], -1)


def polish(data: ConvexData, normals: Tensor, scattering: Scattering | SatelliteScattering, *, lam: Tensor,
           beta: Tensor, period_s: Tensor, areas: Tensor, closure: float = 0.1, iterations: int = 30,
           sigma: float = 0.01, area_prior_std: float = 3.0, smoothness: float = 0.0,
           basis: Tensor | None = None) -> Polished:
    """Levenberg–Marquardt on ``(λ, β, P, log a)`` of ``B`` starts at once (module docstring), or with ``basis``
    ``(K, J)`` on ``(λ, β, P, c)``, ``log a = basis c`` (e.g. :func:`~lightcurve_gp.photometry.convex.real_harmonics`:
    convexinv's smooth shape, ``J`` parameters instead of ``K``; ``c`` starts at the least-squares fit of the
    floored start's log areas and the prior is on ``c``; the asteroid law only).

    The residuals are whitened by ``sigma`` (relative intensity); a weak Gaussian prior of standard deviation
    ``area_prior_std`` on each log area about its start keeps areas that no sample sees determined;
    ``smoothness`` > 0 adds ``smoothness · (log a_i − log a_j)`` for every normal and its six nearest (whitened
    rows: a Laplacian-like prior that makes the Gaussian image smooth, as a low-degree expansion does). The period is
    scaled to a phase change over the data's span, ``x_P = 2π span (1/P₀ − 1/P)`` (rad), so every coordinate is
    O(1); the areas start at ``max(a, 1e-3 max a)`` (a zero area cannot leave zero in log space). A start whose
    polish ends with no finite rms or a non-positive period is returned as it started (its period's 1σ NaN)."""
    p0 = period_s.to(torch.float64)
    floor = 1e-3 * areas.max(-1, keepdim=True).values
    log_a = torch.log(torch.maximum(areas, floor) / areas.sum(-1, keepdim=True))
    if basis is not None:
        log_a = torch.linalg.lstsq(basis, log_a.T).solution.T
    x0 = torch.cat([lam[:, None], beta[:, None], torch.zeros_like(lam)[:, None], log_a], -1)
    precision = torch.cat([torch.zeros(3, dtype=x0.dtype, device=x0.device),
                           torch.full((log_a.shape[1],), area_prior_std ** -2, dtype=x0.dtype, device=x0.device)])
    residual = PolishResidual(data, normals, scattering, p0, sigma, closure, smoothness, basis=basis)
    options = LeastSquaresOptions(iterations=iterations, jacobian="provided", tolerance=1e-8,
                                  covariance="solution")
    result = batch_least_squares(residual, x0, prior=GaussianPrior.independent(x0, precision), options=options)
    rows = torch.arange(x0.shape[0], device=x0.device)
    x = result.x
    lam_, beta_, period = residual.spin(x, rows)
    r = relative_residuals(data, normals, scattering, lam=lam_, beta=beta_, period_s=period,
                           areas=torch.exp(residual.log_areas(x)))
    rms = torch.sqrt((r * r).mean(-1))
    failed = ~torch.isfinite(rms) | ~(period > 0)         # a step that left the model (data the law cannot fit)
    if bool(failed.any()):                                 # keeps its start, its period's 1σ unknown
        x = torch.where(failed[:, None], x0, x)
        lam_, beta_, period = residual.spin(x, rows)
        r = relative_residuals(data, normals, scattering, lam=lam_, beta=beta_, period_s=period,
                               areas=torch.exp(residual.log_areas(x)))
        rms = torch.sqrt((r * r).mean(-1))
    a = torch.exp(residual.log_areas(x))
    # the Laplace 1σ of x_P, rescaled from the assumed sigma to the fit's rms
    var_phase = torch.diagonal(result.covariance, dim1=1, dim2=2)[:, 2] * (rms / sigma) ** 2
    period_sigma = period * period * torch.sqrt(var_phase.clamp_min(0)) / (2 * math.pi * data.span_s)
    period_sigma = torch.where(failed, torch.full_like(period_sigma, math.nan), period_sigma)
    # a pole past a geographic pole of the grid: fold β back into [−π/2, π/2]
    flip = beta_.abs() > math.pi / 2
    lam_ = torch.where(flip, lam_ + math.pi, lam_)
    beta_ = torch.where(flip, torch.sign(beta_) * math.pi - beta_, beta_)
    return Polished(lam=torch.remainder(lam_, 2 * math.pi), beta=beta_, period_s=period,
                    areas=a / a.sum(-1, keepdim=True), rms=rms, period_sigma_s=period_sigma,
                    iterations=result.iterations)
