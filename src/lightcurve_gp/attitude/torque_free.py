"""Closed-form torque-free motion of a rigid body at any sample times, batched (no time stepping).

For body rates ``ω_0`` at ``t = 0`` and principal moments ``J = diag(I)``, :func:`torque_free_motion` returns the
body rate ``ω(t)`` and the rotation ``Δ(t)`` with ``q(t) = Δ(t) ⊗ q(0)`` (the toolkit's product,
:mod:`.rotations`): ``A(Δ(t)) = A(q(t)) A(q(0))ᵀ`` maps body-frame components at ``t = 0`` to those at ``t``, which
is what :func:`.dynamics.propagate` approximates by RK4. ``Δ`` is continuous in ``t`` from the identity (the same
sign as the RK4 propagation). Every sample is evaluated on its own: a sample days away costs what a sample one
second away costs, and the error does not grow with the number of periods elapsed.

Cases (Landau & Lifshitz, Mechanics §37; Markley & Crassidis, Fundamentals of Spacecraft Attitude Determination
and Control §3.3):

* **Axisymmetric** (two equal moments; spherical). With ``e_s`` the symmetry axis, ``I_t`` the transverse moment
  and ``H = J ω_0``, the motion is the regular precession ``Δ(t) = q(e_s, ν t) ⊗ q(Ĥ, |H| t / I_t)`` with
  ``ν = (I_t − I_s) ω_s / I_t`` (``q(e, Φ)`` the quaternion of angle ``Φ`` about ``e``), ``ω(t) = A(q(e_s, ν t)) ω_0``.
* **Principal-axis spin** (one non-zero component) and ``ω_0 = 0``: ``Δ(t) = q(ω̂_0, |ω_0| t)``, ``ω`` constant.
* **Triaxial tumbler.** In a proper frame ``(1, 2, 3)`` of the principal axes with ``2`` the intermediate one and
  ``3`` the axis ``ω`` circulates about (the largest moment when ``H² > 2 T I_mid``, the short-axis mode; the
  smallest when ``H² < 2 T I_mid``, the long-axis mode): ``ω_1 = A_1 cn u``, ``ω_2 = s_2 A_2 sn u``,
  ``ω_3 = s_3 A_3 dn u``, ``u = λ t + u_0``, with (``d_ij = |I_i − I_j|``, no cancellation)
  ``Q_1 = |H² − 2T I_1| = I_2 d_12 ω_2² + I_3 d_13 ω_3²``, ``Q_3 = |2T I_3 − H²| = I_1 d_13 ω_1² + I_2 d_23 ω_2²``,
  ``A_1² = Q_3/(I_1 d_13)``, ``A_2² = Q_3/(I_2 d_23)``, ``A_3² = Q_1/(I_3 d_13)``, ``λ² = d_23 Q_1/(I_1 I_2 I_3)``,
  ``k² = d_12 Q_3/(d_23 Q_1)``, ``k'² = d_13 |2T I_2 − H²|/(d_23 Q_1)``. The attitude goes through the angular
  momentum frame: with 3-1-3 angles ``(φ, θ, ψ)`` of the body from an inertial frame whose third axis is ``H``,
  ``h = H (sin ψ sin θ, cos ψ sin θ, cos θ)`` gives ``ψ, θ`` from ``ω(t)``, and the precession rate
  ``φ̇ = H (I_1 ω_1² + I_2 ω_2²)/(h_1² + h_2²) = H/I_3 + g/(1 − n sn² u)`` (``g = H (I_3 − I_1)/(I_3 I_1)``,
  ``n = −I_3 d_12 / (I_1 d_23) < 0``) integrates to ``φ(t) − φ(0) = H t/I_3 + (g/λ) [Π(n; am u, k) − Π(n; am u_0,
  k)]``. ``u`` is reduced by the period ``2K``: ``u = 2 K m + r``, ``|r| ≤ K``, ``am u = m π + am r`` and
  ``Π(n; am u) = 2 m Π(n, k) + Π(n; am r)``, so only whole periods are added analytically.
  ``Δ = p⁻¹ ⊗ E(ψ, θ, Δφ) ⊗ E(ψ_0, θ_0, 0)⁻¹ ⊗ p`` with ``E`` the 3-1-3 quaternion and ``p`` the permutation.

Near the separatrix ``k'²`` is kept at ``ε²`` or more (the motion there is ill-conditioned anyway); near-symmetric
bodies (``k → 0``) take the elliptic path; exact principal spins and zero rates are selected by ``torch.where``
from values computed on a safe substitute, so no branch produces NaN.

Units: rad, rad/s, s, kg m². Tensors: ``ω_0 (..., 3)``, ``times (K,)``; float64 (float32 accepted), any device.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from lightcurve_gp.attitude.elliptic import carlson_rf_rj, carlson_steps, jacobi_sn_cn_dn, landen_ladder, legendre_pi
from lightcurve_gp.attitude.rotations import (
    axis_angle_to_quat,
    matrix_to_quat,
    quat_conj,
    quat_left_matrix,
    quat_mul,
    quat_right_matrix,
    rotate,
    rotvec_to_quat,
)

__all__ = ["torque_free_motion", "principal_moments"]

#: samples × rates evaluated together (keeps the temporaries in cache)
CHUNK_ELEMENTS = 1 << 17


def principal_moments(inertia, *, like: Tensor) -> Tensor:
    """The principal moments ``(3,)`` (kg m², finite, > 0) on ``like``'s dtype and device; one-line ``ValueError``
    otherwise."""
    j = torch.as_tensor(inertia, dtype=like.dtype, device=like.device)
    if j.shape != (3,):
        raise ValueError(f"inertia: expected the three principal moments (3,) in kg m^2, got shape {tuple(j.shape)}")
    if not bool(torch.isfinite(j).all()) or bool((j <= 0).any()):
        raise ValueError(f"inertia: principal moments must be finite and > 0 kg m^2, got {j.tolist()}")
    return j


def _axis_quat(axis: int, angle: Tensor) -> Tensor:
    """``q(e_axis, angle)`` ``(..., 4)``."""
    half = 0.5 * angle
    zero = torch.zeros_like(half)
    parts = [zero, zero, zero, torch.cos(half)]
    parts[axis] = torch.sin(half)
    return torch.stack(parts, -1)


def _spin(omega0: Tensor, times: Tensor) -> tuple[Tensor, Tensor]:
    """Constant rate: ``Δ = q(ω̂, |ω| t)``."""
    delta = rotvec_to_quat(omega0.unsqueeze(-2) * times.unsqueeze(-1))
    return delta, omega0.unsqueeze(-2).expand(*delta.shape[:-1], 3)


def _symmetric(omega0: Tensor, j: Tensor, axis: int, times: Tensor) -> tuple[Tensor, Tensor]:
    """Regular precession about ``H`` of a body symmetric about ``axis`` (module docstring)."""
    i_s = j[axis]
    i_t = 0.5 * (j.sum() - i_s)
    h = j * omega0
    h_norm = torch.linalg.vector_norm(h, dim=-1, keepdim=True)
    still = h_norm == 0
    h_hat = torch.where(still, torch.tensor([0.0, 0.0, 1.0], dtype=j.dtype, device=j.device),
                        h / torch.where(still, 1.0, h_norm))
    nu_t = ((i_t - i_s) / i_t * omega0[..., axis]).unsqueeze(-1) * times  # (..., K)
    body = _axis_quat(axis, nu_t)
    about_h = axis_angle_to_quat(h_hat.unsqueeze(-2), h_norm / i_t * times)
    return quat_mul(body, about_h), rotate(body, omega0.unsqueeze(-2))


def _permutations(order: list[int], dtype, device) -> tuple[Tensor, Tensor]:
    """For the short-axis mode (``(1, 2, 3)`` = smallest, middle, largest moment) and the long-axis mode (largest,
    middle, smallest): the proper signed permutation matrices ``P (2, 3, 3)`` (``ω' = P ω``) and their quaternions
    ``p (2, 4)`` (``A(p) = P``)."""
    lo, mid, hi = order
    mats = []
    for a, b, c in ((lo, mid, hi), (hi, mid, lo)):
        cyclic = (b - a) % 3 == 1 and (c - b) % 3 == 1
        m = torch.zeros(3, 3, dtype=dtype, device=device)
        m[0, a], m[1, b], m[2, c] = 1.0, 1.0, 1.0 if cyclic else -1.0
        mats.append(m)
    mats = torch.stack(mats)
    return mats, matrix_to_quat(mats)


def _euler313(psi: Tensor, theta: Tensor, phi: Tensor) -> Tensor:
    """``q(e_3, ψ) ⊗ q(e_1, θ) ⊗ q(e_3, φ)`` ``(..., 4)`` written out."""
    st, ct = torch.sin(0.5 * theta), torch.cos(0.5 * theta)
    diff, summ = 0.5 * (psi - phi), 0.5 * (psi + phi)
    return torch.stack([st * torch.cos(diff), -st * torch.sin(diff), ct * torch.sin(summ), ct * torch.cos(summ)], -1)


def _body_angles(sn: Tensor, cn: Tensor, dn: Tensor, am: Tensor, c: dict) -> tuple[Tensor, Tensor, Tensor]:
    """``ψ`` (continuous), ``θ`` and ``ω' (..., 3)`` from the Jacobi functions of ``u`` (``am`` unwrapped)."""
    alpha, beta = c["alpha"], c["beta"]
    chi = am + torch.atan2((beta - alpha) * sn * cn, alpha * cn * cn + beta * sn * sn)
    psi = 0.5 * math.pi - c["s2"] * chi
    w1, w2, w3 = c["A1"] * cn, c["s2"] * c["A2"] * sn, c["s3"] * c["A3"] * dn
    h_perp = torch.sqrt((c["I1"] * w1).square() + (c["I2"] * w2).square())
    theta = torch.atan2(h_perp, c["I3"] * w3)
    return psi, theta, torch.stack([w1, w2, w3], -1)


def _parameters(omega0: Tensor, j: Tensor, order: list[int]) -> dict:
    """The mode, the permuted moments and rates and the elliptic parameters ``m, mc, n`` ``(...)`` of rates with no
    principal spin (module docstring)."""
    lo, mid, hi = order
    mats, quats = _permutations(order, omega0.dtype, omega0.device)
    w_lo, w_mid, w_hi = omega0[..., lo], omega0[..., mid], omega0[..., hi]
    sam = j[lo] * (j[mid] - j[lo]) * w_lo ** 2 <= j[hi] * (j[hi] - j[mid]) * w_hi ** 2  # H² ≥ 2T I_mid
    sign3 = mats[:, 2].sum(-1)  # ±1: the third row's sign per mode
    i1, i2, i3 = torch.where(sam, j[lo], j[hi]), j[mid].expand_as(w_mid), torch.where(sam, j[hi], j[lo])
    w1, w2 = torch.where(sam, w_lo, w_hi), w_mid
    w3 = torch.where(sam, sign3[0] * w_hi, sign3[1] * w_lo)
    d12, d13, d23 = (i2 - i1).abs(), (i3 - i1).abs(), (i3 - i2).abs()
    q1 = i2 * d12 * w2 ** 2 + i3 * d13 * w3 ** 2
    q3 = i1 * d13 * w1 ** 2 + i2 * d23 * w2 ** 2
    dist = (i3 * d23 * w3 ** 2 - i1 * d12 * w1 ** 2).clamp_min(0.0)
    eps = torch.finfo(omega0.dtype).eps
    return dict(sam=sam, mats=mats, quats=quats, i1=i1, i2=i2, i3=i3, w1=w1, w2=w2, w3=w3, d12=d12, d13=d13,
                d23=d23, q1=q1, q3=q3, mc=(d13 * dist / (d23 * q1)).clamp_min(eps * eps),
                m=(d12 * q3 / (d23 * q1)).clamp(0.0, 1.0), n=-i3 * d12 / (i1 * d23))


def _carlson_steps(prm: dict) -> Tensor:
    """Duplication steps ``(...)`` the rates' integrals need (their complete ones are the worst case)."""
    zero, one = torch.zeros_like(prm["m"]), torch.ones_like(prm["m"])
    return carlson_steps(zero, prm["mc"], one, 1.0 - prm["n"])


def _triaxial_constants(omega0: Tensor, j: Tensor, order: list[int]) -> dict:
    """Per-rate constants of the elliptic solution ``(...)`` (module docstring); ``omega0`` has no principal spin."""
    prm = _parameters(omega0, j, order)
    sam, mats, quats, mc, m = prm["sam"], prm["mats"], prm["quats"], prm["mc"], prm["m"]
    i1, i2, i3, w1, w2, w3 = (prm[k] for k in ("i1", "i2", "i3", "w1", "w2", "w3"))
    d13, d23, q1, q3 = prm["d13"], prm["d23"], prm["q1"], prm["q3"]
    s3 = torch.where(w3 < 0, -1.0, 1.0).to(omega0.dtype)
    s2 = torch.where(sam, s3, -s3)
    a1, a2 = torch.sqrt(q3 / (i1 * d13)), torch.sqrt(q3 / (i2 * d23))
    c = dict(sam=sam, I1=i1, I2=i2, I3=i3, A1=a1, A2=a2, A3=torch.sqrt(q1 / (i3 * d13)),
             lam=torch.sqrt(d23 * q1 / (i1 * i2 * i3)), s2=s2, s3=s3, n=prm["n"],
             alpha=i1 * a1, beta=i2 * a2, ladder=landen_ladder(m, mc))
    c["H"] = torch.sqrt((i1 * w1) ** 2 + (i2 * w2) ** 2 + (i3 * w3) ** 2)
    c["g"] = c["H"] * (i3 - i1) / (i3 * i1)
    c["P"] = torch.where(sam[..., None, None], mats[0], mats[1])
    p = torch.where(sam[..., None], quats[0], quats[1])
    zero, one = torch.zeros_like(m), torch.ones_like(m)
    c["steps"] = int(_carlson_steps(prm).max())
    rf, rj = carlson_rf_rj(zero, mc, one, 1.0 - c["n"], steps=c["steps"])
    c["K"], c["Pi"] = rf, rf + (c["n"] / 3.0) * rj
    # the phase at t = 0: cn u0 = ω'_1/A_1, sn u0 = ω'_2/(s_2 A_2), am u0 = m0 π + φ_r with |φ_r| ≤ π/2
    am0 = torch.atan2(w2 / (s2 * a2), w1 / a1)
    m0 = torch.round(am0 / math.pi)
    phi_r = am0 - m0 * math.pi
    sn0, cn0 = torch.sin(phi_r), torch.cos(phi_r)
    f0, pi0 = legendre_pi(c["n"], sn0, cn0, mc + m * cn0 * cn0, steps=c["steps"])
    c["u0"] = 2.0 * m0 * c["K"] + f0
    c["Pi0"] = 2.0 * m0 * c["Pi"] + pi0
    par = 1.0 - 2.0 * torch.remainder(m0, 2.0)
    psi0, theta0, _ = _body_angles(par * sn0, par * cn0, torch.sqrt(mc + m * cn0 * cn0), am0, c)
    right = quat_mul(quat_conj(_euler313(psi0, theta0, torch.zeros_like(psi0))), p)
    c["M4"] = quat_left_matrix(quat_conj(p)) @ quat_right_matrix(right)  # Δ = M4 E(ψ, θ, Δφ)
    return c


def _triaxial(c: dict, times: Tensor) -> tuple[Tensor, Tensor]:
    """``Δ (..., K, 4)`` and ``ω (..., K, 3)`` of the elliptic solution with constants ``c`` at ``times (K,)``."""
    ex = lambda name: c[name].unsqueeze(-1)  # noqa: E731  per-rate constant against the samples
    u = ex("u0") + ex("lam") * times
    two_k = 2.0 * ex("K")
    turns = torch.round(u / two_k)
    r = u - two_k * turns
    sn, cn, dn, am = jacobi_sn_cn_dn(r, c["ladder"])
    _, pi_r = legendre_pi(ex("n"), sn, cn, dn * dn, steps=c["steps"], f=r)  # F(am r) = r
    par = 1.0 - 2.0 * torch.remainder(turns, 2.0)
    per = {k: (v.unsqueeze(-1) if isinstance(v, Tensor) and v.ndim == c["lam"].ndim else v) for k, v in c.items()}
    psi, theta, w_primed = _body_angles(par * sn, par * cn, dn, am + math.pi * turns, per)
    dphi = ex("H") / ex("I3") * times + ex("g") / ex("lam") * (2.0 * turns * ex("Pi") + pi_r - ex("Pi0"))
    e = _euler313(psi, theta, dphi)
    delta = torch.einsum("...ij,...kj->...ki", c["M4"], e)
    omega = torch.einsum("...ji,...kj->...ki", c["P"], w_primed)
    return delta, omega


def _degenerate(omega0: Tensor) -> Tensor:
    """Rates ``(...)`` with at most one non-zero component (a principal-axis spin or no rotation)."""
    return (omega0 != 0).sum(-1) <= 1


def torque_free_motion(omega0: Tensor, *, inertia, times: Tensor) -> tuple[Tensor, Tensor]:
    """The rotation ``Δ(t)`` and body rate ``ω(t)`` of the torque-free motion with body rate ``omega0 (..., 3)``
    (rad/s) at ``t = 0``, for principal moments ``inertia (3,)`` (kg m²), at ``times (K,)`` (s, any order, any
    spacing, negative allowed).

    Returns:
        ``(delta (..., K, 4), omega (..., K, 3))`` with ``q(t_k) = delta[..., k, :] ⊗ q(0)`` (unit quaternions,
        continuous in ``t`` from the identity) and ``ω(t_k)`` in rad/s, on ``omega0``'s dtype and device.
    """
    if not isinstance(omega0, Tensor) or omega0.ndim == 0 or omega0.shape[-1] != 3 or not omega0.is_floating_point():
        raise ValueError(f"omega0: expected a floating tensor (..., 3) of body rates in rad/s, got "
                         f"{getattr(omega0, 'shape', type(omega0).__name__)}")
    times = torch.as_tensor(times, dtype=omega0.dtype, device=omega0.device)
    if times.ndim != 1:
        raise ValueError(f"times: expected a vector (K,) of seconds, got shape {tuple(times.shape)}")
    if not bool(torch.isfinite(omega0).all()) or not bool(torch.isfinite(times).all()):
        raise ValueError("omega0 and times must be finite")
    j = principal_moments(inertia, like=omega0)
    order = sorted(range(3), key=lambda i: float(j[i]))
    lo, mid, hi = order
    tol = 8.0 * torch.finfo(omega0.dtype).eps * float(j[hi])
    near_lo, near_hi = float(j[mid] - j[lo]) <= tol, float(j[hi] - j[mid]) <= tol
    if near_lo and near_hi:
        return _spin(omega0, times)
    if near_lo or near_hi:
        return _symmetric(omega0, j, hi if near_lo else lo, times)
    batch = omega0.shape[:-1]
    flat = omega0.reshape(-1, 3)
    spin = _degenerate(flat)
    safe = torch.where(spin[:, None], torch.tensor([0.3, 0.5, 0.7], dtype=flat.dtype, device=flat.device), flat)
    # rates grouped by the duplication steps they need, so that a few hard ones (near the separatrix, a large |n|)
    # do not set every rate's cost
    need = _carlson_steps(_parameters(safe, j, order))
    per = max(1, CHUNK_ELEMENTS // max(1, times.numel()))
    delta = flat.new_empty(flat.shape[0], times.numel(), 4)
    omega = flat.new_empty(flat.shape[0], times.numel(), 3)
    for value in torch.unique(need).tolist():
        for rows in torch.nonzero(need == value).squeeze(-1).split(per):
            delta[rows], omega[rows] = _triaxial(_triaxial_constants(safe[rows], j, order), times)
    if bool(spin.any()):
        d_spin, w_spin = _spin(flat, times)
        delta = torch.where(spin[:, None, None], d_spin, delta)
        omega = torch.where(spin[:, None, None], w_spin, omega)
    return delta.reshape(*batch, times.numel(), 4), omega.reshape(*batch, times.numel(), 3)
