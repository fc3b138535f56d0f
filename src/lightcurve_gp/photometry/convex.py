"""A convex body as its Gaussian image, its scattering law and its principal-axis rotation (convex inversion).

A convex body is given, up to translation, by its *Gaussian image*: non-negative areas ``a_k`` on a fixed set of
outward facet normals ``n_k`` (Minkowski). Its disk-integrated brightness under a Sun direction ``s`` and an
observer direction ``e`` (unit vectors in the body frame) is linear in the areas:

    L = f(α) Σ_k a_k S(μ_k, μ0_k) [μ_k > 0, μ0_k > 0],   μ_k = n_k·e,  μ0_k = n_k·s,

with the Lommel–Seeliger plus ``c``·Lambert law ``S(μ, μ0) = μ μ0 / (μ + μ0) + c μ μ0`` and the phase function
``f(α) = a exp(−α/d) + k α + 1`` (α the phase angle in rad) of Kaasalainen, Torppa & Muinonen (2001). Only facets lit
and seen count; for a convex body no facet shadows another, so the sum is exact.

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

import numpy as np
import torch
from scipy.special import sph_harm_y
from torch import Tensor

__all__ = ["Scattering", "fibonacci_normals", "real_harmonics", "spin_matrices", "body_vectors", "facet_brightness",
           "brightness", "phase_angle", "pole_vector", "pole_angles"]


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


def facet_brightness(normals: Tensor, sun_body: Tensor, obs_body: Tensor, alpha: Tensor,
                     scattering: Scattering) -> Tensor:
    """The brightness of a unit area on each normal: ``G`` ``(B, N, K)`` with ``L = G a``.

    Args:
        normals: ``(K, 3)`` unit normals (body frame).
        sun_body, obs_body: ``(B, N, 3)`` unit vectors object → Sun and object → observer in the body frame.
        alpha: ``(N,)`` phase angles (rad).
        scattering: the law and phase function.
    """
    mu0 = sun_body @ normals.T
    mu = obs_body @ normals.T
    return scattering.law(mu, mu0) * scattering.phase_function(alpha)[:, None]


def brightness(areas: Tensor, normals: Tensor, sun_body: Tensor, obs_body: Tensor, alpha: Tensor,
               scattering: Scattering) -> Tensor:
    """Disk-integrated brightness ``(B, N)`` of ``B`` Gaussian images ``areas`` ``(B, K)`` (relative units)."""
    return (facet_brightness(normals, sun_body, obs_body, alpha, scattering) * areas[:, None, :]).sum(-1)
