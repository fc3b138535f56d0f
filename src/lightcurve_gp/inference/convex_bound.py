"""The Cramér–Rao bound of a convex inversion's pole and period, the shape and the zero points profiled out.

Model (in magnitudes, where the noise is Gaussian): sample ``i`` of light curve ``c`` is
``m_i = −2.5 log10 L_i(λ, β, P, a) + z_c + v_i``, ``v_i ~ N(0, σ_i²)``, with ``L = G a``
(:func:`~lightcurve_gp.inference.convex_fit.design`: the areas ``a`` on fixed normals, every basis of the law) and
one unknown zero point ``z_c`` per curve (every curve relative). The unknowns are ``θ = (λ, β, P; a_F, z)``: the
spin, the *free* areas ``a_F`` (an area at its bound 0 is held there: at a constrained optimum the active set is
known to first order, so it carries no information and costs none) and the zero points.

Fisher information ``F = Jᵀ Σ⁻¹ J``, ``J_i = ∂m_i/∂θ``: ``∂m_i/∂a_k = −(2.5/ln 10) G_ik / L_i``,
``∂m_i/∂z_c = [i ∈ c]`` and ``∂m_i/∂(λ, β, P) = −(2.5/ln 10) ∂L_i/∂(λ, β, P) / L_i`` by forward-mode automatic
differentiation of the rendering (exact to rounding). The nuisance block is singular (a common scale of the areas is
a common zero point), so the spin's bound is the Schur complement computed as a projection:
``F_spin = J_sᵀ (I − Π_n) J_s`` with ``Π_n`` the orthogonal projection onto the whitened nuisance columns (a
least-squares solve, rank-revealing), and ``cov(λ̂, β̂, P̂) ⪰ F_spin⁻¹`` — the spin block of ``F⁻¹`` wherever the
nuisance is identifiable, and what any unbiased estimator that knows nothing of the shape and the zero points can
reach. The rotation phase at the epoch is not an unknown: the areas absorb it, as the search assumes.

The pole's error lives on the sphere: in the tangent plane ``(cos β δλ, δβ)`` its covariance is ``D C_pole D``,
``D = diag(cos β, 1)``. :func:`circular_probability` is the chance that a Gaussian error of a 2 × 2 covariance lies
within a radius (one quadrature over the direction), :func:`circular_radius` the radius that holds a probability.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.autograd.forward_ad as fwad
from torch import Tensor

from lightcurve_gp.inference.convex_fit import ConvexData, design
from lightcurve_gp.photometry.convex import SatelliteScattering, Scattering

__all__ = ["ConvexBound", "magnitude_jacobian", "convex_bound", "circular_probability", "circular_radius"]

#: ``2.5 / ln 10``: magnitudes per unit of ``ln`` intensity
MAG_PER_LN = 2.5 / math.log(10.0)


@dataclass(frozen=True)
class ConvexBound:
    """The bound of one spin state (module docstring).

    Attributes:
        covariance: ``(3, 3)`` the bound on ``(λ, β, P)`` (rad², rad·s, s²), shape and zero points profiled.
        pole_covariance_deg2: ``(2, 2)`` the pole's in the tangent plane ``(cos β δλ, δβ)`` (deg²).
        pole_sigma_deg: ``sqrt(trace)`` of that: the pole's rms angular error at the bound (deg).
        pole_axes_deg: ``(2,)`` its 1σ semi-axes, the larger first (deg).
        pole_radius95_deg: the radius about the pole holding 95 % of the bound's Gaussian (deg).
        period_sigma_s: the period's 1σ (s).
        free_areas: areas counted as unknowns; curves: zero points.
    """

    covariance: Tensor
    pole_covariance_deg2: Tensor
    pole_sigma_deg: float
    pole_axes_deg: Tensor
    pole_radius95_deg: float
    period_sigma_s: float
    free_areas: int
    curves: int

    def within(self, radius_deg: float) -> float:
        """The chance that the pole's error at the bound is below ``radius_deg``."""
        return circular_probability(self.pole_covariance_deg2, radius_deg)


def magnitude_jacobian(data: ConvexData, normals: Tensor, scattering: Scattering | SatelliteScattering, *,
                       lam: float, beta: float, period_s: float, areas: Tensor,
                       phi0: float = 0.0) -> tuple[Tensor, Tensor]:
    """``∂m/∂(λ, β, P)`` ``(N, 3)`` (mag per rad, rad, s) and ``∂m/∂a`` ``(N, M·K)`` (mag per unit area; ``areas``
    ``(M·K,)`` in ``design``'s units) of the model magnitudes ``m = −2.5 log10 L`` of one spin state (float64),
    the spin's by forward-mode differentiation of :func:`~lightcurve_gp.inference.convex_fit.design`."""
    areas = areas.to(torch.float64)
    spin = torch.tensor([lam, beta, period_s], dtype=torch.float64)
    phi = torch.tensor([phi0], dtype=torch.float64)
    G0 = design(data, normals, scattering, lam=spin[:1], beta=spin[1:2], period_s=spin[2:], phi0=phi)[0]
    L = G0 @ areas
    columns = []
    for j in range(3):
        with fwad.dual_level():
            dual = fwad.make_dual(spin, torch.eye(3, dtype=torch.float64)[j])
            G = design(data, normals, scattering, lam=dual[:1], beta=dual[1:2], period_s=dual[2:], phi0=phi)[0]
            columns.append(fwad.unpack_dual(G @ areas).tangent)
    dL = torch.stack(columns, -1)                                                     # (N, 3)
    return -MAG_PER_LN * dL / L[:, None], -MAG_PER_LN * G0 / L[:, None]


def convex_bound(data: ConvexData, normals: Tensor, scattering: Scattering | SatelliteScattering, *, lam: float,
                 beta: float, period_s: float, areas: Tensor, sigma_mag: float | Tensor, phi0: float = 0.0,
                 active_floor: float = 1e-3) -> ConvexBound:
    """The bound of the spin state (``lam``, ``beta`` rad, ``period_s`` s, ``phi0`` rad) with ``areas``
    ``(M·K,)`` on ``normals`` ``(K, 3)`` from the samples of ``data`` (its geometry, times and curves; its
    intensities are not used) with magnitude noise ``sigma_mag`` (mag, a number or ``(N,)``). Areas below
    ``active_floor`` times the largest are at their bound and held fixed (module docstring)."""
    J_spin, J_area = magnitude_jacobian(data, normals, scattering, lam=lam, beta=beta, period_s=period_s,
                                        areas=areas, phi0=phi0)
    free = areas > active_floor * areas.max()
    zero_points = torch.nn.functional.one_hot(data.curve, data.curves).to(torch.float64)
    sigma = torch.as_tensor(sigma_mag, dtype=torch.float64).expand(len(data))
    J_s = J_spin / sigma[:, None]
    J_n = torch.cat([J_area[:, free], zero_points], -1) / sigma[:, None]
    scale = J_n.norm(dim=0).clamp_min(1e-300)                        # columns of unit norm: a fair rank cut
    coef = torch.linalg.lstsq(J_n / scale, J_s, rcond=1e-10, driver="gelsd").solution
    R = J_s - (J_n / scale) @ coef                                   # the spin's columns, nuisance projected out
    C = torch.linalg.inv(R.T @ R)
    C = 0.5 * (C + C.T)
    D = torch.diag(torch.tensor([math.cos(beta), 1.0], dtype=torch.float64))
    pole = D @ C[:2, :2] @ D * math.degrees(1.0) ** 2
    axes = torch.sqrt(torch.linalg.eigvalsh(pole).clamp_min(0.0)).flip(0)
    return ConvexBound(covariance=C, pole_covariance_deg2=pole, pole_sigma_deg=float(torch.sqrt(torch.trace(pole))),
                       pole_axes_deg=axes, pole_radius95_deg=circular_radius(pole, 0.95),
                       period_sigma_s=float(torch.sqrt(C[2, 2])), free_areas=int(free.sum()), curves=data.curves)


def circular_probability(covariance: Tensor, radius: float, *, directions: int = 720) -> float:
    """``P(|x| ≤ radius)`` for ``x ~ N(0, covariance)`` in 2-D (``covariance`` ``(2, 2)``, positive definite):
    ``(1 / 2π√det) ∫ (1 − exp(−r² q(θ)/2)) / q(θ) dθ`` with ``q(θ) = uᵀ Σ⁻¹ u``, ``u`` the unit vector at ``θ``
    (the radial integral in closed form; the periodic integrand's trapezoid rule converges geometrically)."""
    cov = covariance.to(torch.float64)
    theta = torch.arange(directions, dtype=torch.float64) * (2 * math.pi / directions)
    u = torch.stack([torch.cos(theta), torch.sin(theta)], -1)
    q = (u @ torch.linalg.inv(cov) * u).sum(-1)
    integrand = -torch.expm1(-0.5 * radius * radius * q) / q
    return float(integrand.mean() / torch.sqrt(torch.linalg.det(cov)))


def circular_radius(covariance: Tensor, probability: float) -> float:
    """The radius within which ``x ~ N(0, covariance)`` (2-D) lies with ``probability``: bisection on
    :func:`circular_probability` between the one-dimensional and the isotropic extremes' brackets."""
    largest = float(torch.linalg.eigvalsh(covariance.to(torch.float64))[-1])
    lo, hi = 0.0, math.sqrt(-2.0 * math.log1p(-probability) * 2.0 * largest) + 1e-300
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if circular_probability(covariance, mid) < probability else (lo, mid)
    return 0.5 * (lo + hi)
