"""A convex body as its Gaussian image, its scattering law and its principal-axis rotation (convex inversion).

A convex body is given, up to translation, by its *Gaussian image*: non-negative areas ``a_k`` on a fixed set of
outward facet normals ``n_k`` (Minkowski). Its disk-integrated brightness under a Sun direction ``s`` and an
observer direction ``e`` (unit vectors in the body frame) is linear in the areas:

    L = f(α) Σ_k a_k S(μ_k, μ0_k) [μ_k > 0, μ0_k > 0],   μ_k = n_k·e,  μ0_k = n_k·s,

with the Lommel–Seeliger plus ``c``·Lambert law ``S(μ, μ0) = μ μ0 / (μ + μ0) + c μ μ0`` and the phase function
``f(α) = a exp(−α/d) + k α + 1`` (α the phase angle in rad) of Kaasalainen, Torppa & Muinonen (2001). Only facets lit
and seen count; for a convex body no facet shadows another, so the sum is exact.

A satellite's facets reflect specularly too: :class:`SatelliteScattering` is a sum of Ashikhmin–Shirley *bases*, each
with its own non-negative areas on the same normals, ``L = Σ_m Σ_k a_mk S_m(μ_k, μ0_k, ν_k)`` (``ν_k = n_k·h``, ``h``
the half-angle vector): the diffuse term and one specular lobe per fixed exponent (module :mod:`.brdf`; with
``n_u = n_v = n`` the lobe is ``(n·h)^n`` and, since ``v·h = cos(α/2)``, ``c_s μ μ0 = (n+1)/(8π) F(α)/cos(α/2)
ν^n min(μ, μ0)``). The brightness stays linear in the ``M·K`` areas (basis-major: the areas of basis ``m`` are
``a[m·K:(m+1)·K]``), so the areas are still a non-negative least-squares problem per spin state. ``ρ(1 − F0)`` of
a material is absorbed by its diffuse area, the Fresnel reflectance ``F0`` of the lobes is fixed.

Rotation about the principal axis of largest inertia: pole (λ, β) in the ecliptic frame, sidereal period ``P``,
rotation phase ``φ0`` at ``t = 0``. A vector ``v`` in the ecliptic frame has the body coordinates

    v_body = R_z(φ0 + 2π t / P) R_y(90° − β) R_z(λ) v,

with the passive (coordinate) rotations ``R_z(θ) = [[cos θ, sin θ, 0], [−sin θ, cos θ, 0], [0, 0, 1]]`` and
``R_y(θ) = [[cos θ, 0, −sin θ], [0, 1, 0], [sin θ, 0, cos θ]]``: the pole becomes the body ``z`` axis and the
body turns prograde about it. It is closed form at any ``t`` (decades: the phase is formed in float64).

A smooth Gaussian image (convexinv's shape): ``a_k = exp(Σ_lm c_lm Y_lm(n_k))`` with the real spherical harmonics
``Y_lm`` up to a degree ``D`` (``(D + 1)²`` coefficients; :func:`real_harmonics` gives the basis ``Y`` with
``log a = Y c``).

Shapes: ``(B, …)`` batches of spin states, ``(N, 3)`` per-sample unit vectors, ``(K, 3)`` normals.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from scipy.special import sph_harm_y
from torch import Tensor

from lightcurve_gp.photometry.brdf import DIFFUSE_SCALE, exp_floor

__all__ = ["Scattering", "SatelliteScattering", "Terms", "fibonacci_normals", "ring_normals", "area_normals",
           "real_harmonics", "spin_matrices", "body_vectors", "facet_brightness", "facet_terms", "brightness",
           "phase_angle", "pole_vector", "pole_angles", "folded_pole"]


@dataclass(frozen=True)
class Scattering:
    """Lommel–Seeliger + ``lambert``·Lambert with the phase function ``a exp(−α/d) + k α + 1`` (module docstring;
    convexinv's example: ``lambert = 0.1, a = 0.5, d = 0.1, k = −0.5``)."""

    lambert: float = 0.1
    amplitude: float = 0.5
    width_rad: float = 0.1
    slope: float = -0.5

    def phase_function(self, alpha: Tensor) -> Tensor:
        """``f(α)`` for phase angles ``alpha`` (rad), any shape."""
        return self.amplitude * torch.exp(-alpha / self.width_rad) + self.slope * alpha + 1.0

    def law(self, mu: Tensor, mu0: Tensor) -> Tensor:
        """``S(μ, μ0)`` where both are positive, else 0 (any broadcastable shapes): with both clamped at 0 the
        product vanishes wherever either does."""
        mu, mu0 = mu.clamp_min(0.0), mu0.clamp_min(0.0)
        product = mu * mu0
        return product * (1.0 / (mu + mu0).clamp_min(1e-30) + self.lambert)

    bases = 1
    uses_half_angle = False

    def basis_names(self) -> tuple[str, ...]:
        """One name per basis (the areas' column names)."""
        return ("lommel_seeliger",)

    def terms(self, mu: Tensor, mu0: Tensor, nu: Tensor | None, alpha: Tensor, *, derivatives: bool = False
              ) -> Terms:
        """The brightness of a unit area and (``derivatives``) its partial derivatives in ``μ`` and ``μ0``, each
        ``(B, N, 1, K)`` from ``mu``, ``mu0`` ``(B, N, K)`` and ``alpha`` ``(N,)``; ``nu`` is not used.
        ``∂S/∂μ = f(α) (μ0²/(μ + μ0)² + c μ0)`` and its twin, 0 unless lit and seen."""
        f = self.phase_function(alpha)[:, None]
        value = (self.law(mu, mu0) * f)[:, :, None]
        if not derivatives:
            return Terms(value)
        mu, mu0 = mu.clamp_min(0.0), mu0.clamp_min(0.0)
        lit = (mu > 0) & (mu0 > 0)
        total = torch.where(lit, mu + mu0, 1.0)
        d_mu = torch.where(lit, f * (mu0 * mu0 / (total * total) + self.lambert * mu0), 0.0)
        d_mu0 = torch.where(lit, f * (mu * mu / (total * total) + self.lambert * mu), 0.0)
        return Terms(value, d_mu[:, :, None], d_mu0[:, :, None], None)


class Terms(NamedTuple):
    """A law's per-basis brightness of a unit area ``value`` ``(B, N, M, K)`` and, when asked, its partial
    derivatives in ``μ = n·v``, ``μ0 = n·s`` and ``ν = n·h`` (same shape; ``d_nu`` ``None`` for a law without
    ``h``)."""

    value: Tensor
    d_mu: Tensor | None = None
    d_mu0: Tensor | None = None
    d_nu: Tensor | None = None


def _pow5(x: Tensor) -> Tensor:
    x2 = x * x
    return x2 * x2 * x


@dataclass(frozen=True)
class SatelliteScattering:
    """Ashikhmin–Shirley bases (module docstring): the diffuse term (``diffuse``) and one isotropic specular lobe
    per exponent in ``exponents`` with the Fresnel reflectance ``f0``; no phase function (the law is complete).

    Per unit area, with ``μ = n·v``, ``μ0 = n·s``, ``ν = n·h`` and ``cos(α/2) = v·h``, where ``μ, μ0 > 0``:

        diffuse:  28/(23π) [1 − (1 − μ0/2)^5] [1 − (1 − μ/2)^5] μ μ0       (ρ(1 − F0) in the area)
        lobe n:   (n + 1)/(8π) F(α) / cos(α/2) · ν^n min(μ, μ0),   F(α) = F0 + (1 − F0)(1 − cos(α/2))^5
    """

    f0: float = 0.5
    exponents: tuple[float, ...] = (800.0,)
    diffuse: bool = True

    uses_half_angle = True

    @property
    def bases(self) -> int:
        """The number of bases ``M``."""
        return int(self.diffuse) + len(self.exponents)

    def basis_names(self) -> tuple[str, ...]:
        """One name per basis (the areas' column names): ``diffuse``, ``lobe_<n>``."""
        return ("diffuse",) * int(self.diffuse) + tuple(f"lobe_{n:g}" for n in self.exponents)

    def terms(self, mu: Tensor, mu0: Tensor, nu: Tensor | None, alpha: Tensor, *, derivatives: bool = False
              ) -> Terms:
        """Per-basis brightness of a unit area ``(B, N, M, K)`` (and its partial derivatives in ``μ``, ``μ0``,
        ``ν``) from ``mu``, ``mu0``, ``nu`` ``(B, N, K)`` and the phase angles ``alpha`` ``(N,)`` (rad)."""
        lit = (mu > 0) & (mu0 > 0)
        zero = torch.zeros((), dtype=mu.dtype, device=mu.device)
        mu, mu0 = torch.where(lit, mu, zero), torch.where(lit, mu0, zero)
        values, d_mu, d_mu0, d_nu = [], [], [], []
        if self.diffuse:
            b, b0 = 1.0 - _pow5(1.0 - 0.5 * mu), 1.0 - _pow5(1.0 - 0.5 * mu0)
            values.append(DIFFUSE_SCALE * b * b0 * mu * mu0)
            if derivatives:
                db = 2.5 * (1.0 - 0.5 * mu) ** 4
                db0 = 2.5 * (1.0 - 0.5 * mu0) ** 4
                d_mu.append(DIFFUSE_SCALE * b0 * mu0 * (db * mu + b))
                d_mu0.append(DIFFUSE_SCALE * b * mu * (db0 * mu0 + b0))
                d_nu.append(torch.zeros_like(mu))
        if self.exponents:
            half = torch.cos(0.5 * alpha)[:, None]                                     # v·h  (N, 1)
            fresnel = self.f0 + (1.0 - self.f0) * _pow5(1.0 - half)
            smaller = torch.minimum(mu, mu0)
            log_nu = torch.log(torch.where(lit, nu, torch.ones_like(nu)).clamp_min(torch.finfo(nu.dtype).tiny))
            for n in self.exponents:
                scale = (n + 1.0) / (8.0 * math.pi) * fresnel / half
                lobe = torch.where(lit, torch.exp((n * log_nu).clamp_min(exp_floor(mu.dtype))), zero)
                values.append(scale * lobe * smaller)
                if derivatives:
                    d_mu.append(torch.where(mu < mu0, scale * lobe, zero))
                    d_mu0.append(torch.where(mu < mu0, zero, scale * lobe))
                    lobe_1 = torch.where(lit, torch.exp(((n - 1.0) * log_nu).clamp_min(exp_floor(mu.dtype))), zero)
                    d_nu.append(scale * n * lobe_1 * smaller)
        stack = lambda parts: torch.stack(parts, -2)  # noqa: E731
        if not derivatives:
            return Terms(stack(values))
        return Terms(stack(values), stack(d_mu), stack(d_mu0), stack(d_nu))


def fibonacci_normals(k: int, *, dtype: torch.dtype = torch.float64, device=None) -> Tensor:
    """``k`` nearly uniform unit vectors ``(k, 3)`` on the sphere (the Fibonacci lattice)."""
    i = torch.arange(k, dtype=dtype, device=device) + 0.5
    z = 1.0 - 2.0 * i / k
    r = torch.sqrt(torch.clamp(1.0 - z * z, min=0.0))
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)


def real_harmonics(normals: Tensor, degree: int) -> Tensor:
    """The real orthonormal spherical harmonics up to ``degree`` at unit vectors ``normals`` ``(K, 3)``:
    ``(K, (degree + 1)²)``, columns ordered by ``l`` then ``m = −l … l`` (``m > 0``: ``√2 Re Y_lm``, ``m < 0``:
    ``√2 Im Y_l|m|``, ``m = 0``: ``Y_l0``, Condon–Shortley phase as scipy's). Polar angle from ``z``."""
    n = normals.detach().cpu().numpy().astype(np.float64)
    theta = np.arccos(np.clip(n[:, 2], -1.0, 1.0))
    phi = np.arctan2(n[:, 1], n[:, 0])
    cols = []
    for lv in range(degree + 1):
        for m in range(-lv, lv + 1):
            y = sph_harm_y(lv, abs(m), theta, phi)
            cols.append(y.real if m == 0 else math.sqrt(2.0) * (y.real if m > 0 else y.imag))
    return torch.as_tensor(np.stack(cols, -1), dtype=normals.dtype, device=normals.device)


def pole_vector(lam: Tensor, beta: Tensor) -> Tensor:
    """Unit pole vectors ``(…, 3)`` from ecliptic longitude and latitude (rad)."""
    return torch.stack([torch.cos(beta) * torch.cos(lam), torch.cos(beta) * torch.sin(lam), torch.sin(beta)], -1)


def pole_angles(v: Tensor) -> tuple[Tensor, Tensor]:
    """Ecliptic longitude in [0, 2π) and latitude (rad) of vectors ``(…, 3)``."""
    v = v / v.norm(dim=-1, keepdim=True)
    return torch.remainder(torch.atan2(v[..., 1], v[..., 0]), 2 * math.pi), torch.asin(v[..., 2].clamp(-1, 1))


def _rz(theta: Tensor) -> Tensor:
    c, s = torch.cos(theta), torch.sin(theta)
    z, o = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack([torch.stack([c, s, z], -1), torch.stack([-s, c, z], -1), torch.stack([z, z, o], -1)], -2)


def _ry(theta: Tensor) -> Tensor:
    c, s = torch.cos(theta), torch.sin(theta)
    z, o = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack([torch.stack([c, z, -s], -1), torch.stack([z, o, z], -1), torch.stack([s, z, c], -1)], -2)


def spin_matrices(*, lam: Tensor, beta: Tensor, period_s: Tensor, phi0: Tensor, t_s: Tensor) -> Tensor:
    """Ecliptic → body matrices ``(B, N, 3, 3)`` for ``B`` spin states (each of ``lam``, ``beta`` (rad),
    ``period_s`` (s), ``phi0`` (rad) ``(B,)``) at the times ``t_s`` ``(N,)`` (s from the epoch)."""
    pole = _ry(math.pi / 2 - beta) @ _rz(lam)                                   # (B, 3, 3)
    turns = torch.remainder(t_s.to(torch.float64)[None, :] / period_s.to(torch.float64)[:, None], 1.0)
    phase = (2 * math.pi * turns).to(lam.dtype) + phi0[:, None]                  # (B, N)
    return _rz(phase) @ pole[:, None]


def folded_pole(lam_deg, beta_deg):
    """The same spin state written with ``β`` in [−90°, 90°]: ``(λ', β', φ0')`` (deg, numpy arrays of the inputs'
    shape). A state past the ecliptic's pole, ``|β| > 90°``, is the axis ``(λ + 180°, ±180° − β)`` whose body frame
    is turned by 180° about it, ``R_y(90° − β') R_z(λ') = R_z(180°) R_y(90° − β) R_z(λ)``, so the same areas need the
    rotation phase ``φ0' = 180°`` there (0° elsewhere); ``λ'`` in [0°, 360°)."""
    lam, beta = np.asarray(lam_deg, dtype=np.float64), np.asarray(beta_deg, dtype=np.float64)
    beta = (beta + 180.0) % 360.0 - 180.0
    past = np.abs(beta) > 90.0
    lam_f = np.where(past, lam + 180.0, lam) % 360.0
    beta_f = np.where(past, np.sign(beta) * 180.0 - beta, beta)
    return lam_f, beta_f, np.where(past, 180.0, 0.0)


def body_vectors(v: Tensor, *, lam: Tensor, beta: Tensor, period_s: Tensor, phi0: Tensor, t_s: Tensor) -> Tensor:
    """The ecliptic vectors ``v`` ``(N, 3)`` (one per time ``t_s`` ``(N,)``) in the body frames of ``B`` spin states:
    ``(B, N, 3)`` (see :func:`spin_matrices`), without forming the per-sample matrices."""
    pole = _ry(math.pi / 2 - beta) @ _rz(lam)                                   # (B, 3, 3)
    w = torch.einsum("bij,nj->bni", pole, v.to(lam.dtype))                      # (B, N, 3)
    turns = torch.remainder(t_s.to(torch.float64)[None, :] / period_s.to(torch.float64)[:, None], 1.0)
    phase = (2 * math.pi * turns).to(lam.dtype) + phi0[:, None]
    c, s = torch.cos(phase), torch.sin(phase)
    return torch.stack([c * w[..., 0] + s * w[..., 1], -s * w[..., 0] + c * w[..., 1], w[..., 2]], -1)


def phase_angle(sun: Tensor, observer: Tensor) -> Tensor:
    """Sun–object–observer angle (rad) of unit vectors ``(…, 3)``."""
    return torch.atan2(torch.linalg.cross(sun, observer).norm(dim=-1), (sun * observer).sum(-1))


def ring_normals(k: int, *, dtype: torch.dtype = torch.float64, device=None) -> Tensor:
    """``k`` unit vectors ``(k, 3)`` on the body equator (perpendicular to the spin axis ``z``), equally spaced in
    longitude from 0: the faces parallel to a principal spin axis that a satellite's box has."""
    phi = torch.arange(k, dtype=dtype, device=device) * (2 * math.pi / k)
    return torch.stack([torch.cos(phi), torch.sin(phi), torch.zeros_like(phi)], -1)


def area_normals(normals: Tensor, scattering) -> Tensor:
    """The normal of every area ``(M·K, 3)``: ``normals`` ``(K, 3)`` once per basis (basis-major)."""
    return normals.repeat(scattering.bases, 1)


def facet_brightness(normals: Tensor, sun_body: Tensor, obs_body: Tensor, alpha: Tensor,
                     scattering: Scattering | SatelliteScattering) -> Tensor:
    """The brightness of a unit area on each normal and basis: ``G`` ``(B, N, M·K)`` with ``L = G a`` (basis-major;
    ``M = 1`` for :class:`Scattering`).

    Args:
        normals: ``(K, 3)`` unit normals (body frame).
        sun_body, obs_body: ``(B, N, 3)`` unit vectors object → Sun and object → observer in the body frame.
        alpha: ``(N,)`` phase angles (rad).
        scattering: the law (and its phase function).
    """
    return facet_terms(normals, sun_body, obs_body, alpha, scattering)[0].value.flatten(-2)


def facet_terms(normals: Tensor, sun_body: Tensor, obs_body: Tensor, alpha: Tensor,
                scattering: Scattering | SatelliteScattering, *, derivatives: bool = False
                ) -> tuple[Terms, Tensor | None, Tensor | None]:
    """:meth:`terms` of the law on ``normals`` ``(K, 3)``: per-basis values ``(B, N, M, K)`` (and derivatives),
    with the half-angle vectors ``h`` ``(B, N, 3)`` and ``|s + v|`` ``(B, N, 1)`` (``None`` for a law without
    ``h``)."""
    mu0 = sun_body @ normals.T
    mu = obs_body @ normals.T
    nu = h = norm = None
    if scattering.uses_half_angle:
        both = sun_body + obs_body
        norm = torch.linalg.vector_norm(both, dim=-1, keepdim=True).clamp_min(torch.finfo(both.dtype).tiny)
        h = both / norm
        nu = h @ normals.T
    return scattering.terms(mu, mu0, nu, alpha, derivatives=derivatives), h, norm


def brightness(areas: Tensor, normals: Tensor, sun_body: Tensor, obs_body: Tensor, alpha: Tensor,
               scattering: Scattering | SatelliteScattering) -> Tensor:
    """Disk-integrated brightness ``(B, N)`` of ``B`` Gaussian images ``areas`` ``(B, M·K)`` (relative units)."""
    return (facet_brightness(normals, sun_body, obs_body, alpha, scattering) * areas[:, None, :]).sum(-1)
