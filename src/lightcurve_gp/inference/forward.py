"""The inversion's forward model: light curves of many trajectories ``(q_0, ω_0, ρ)`` and their exact Jacobians.

Kinematics. With ω the body rate, ``q̇ = ½ [ω; 0] ⊗ q`` gives ``q(t) = Δ(t; ω_0) ⊗ q_0`` where ``Δ`` solves the same
equations from the identity (in closed form at every sample time, :mod:`lightcurve_gp.attitude.torque_free`) and
depends on ``ω_0`` and the inertia only: every attitude that shares a rate shares one propagation.

Photometry. The facets are merged into groups of equal normal and material (:meth:`Facets.grouped`; 6 for the
box-wing) and the flux is split as ``f = ρ D(q) + S(q)`` (diffuse at ρ = 1 and specular, Ashikhmin–Shirley with
the known ``F0`` and an isotropic lobe ``n_u = n_v = n``, where the lobe term is ``(n·h)^n``):

    D = 28/(23π) (1 − F0) Σ_g a_g [1 − (1 − n·s/2)^5] [1 − (1 − n·v/2)^5] (n·s)(n·v)
    S = (n + 1)/(8π) F(v·h) Σ_g a_g (n·h)^n min(n·s, n·v) / (v·h)         over lit and visible groups

and ``m = −26.7 − 2.5 log10(f / r²)`` (the renderer's formulas, :mod:`lightcurve_gp.photometry.render`).

Jacobian. A body-side rotation ``q ↦ exp(θ) ⊗ q`` moves ``s_b ↦ s_b + s_b × θ``, so ``∂(n·s_b)/∂θ = n × s_b`` and
the body-frame gradient of the flux is ``(Σ_g ∂f/∂(n·s)_g n_g) × s_b + (…) × v_b + (…) × h_b`` — three small
matrix products. The state's columns follow from it without differentiating the renderer again:

* initial attitude ``q_0 ↦ exp(θ_0) ⊗ q_0``: the body perturbation at ``t`` is ``A(Δ(t)) θ_0``;
* initial rate ``ω_0 + δω``: ``Δ(t; ω_0 + δω) ⊗ Δ(t; ω_0)⁻¹ = exp(Φ(t) δω)``, ``Φ (…, T, 3, 3)`` from three
  propagations with shifted rates (:func:`rate_sensitivity`, forward differences);
* ``β = ln ρ``: ``∂m/∂β = −2.5/ln 10 · ρD/f``.

Tensors: ``q (..., 4)`` scalar last inertial → body, rates rad/s, times s, magnitudes mag.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import attitude_matrix, quat_conj, quat_mul
from lightcurve_gp.attitude.torque_free import torque_free_motion
from lightcurve_gp.photometry.brdf import DIFFUSE_SCALE, exp_floor
from lightcurve_gp.photometry.render import SUN_MAGNITUDE, Scene

__all__ = ["GroupRenderer", "Photometry", "propagate_rates", "rate_sensitivity", "M_PER_LN"]

#: ``2.5 / ln 10``: magnitudes per natural-log unit of flux
M_PER_LN = 2.5 / math.log(10.0)


@dataclass(frozen=True)
class Photometry:
    """Diffuse flux at ρ = 1 ``D``, specular flux ``S`` and, when asked for, their body-frame gradients ``dD``,
    ``dS`` ``(..., 3)`` (per radian of a body-side rotation)."""

    D: Tensor
    S: Tensor
    dD: Tensor | None = None
    dS: Tensor | None = None


def _quadratic_coefficients(dtype: torch.dtype, device) -> Tensor:
    """``C (10, 3, 3)`` with ``A(q) = Σ_m μ_m(q) C_m`` for the ten monomials ``μ = (q_k q_l)_{k ≤ l}`` (the attitude
    matrix is a quadratic form in ``q``; :func:`_monomials` orders them)."""
    eye = torch.eye(4, dtype=dtype, device=device)
    single = attitude_matrix(eye)  # (4, 3, 3): coefficient of q_k²
    out = []
    for k, j in _PAIRS:
        out.append(single[k] if k == j else attitude_matrix(eye[k] + eye[j]) - single[k] - single[j])
    return torch.stack(out)


_PAIRS = [(k, j) for k in range(4) for j in range(k, 4)]


def _monomials(q: Tensor) -> Tensor:
    """``μ (10, ...)``: the products ``q_k q_l`` (``k ≤ l``) of ``q (..., 4)``, first dimension the monomial."""
    qt = q.movedim(-1, 0)
    return torch.stack([qt[k] * qt[j] for k, j in _PAIRS])


class GroupRenderer:
    """The flux of a :class:`~lightcurve_gp.photometry.render.Scene`'s facet groups for batches of attitudes.

    Every cosine ``n_g · A(q) x`` is a quadratic form in ``q``: one matrix product of the ten monomials
    ``q_k q_l`` gives all of them, laid out with the attitudes last so that every elementwise operation runs on
    contiguous rows.

    Args:
        scene: the facets (isotropic lobes) under a fixed or per-sample geometry; per-sample attitudes carry the
            samples along their last batch dimension, as in the scene.
    """

    def __init__(self, scene: Scene) -> None:
        groups, _ = scene.facets.grouped()
        if not bool((groups.n_u == groups.n_v).all()):
            raise ValueError("the inversion's renderer needs isotropic lobes (surface.n_u = surface.n_v)")
        self.per_sample = scene.per_sample
        self.normals = groups.normals  # (G, 3)
        self.G = len(groups)
        col = lambda t: t.unsqueeze(-1).unsqueeze(-1) if self.per_sample else t.unsqueeze(-1)  # noqa: E731
        self.area_d = col(DIFFUSE_SCALE * (1.0 - groups.f0) * groups.areas)  # (G, 1[, 1])
        self.lobe = col(groups.n_u)
        frame = torch.stack([scene.sun, scene.observer, scene.half], -1)  # (3, 3) | (T, 3, 3): ŝ, v̂, ĥ
        vh = (scene.observer * scene.half).sum(-1)  # () | (T,)
        fresnel = groups.f0 + (1.0 - groups.f0) * (1.0 - vh.unsqueeze(-1)) ** 5  # (G,) | (T, G)
        spec = (groups.n_u + 1.0) / (8.0 * math.pi) * fresnel * groups.areas / vh.unsqueeze(-1)
        self.spec = spec.T.unsqueeze(-1) if self.per_sample else spec.unsqueeze(-1)  # (G, 1) | (G, T, 1)
        r = scene.r_obs if isinstance(scene.r_obs, Tensor) else torch.tensor(scene.r_obs)
        self.log_r2 = 2.0 * torch.log(r.to(self.normals))  # () | (T,)
        coef = _quadratic_coefficients(frame.dtype, frame.device) @ frame.unsqueeze(-3)  # ([T,] 10, 3 i, 3 c)
        cos = torch.einsum("gi,...mic->...cgm", self.normals, coef).flatten(-3, -2)  # ([T,] 3G, 10)
        body = coef.permute(*range(coef.ndim - 3), -1, -2, -3).flatten(-3, -2)  # ([T,] 9 (c, i), 10)
        self.W = torch.cat([cos, body], -2)  # ([T,] 3G + 9, 10)

    def restrict(self, index: Tensor) -> "GroupRenderer":
        """The renderer of the samples ``index`` of a per-sample geometry (itself for a fixed one)."""
        if not self.per_sample:
            return self
        out = object.__new__(GroupRenderer)
        out.__dict__.update(self.__dict__)
        out.W, out.spec, out.log_r2 = self.W[index], self.spec[:, index], self.log_r2[index]
        return out

    def magnitude(self, flux: Tensor) -> Tensor:
        """``m = −26.7 − 2.5 log10(f / r²)`` of fluxes ``(..., T)`` (NaN where ``f ≤ 0``)."""
        f = torch.where(flux > 0, flux, torch.full_like(flux, math.nan))
        return SUN_MAGNITUDE - M_PER_LN * (torch.log(f) - self.log_r2)

    def _rows(self, q: Tensor) -> Tensor:
        """``(3G + 9, N)`` (fixed) or ``(3G + 9, T, B)`` (per sample) cosines and body vectors of ``q``."""
        if not self.per_sample:
            return self.W @ _monomials(q.reshape(-1, 4))
        T = self.W.shape[0]
        mono = _monomials(q.reshape(-1, T, 4)).permute(2, 0, 1)  # (T, 10, B)
        return torch.bmm(self.W, mono).transpose(0, 1)  # (R, T, B)

    def __call__(self, q: Tensor, *, gradient: bool = False) -> Photometry:
        """``D``, ``S`` ``(...)`` of attitudes ``q (..., 4)`` and, with ``gradient``, their body-frame gradients
        ``(..., 3)``."""
        batch = q.shape[:-1]
        rows = self._rows(q)
        G = self.G
        ns, nv, nh = rows[:G], rows[G:2 * G], rows[2 * G:3 * G]
        lit = (ns > 0) & (nv > 0)
        zero = torch.zeros((), dtype=ns.dtype, device=ns.device)
        ns, nv = torch.where(lit, ns, zero), torch.where(lit, nv, zero)
        ps, pv = 1.0 - 0.5 * ns, 1.0 - 0.5 * nv
        ps4, pv4 = (ps * ps).square(), (pv * pv).square()
        bs, bv = 1.0 - ps4 * ps, 1.0 - pv4 * pv  # 1 − (1 − x/2)^5
        tiny = torch.finfo(ns.dtype).tiny
        lobe = torch.exp((self.lobe * torch.log(nh.clamp_min(tiny))).clamp_min(exp_floor(ns.dtype)))
        spec_g = self.spec * lobe  # × min(n·s, n·v)
        d_g = self.area_d * bs * bv * ns * nv
        s_g = spec_g * torch.minimum(ns, nv)
        out = (d_g.sum(0), s_g.sum(0))
        if not gradient:
            return Photometry(*(self._shape(t, batch) for t in out))
        dd_ns = self.area_d * bv * nv * (2.5 * ps4 * ns + bs)  # ∂/∂(n·s), zero outside lit & visible
        dd_nv = self.area_d * bs * ns * (2.5 * pv4 * nv + bv)
        ds_nh = self.lobe * s_g / nh.clamp_min(tiny)
        s_first = ns <= nv  # min(n·s, n·v) = n·s
        ds_ns = torch.where(s_first, spec_g, zero) * lit
        ds_nv = torch.where(s_first, zero, spec_g) * lit
        s_b, v_b, h_b = rows[3 * G:3 * G + 3], rows[3 * G + 3:3 * G + 6], rows[3 * G + 6:]
        n = self.normals.T.reshape(3, G, *([1] * (rows.ndim - 1)))
        weigh = lambda c: (n * c).sum(1)  # noqa: E731  Σ_g c_g n_g → (3, ...)
        grad_d = _cross(weigh(dd_ns), s_b) + _cross(weigh(dd_nv), v_b)
        grad_s = _cross(weigh(ds_ns), s_b) + _cross(weigh(ds_nv), v_b) + _cross(weigh(ds_nh), h_b)
        return Photometry(*(self._shape(t, batch) for t in out),
                          *(self._shape(t, batch + (3,)) for t in (grad_d, grad_s)))

    def _shape(self, t: Tensor, shape: torch.Size) -> Tensor:
        """Rows laid out attitudes-last back to ``shape`` (a leading vector axis of 3 moved last)."""
        if t.ndim == (2 if not self.per_sample else 3) and shape[-1:] == (3,) and t.shape[0] == 3:
            t = t.movedim(0, -1)
        if self.per_sample:  # (T, B[, 3]) → (B, T[, 3])
            t = t.transpose(0, 1)
        return t.reshape(shape)


def _cross(a: Tensor, b: Tensor) -> Tensor:
    """``a × b`` of vectors stored along the first dimension ``(3, ...)``."""
    return torch.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def propagate_rates(omega0: Tensor, *, inertia: Tensor, times: Tensor) -> Tensor:
    """``Δ(t_k; ω_0)`` ``(..., K, 4)`` at the sample times ``times (K,)`` (s from the epoch of ``ω_0``, any spacing)
    for rates ``ω_0 (..., 3)`` (rad/s) and principal moments ``inertia (3,)``: the closed-form torque-free motion
    (:func:`~lightcurve_gp.attitude.torque_free.torque_free_motion`), every sample at once, no time steps."""
    j = torch.as_tensor(inertia, dtype=omega0.dtype, device=omega0.device)
    if j.shape != (3,):
        raise ValueError(f"inertia: the inversion needs the three principal moments (3,), got {tuple(j.shape)}")
    return torque_free_motion(omega0, inertia=j, times=times)[0]


def rate_sensitivity(omega0: Tensor, *, inertia: Tensor, times: Tensor,
                     step: float = 1e-7) -> tuple[Tensor, Tensor]:
    """``Δ (..., K, 4)`` and ``Φ (..., K, 3, 3)`` with ``Δ(t; ω_0 + δω) ⊗ Δ(t; ω_0)⁻¹ ≈ exp(Φ(t) δω)`` (body-side
    rotation per rad/s), from one batched propagation of ``ω_0`` and its three forward-shifted copies (``step``
    rad/s)."""
    shifts = torch.cat([torch.zeros(1, 3, dtype=omega0.dtype, device=omega0.device),
                        step * torch.eye(3, dtype=omega0.dtype, device=omega0.device)])  # (4, 3)
    deltas = propagate_rates(omega0.unsqueeze(-2) + shifts, inertia=inertia, times=times)  # (..., 4, K, 4)
    base = deltas[..., 0, :, :]
    rel = quat_mul(deltas[..., 1:, :, :], quat_conj(base).unsqueeze(-3))  # (..., 3, K, 4)
    rel = torch.where(rel[..., 3:] < 0, -rel, rel)
    phi = 2.0 * rel[..., :3] / step  # (..., 3 [shift j], K, 3 [axis])
    return base, phi.movedim(-3, -1)  # (..., K, 3 [axis], 3 [shift j])
