"""The nonlinear polish of a convex inversion's spin state and shape, several starts at once.

**Polish** (:func:`polish`): the convexinv objective itself, the relative-intensity residuals with each curve
normalised by its model mean, ``r_i = ỹ_i − L_i / L̄_c``, over ``x = (λ, β, P, log a)`` by the project's
Levenberg–Marquardt core (:func:`~lightcurve_gp.inference.solver.batch_least_squares`) with a Jacobian in closed
form, the closure term as three more residuals and a weak prior on the log areas. Its rms, ``sqrt(Σ r² / N)``, is
convexinv's "rms". With the data's weights (:attr:`~lightcurve_gp.inference.convex_fit.ConvexData.weight`, e.g.
``1/ỹ``: magnitude-consistent) each residual is ``w_i r_i`` and ``fit_rms`` is their rms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.inference.convex_fit import ConvexData, design, relative_residuals
from lightcurve_gp.inference.solver import GaussianPrior, LeastSquaresOptions, batch_least_squares
from lightcurve_gp.photometry.convex import SatelliteScattering, Scattering, area_normals, body_vectors, facet_terms

__all__ = ["Polished", "PolishResidual", "polish"]


@dataclass(frozen=True)
class Polished:
    """Spin states and shapes after :func:`polish`.

    Attributes:
        lam, beta: pole (rad) ``(B,)``, ``λ`` in [0, 2π), ``β`` as the polish ended (past ±π/2 when it crossed the
            ecliptic's pole: folding it would turn the body frame by π about the axis and leave ``areas`` another
            body's); period_s: sidereal period (s) ``(B,)``.
        areas: ``(B, M·K)`` areas (relative units, summing to 1; basis-major).
        rms: convexinv's rms of the relative-intensity residuals ``(B,)``.
        fit_rms: the rms of the weighted residuals ``w_i r_i``, what the polish minimised ``(B,)`` (``rms`` when the
            data have no weights).
        period_sigma_s: the period's 1σ from the Laplace approximation with the residuals' rms as noise ``(B,)``.
        iterations: Levenberg–Marquardt iterations taken ``(B,)``.
    """

    lam: Tensor
    beta: Tensor
    period_s: Tensor
    areas: Tensor
    rms: Tensor
    fit_rms: Tensor
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
        self.inv_scale = data.weights() / sigma                       # (N,): whitening of each data residual
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
        r = (self.data.y - L / mean) * self.inv_scale
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
        spin_jac = -(dL - ratio * dL_mean) / mean[..., None] * self.inv_scale[:, None]
        spin_jac = torch.cat([spin_jac, torch.zeros(A, 3 + self.diff.shape[0], 3, dtype=x.dtype, device=x.device)], 1)
        # ∂(L_i / L̄_c)/∂log a_k = a_k (G_ik − (L_i / L̄_c) Ḡ_ck) / L̄_c, Ḡ_ck the curve mean of G_·k
        Gbar = self.data.curve_mean(G.transpose(1, 2)).transpose(1, 2)[:, self.data.curve]  # (A, N, K)
        dratio = (G - ratio * Gbar) * a[:, None, :] / mean[..., None]
        s = a.sum(-1, keepdim=True)
        centroid = (a @ self.normals) / s                                                   # (A, 3)
        dclose = self.weight * a[:, None, :] * (self.normals.T[None] - centroid[..., None]) / s[..., None]
        area_jac = torch.cat([-dratio * self.inv_scale[:, None], dclose], 1)
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

    The residuals are whitened by ``sigma`` (relative intensity; times the data's weights when given); a weak
    Gaussian prior of standard deviation ``area_prior_std`` on each log area about its start keeps areas that no
    sample sees determined;
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
    rw = r * data.weights()
    fit_rms = torch.sqrt((rw * rw).mean(-1))
    # the Laplace 1σ of x_P, rescaled from the assumed sigma to the fit's rms
    var_phase = torch.diagonal(result.covariance, dim1=1, dim2=2)[:, 2] * (fit_rms / sigma) ** 2
    period_sigma = period * period * torch.sqrt(var_phase.clamp_min(0)) / (2 * math.pi * data.span_s)
    period_sigma = torch.where(failed, torch.full_like(period_sigma, math.nan), period_sigma)
    # β is left as the polish ended, past ±π/2 when it crossed the ecliptic's pole: (λ + π, π − β) is the same axis
    # but a body frame turned by π about it, in which these areas on these normals are another body
    return Polished(lam=torch.remainder(lam_, 2 * math.pi), beta=beta_, period_s=period,
                    areas=a / a.sum(-1, keepdim=True), rms=rms, fit_rms=fit_rms, period_sigma_s=period_sigma,
                    iterations=result.iterations)
