"""Jacobi elliptic functions and Carlson's symmetric elliptic integrals in batched torch (any device, float dtype).

The torque-free motion of a triaxial body (:mod:`.torque_free`) needs, per sample, the Jacobi functions
``sn, cn, dn`` of a real argument, the amplitude ``am`` and the incomplete integral of the third kind
``Π(n; φ, k)``; per body rate the quarter period ``K(k)`` and the complete ``Π(n, k)``. The parameter is passed as
``m = k²`` together with its complement ``mc = 1 − m`` (both computed by the caller without cancellation, which is
what keeps the near-separatrix case ``m → 1`` accurate).

* Amplitude: the arithmetic–geometric mean ladder (descending Landen / Gauss transformation; Abramowitz & Stegun
  16.4): ``a_0 = 1, b_0 = √mc, c_0 = √m``, ``a_{i+1} = (a_i + b_i)/2``, ``b_{i+1} = √(a_i b_i)``,
  ``c_{i+1} = c_i²/(4 a_{i+1})``; then ``φ_N = 2^N a_N u`` and ``φ_{i−1} = (φ_i + asin((c_i/a_i) sin φ_i))/2``,
  ``am(u) = φ_0``; ``K = π/(2 a_N)``. The ladder is built once per parameter with the number of rungs the worst
  parameter of the batch needs; every argument then takes the same fixed number of steps.
* Integrals: Carlson's duplication (B. C. Carlson, "Numerical computation of real or complex elliptic integrals",
  Numer. Algorithms 10, 1995): ``R_F(x, y, z)`` and ``R_J(x, y, z, p)`` share the duplication of ``x, y, z``; after
  ``N`` steps the fifth-order series in the normalised deviations finishes them. ``N`` comes from Carlson's stopping
  rule on the worst arguments of the batch, so again every element takes the same steps (no data-dependent loop
  per element). Here ``x, y, z ≥ 0`` and ``p > 0`` (``p`` is at least the largest of ``x, y, z``, so the ``R_C``
  terms are arctangents).

Legendre forms for ``|φ| ≤ π/2``: ``F(φ, k) = sin φ R_F(cos²φ, 1 − m sin²φ, 1)``,
``Π(n; φ, k) = F + (n/3) sin³φ R_J(cos²φ, 1 − m sin²φ, 1, 1 − n sin²φ)`` (sign convention ``1 − n sin²θ`` in the
integrand, that of scipy/DLMF); complete ones at ``φ = π/2``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = ["LandenLadder", "landen_ladder", "jacobi_amplitude", "jacobi_sn_cn_dn", "carlson_steps",
           "carlson_rf_rj", "legendre_pi", "MAX_STEPS"]

#: the most AGM rungs or duplication steps any parameter may need (far above what double precision asks for)
MAX_STEPS = 60


class LandenLadder:
    """The AGM ladder of parameters ``m, mc`` ``(...)``: ``ratios (N, ...)`` the ``c_i/a_i`` of the rungs
    ``i = 1..N`` and ``scale (...)`` ``= 2^N a_N`` (so ``K = π 2^(N−1) / scale``)."""

    def __init__(self, ratios: Tensor, scale: Tensor, m: Tensor, mc: Tensor):
        self.ratios, self.scale, self.m, self.mc = ratios, scale, m, mc

    @property
    def quarter_period(self) -> Tensor:
        """``K(k)`` ``(...)``: ``π / (2 a_N)``."""
        return (math.pi * 2.0 ** (self.ratios.shape[0] - 1)) / self.scale


def landen_ladder(m: Tensor, mc: Tensor) -> LandenLadder:
    """The AGM ladder of ``m = k² ∈ [0, 1)`` and ``mc = 1 − m > 0`` ``(...)`` with as many rungs as the batch's
    largest ``m`` needs for ``c_N/a_N`` below the dtype's epsilon."""
    eps = torch.finfo(m.dtype).eps
    a, b, c = torch.ones_like(m), torch.sqrt(mc), torch.sqrt(m)
    ratios = []
    while bool((c > eps * a).any()):
        if len(ratios) == MAX_STEPS:
            raise ValueError(f"landen_ladder: no convergence in {MAX_STEPS} rungs (mc = {float(mc.min()):g})")
        a, b, c = 0.5 * (a + b), torch.sqrt(a * b), c * c
        c = c / (4.0 * a)
        ratios.append(c / a)
    n = len(ratios)
    stack = torch.stack(ratios) if ratios else m.new_zeros(0, *m.shape)
    return LandenLadder(stack, a * 2.0 ** n, m, mc)


def jacobi_amplitude(u: Tensor, ladder: LandenLadder) -> Tensor:
    """``am(u | m)`` of arguments ``u (..., K)`` whose parameter's ladder has batch shape ``(...)`` (any real ``u``;
    ``am`` is continuous and increasing, ``am(u + 2K) = am(u) + π``)."""
    phi = ladder.scale.unsqueeze(-1) * u
    for i in range(ladder.ratios.shape[0] - 1, -1, -1):
        phi = 0.5 * (phi + torch.asin(ladder.ratios[i].unsqueeze(-1) * torch.sin(phi)))
    return phi


def jacobi_sn_cn_dn(u: Tensor, ladder: LandenLadder) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(sn, cn, dn, am)`` of ``u (..., K)`` (ladder of batch shape ``(...)``); ``dn = √(mc + m cn²)``, which keeps
    its relative accuracy near ``m = 1``."""
    am = jacobi_amplitude(u, ladder)
    sn, cn = torch.sin(am), torch.cos(am)
    dn = torch.sqrt(ladder.mc.unsqueeze(-1) + ladder.m.unsqueeze(-1) * cn * cn)
    return sn, cn, dn, am


def carlson_steps(x: Tensor, y: Tensor, z: Tensor, p: Tensor) -> Tensor:
    """The duplication steps Carlson's rule asks of each set of arguments (broadcast shape, int64) for the dtype's
    precision: the least ``N`` with ``4^(−N) Q < A_N``, ``Q = (ε/4)^(−1/6) max|A_0 − (x, y, z, p)|`` (Carlson 1995,
    for ``R_J``; ``R_F``'s rule asks for no more). A batch takes the most any of its elements asks."""
    x, y, z, p = torch.broadcast_tensors(x, y, z, p)
    eps = torch.finfo(x.dtype).eps
    a0 = (x + y + z + 2.0 * p) / 5.0
    q = (0.25 * eps) ** (-1.0 / 6.0) * torch.stack([(a0 - v).abs() for v in (x, y, z, p)]).amax(0)
    a, n = a0, 0
    steps = torch.zeros(x.shape, dtype=torch.int64, device=x.device)
    while True:
        pending = q * 0.25 ** n >= a.abs()
        if not bool(pending.any()):
            return steps
        if n == MAX_STEPS:
            raise ValueError(f"carlson_steps: no convergence in {MAX_STEPS} steps")
        steps = steps + pending
        sx, sy, sz = torch.sqrt(x), torch.sqrt(y), torch.sqrt(z)
        lam = sx * sy + sx * sz + sy * sz
        x, y, z, p, a = (x + lam) / 4, (y + lam) / 4, (z + lam) / 4, (p + lam) / 4, (a + lam) / 4
        n += 1


def _atan_ratio(e: Tensor) -> Tensor:
    """``R_C(1, 1 + e) = atan(√e)/√e`` for ``e ≥ 0`` (its series below 1e-3; the series alone when every ``e`` is
    that small, as after the first duplications, where ``e`` shrinks about 64-fold per step)."""
    series = 1.0 - e * (1.0 / 3.0 - e * (1.0 / 5.0 - e * (1.0 / 7.0 - e * (1.0 / 9.0 - e / 11.0))))
    small = e < 1e-3
    if bool(small.all()):
        return series
    root = torch.sqrt(torch.where(small, torch.ones_like(e), e))
    return torch.where(small, series, torch.atan(root) / root)


def carlson_rf_rj(x: Tensor, y: Tensor, z: Tensor, p: Tensor, *, steps: int,
                  with_rf: bool = True) -> tuple[Tensor | None, Tensor]:
    """``R_F(x, y, z)`` (``None`` unless ``with_rf``) and ``R_J(x, y, z, p)`` (broadcast shapes) by ``steps``
    duplications and the fifth-order series; ``x, y, z ≥ 0`` with at most one zero, ``p ≥ max(x, y, z)``, ``p > 0``
    (see :func:`carlson_steps`).

    The duplication runs on the scaled arguments ``X_i = 4^i x_i`` (so ``X_{i+1} = X_i + Λ_i``, ``Λ_i = 4^i λ_i``):
    the i-th ``R_C`` term ``4^(−i) R_C(1, 1 + e_i)/d_i`` is ``2^i R_C(1, 1 + δ/D_i²)/D_i`` with ``D_i = 2^(3i) d_i``."""
    x, y, z, p = torch.broadcast_tensors(x, y, z, p)
    s3 = x + y + z
    af0, aj0 = s3 / 3.0, (s3 + 2.0 * p) / 5.0
    fx, fy = af0 - x, af0 - y
    dx, dy, dz = aj0 - x, aj0 - y, aj0 - z
    delta = (p - x) * (p - y) * (p - z)
    total = torch.zeros_like(x)
    for i in range(steps):
        sx, sy, sz, sp = torch.sqrt(x), torch.sqrt(y), torch.sqrt(z), torch.sqrt(p)
        lam = sx * (sy + sz) + sy * sz
        d = (sp + sx) * (sp + sy) * (sp + sz)
        total = total + (2.0 ** i) * _atan_ratio(delta / (d * d)) / d
        x, y, z, p = x + lam, y + lam, z + lam, p + lam
    s3 = x + y + z
    af, aj = s3 / 3.0, (s3 + 2.0 * p) / 5.0  # 4^steps times the unscaled means
    rf = None
    if with_rf:
        X, Y = fx / af, fy / af
        Z = -(X + Y)
        e2, e3 = X * Y - Z * Z, X * Y * Z
        rf = (2.0 ** steps) * (1.0 - e2 / 10.0 + e3 / 14.0 + e2 * e2 / 24.0 - 3.0 * e2 * e3 / 44.0) / torch.sqrt(af)
    # R_J
    X, Y, Z = dx / aj, dy / aj, dz / aj
    P = -(X + Y + Z) / 2.0
    xyz, p2 = X * Y * Z, P * P
    e2 = X * Y + X * Z + Y * Z - 3.0 * p2
    e3 = xyz + 2.0 * e2 * P + 4.0 * p2 * P
    e4 = (2.0 * xyz + e2 * P + 3.0 * p2 * P) * P
    e5 = xyz * p2
    series = (1.0 - 3.0 * e2 / 14.0 + e3 / 6.0 + 9.0 * e2 * e2 / 88.0 - 3.0 * e4 / 22.0 - 9.0 * e2 * e3 / 52.0
              + 3.0 * e5 / 26.0)
    rj = (2.0 ** steps) * series / (aj * torch.sqrt(aj)) + 6.0 * total
    return rf, rj


def legendre_pi(n: Tensor, sn: Tensor, cn: Tensor, dn2: Tensor, *, steps: int,
                f: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """``(F(φ, k), Π(n; φ, k))`` for ``|φ| ≤ π/2`` and ``n ≤ 0`` from ``sin φ, cos φ``, ``1 − m sin²φ`` (broadcast);
    a known ``F`` (e.g. ``u`` itself when ``φ = am u``) saves the ``R_F`` series."""
    s2 = sn * sn
    rf, rj = carlson_rf_rj(cn * cn, dn2, torch.ones_like(sn), 1.0 - n * s2, steps=steps, with_rf=f is None)
    f = sn * rf if f is None else f
    return f, f + (n / 3.0) * sn * s2 * rj
