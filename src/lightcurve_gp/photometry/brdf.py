"""Facet reflectance: the Ashikhmin–Shirley BRDF of the paper (section 2.1, its typo fixed) and Lambert.

All functions are pure and broadcast over leading dimensions. Inputs are body-frame unit vectors ``(..., 3)``:
``s`` towards the Sun, ``v`` towards the observer, facet normal ``n`` and tangent axes ``u``, ``w = n × u``
(``Facets.u``/``Facets.v``); material parameters broadcast against ``(...)``.

Ashikhmin–Shirley, with ``h = (s + v)/|s + v|`` (paper Sec. 2.1, Eqs. (2)–(7); docs/design.md)::

    c_d = 28ρ/(23π) (1 − F0) [1 − (1 − n·s/2)^5] [1 − (1 − n·v/2)^5]
    F   = F0 + (1 − F0)(1 − v·h)^5
    γ   = (n_u (h·u)² + n_v (h·w)²) / (1 − (n·h)²)          (lobe term (n·h)^γ = 1 where h ∥ n)
    c_s = √((n_u + 1)(n_v + 1)) / (8π) · F (n·h)^γ / ((v·h) max(n·s, n·v))

The paper prints ``/1`` in the second bracket of ``c_d``; the authors' code (and this one) uses ``/2``.

Numerics:

* ``γ`` uses ``(h·u)² + (h·w)²`` for ``1 − (n·h)²`` — equal for a unit ``h`` and an orthonormal frame, but free of
  the cancellation near ``h ∥ n``; there both vanish and the lobe term is 1 (``γ`` is set to ``n_u``, ``n·h = 1``).
* ``(n·h)^γ = exp(γ log(n·h))``, ``log(n·h)`` from ``1 − n·h = ((h·u)² + (h·w)²)/(1 + n·h)`` (no rounding of
  ``n·h`` near 1 amplified by γ), with the exponent clamped below at :func:`exp_floor` (−60 in float32, −600 in
  float64): float32 ``exp`` of arguments below about −87, and products of tiny lobes with small cosines, take
  slow denormal paths; the clamped lobe values (below ~1e-25) are negligible next to the diffuse term.
* Outside ``n·s > 0, n·v > 0`` (where the renderer masks the facet out) every output stays finite, so masks
  multiply without producing NaN values or gradients.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

__all__ = ["Surface", "ashikhmin_shirley", "ashikhmin_shirley_cosines", "ashikhmin_shirley_projected", "lambert",
           "exp_floor", "DIFFUSE_SCALE"]

#: 28 / (23 π), the normalisation of the Ashikhmin–Shirley diffuse term
DIFFUSE_SCALE = 28.0 / (23.0 * math.pi)


class Surface(NamedTuple):
    """Ashikhmin–Shirley parameters of a whole object, one value per batch element: every field ``(B,)``.

    ``rho`` diffuse reflectance, ``f0`` Fresnel reflectance at normal incidence, ``n_u``/``n_v`` lobe exponents.
    The renderer gives every facet of batch element ``b`` the parameters ``surface[:, b]`` (see
    :meth:`lightcurve_gp.photometry.render.Scene.flux_parts`).
    """

    rho: Tensor
    f0: Tensor
    n_u: Tensor
    n_v: Tensor

    def to(self, device=None, dtype=None) -> "Surface":
        """Copy with every field moved to ``device`` and/or cast to ``dtype``."""
        return Surface(*(t.to(device=device, dtype=dtype) for t in self))

    def index(self, rows) -> "Surface":
        """The batch elements ``rows`` (an index, slice or mask) of every field."""
        return Surface(*(t[rows] for t in self))


def exp_floor(dtype: torch.dtype) -> float:
    """Lowest exponent passed to ``exp`` in the specular lobe: −60 for 16/32-bit floats, −600 for float64.

    Both keep the lobe and its products with small cosines clear of denormal numbers (float32 below ~1e-38,
    float64 below ~1e-308), whose arithmetic is many times slower.
    """
    return -600.0 if dtype == torch.float64 else -60.0


def _pow5(x: Tensor) -> Tensor:
    x2 = x * x
    return x2 * x2 * x  # cheaper than pow(x, 5) elementwise


def _dot(a: Tensor, b: Tensor) -> Tensor:
    return (a * b).sum(-1)


def ashikhmin_shirley(s: Tensor, v: Tensor, n: Tensor, u: Tensor, w: Tensor, rho, f0, n_u, n_v
                      ) -> tuple[Tensor, Tensor]:
    """Diffuse and specular parts ``(c_d, c_s)`` of the Ashikhmin–Shirley BRDF (1/sr), shapes broadcast to ``(...)``.

    Args:
        s, v: unit vectors to the Sun and to the observer ``(..., 3)``.
        n, u, w: facet normal and tangent axes (``w = n × u``) ``(..., 3)``.
        rho, f0, n_u, n_v: diffuse reflectance, Fresnel reflectance at normal incidence and lobe exponents,
            numbers or tensors broadcasting against ``(...)``. ``c_d`` is linear in ``rho``.

    The values are meaningful where ``n·s > 0`` and ``n·v > 0``; elsewhere they are finite and arbitrary.
    """
    hs = s + v
    h = hs / torch.linalg.vector_norm(hs, dim=-1, keepdim=True).clamp_min(torch.finfo(hs.dtype).tiny)
    return ashikhmin_shirley_cosines(_dot(n, s), _dot(n, v), _dot(n, h), _dot(v, h), _dot(h, u), _dot(h, w),
                                     rho, f0, n_u, n_v)


def ashikhmin_shirley_cosines(ns: Tensor, nv: Tensor, nh: Tensor, vh: Tensor, hu: Tensor, hw: Tensor,
                              rho, f0, n_u, n_v) -> tuple[Tensor, Tensor]:
    """:func:`ashikhmin_shirley` from the cosines ``n·s, n·v, n·h, v·h, h·u, h·w`` (all broadcast to ``(...)``)."""
    tiny = torch.finfo(torch.result_type(ns, nh)).tiny
    c_d = _diffuse(ns, nv, rho, f0)
    denom = (vh * torch.maximum(ns, nv)).clamp_min(tiny)
    c_s = _specular_numerator(nh, vh, hu, hw, f0, n_u, n_v) / denom
    return c_d, c_s


def ashikhmin_shirley_projected(ns: Tensor, nv: Tensor, nh: Tensor, vh: Tensor, hu: Tensor, hw: Tensor,
                                rho, f0, n_u, n_v) -> tuple[Tensor, Tensor]:
    """``(c_d (n·s)(n·v), c_s (n·s)(n·v))`` where ``n·s > 0`` and ``n·v > 0``, zero elsewhere: a facet's flux per area.

    Uses ``(n·s)(n·v) / max(n·s, n·v) = min(n·s, n·v)``, so the specular part has no division by a small cosine;
    values and gradients are finite everywhere (masked entries get zero gradient).
    """
    lit = (ns > 0) & (nv > 0)
    zero = torch.zeros((), dtype=ns.dtype, device=ns.device)
    ns, nv = torch.where(lit, ns, zero), torch.where(lit, nv, zero)
    diffuse = _diffuse(ns, nv, rho, f0) * (ns * nv)
    specular = _specular_numerator(nh, vh, hu, hw, f0, n_u, n_v) * torch.minimum(ns, nv) / vh
    return diffuse, specular


def _diffuse(ns: Tensor, nv: Tensor, rho, f0) -> Tensor:
    return DIFFUSE_SCALE * rho * (1.0 - f0) * (1.0 - _pow5(1.0 - 0.5 * ns)) * (1.0 - _pow5(1.0 - 0.5 * nv))


def _specular_numerator(nh: Tensor, vh: Tensor, hu: Tensor, hw: Tensor, f0, n_u, n_v) -> Tensor:
    """``√((n_u+1)(n_v+1))/(8π) · F · (n·h)^γ``: ``c_s`` without its denominator ``(v·h) max(n·s, n·v)``."""
    dtype = torch.promote_types(nh.dtype, hu.dtype)
    fresnel = f0 + (1.0 - f0) * _pow5(1.0 - vh)
    hu2, hw2 = hu * hu, hw * hw
    tangential = hu2 + hw2  # = 1 − (n·h)² for a unit h in an orthonormal frame, without cancellation
    parallel = tangential <= 0.0
    gamma = torch.where(parallel, n_u * torch.ones_like(tangential),
                        (n_u * hu2 + n_v * hw2) / torch.where(parallel, 1.0, tangential))
    # log(n·h) = log1p(−(1 − n·h)) with 1 − n·h = (1 − (n·h)²)/(1 + n·h): accurate near the lobe's peak, where
    # n·h rounds to 1 in float32 (the lobe with γ ≈ 800 amplifies the rounding of n·h 800-fold)
    one_minus_nh = (tangential / (1.0 + nh.clamp_min(0.0))).clamp_max(1.0 - torch.finfo(dtype).eps)
    exponent = (gamma * torch.log1p(-one_minus_nh)).clamp_min(exp_floor(dtype))
    if isinstance(n_u, Tensor) or isinstance(n_v, Tensor):
        norm = torch.sqrt(torch.as_tensor((n_u + 1.0) * (n_v + 1.0)))
    else:
        norm = math.sqrt((n_u + 1.0) * (n_v + 1.0))
    return norm / (8.0 * math.pi) * fresnel * torch.exp(exponent)


def lambert(s: Tensor, v: Tensor, n: Tensor, rho) -> Tensor:
    """Lambertian BRDF ``ρ/π`` (1/sr), broadcast to the batch shape of ``s``, ``v`` and ``n``."""
    shape = torch.broadcast_shapes(s.shape, v.shape, n.shape)[:-1]
    return rho / math.pi * torch.ones(shape, dtype=n.dtype, device=n.device)
