"""Quaternion algebra, attitude matrices, Euler 3-2-1 angles and generalised Rodrigues parameters.

Conventions (paper Sec. 2.3; docs/design.md):

* quaternions are **scalar last**, ``q = [e sin(Φ/2), cos(Φ/2)]``, shape ``(..., 4)``;
* the product is the paper's Eq. (13),
  ``q ⊗ p = [q4 p̄ + p4 q̄ − q̄ × p̄ ; q4 p4 − q̄·p̄]``, so that ``A(q ⊗ p) = A(q) A(p)``;
* ``A(q)`` maps inertial vectors to the body frame, ``v_b = A(q) v_i``;
* Euler 3-2-1 angles ``(φ, θ, ψ)`` = (yaw, pitch, roll) with ``A = R_x(ψ) R_y(θ) R_z(φ)`` (paper Eq. (16));
* GRP ``p = f q̄ / (a + q4)`` (Crassidis & Markley 2003), ``a = 1``, ``f = 2 (a + 1) = 4`` by default.

Every function works on tensors with arbitrary leading batch dimensions, on any device and floating dtype.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = [
    "quat_mul",
    "quat_left_matrix",
    "quat_right_matrix",
    "quat_conj",
    "quat_inv",
    "quat_normalize",
    "quat_canonical",
    "attitude_matrix",
    "matrix_to_quat",
    "axis_angle_to_quat",
    "rotvec_to_quat",
    "quat_to_rotvec",
    "euler321_to_quat",
    "quat_to_euler321",
    "matrix_to_euler321",
    "quat_to_grp",
    "grp_to_quat",
    "rotate",
    "identity_quat",
]


def identity_quat(*batch: int, dtype: torch.dtype | None = None, device=None) -> Tensor:
    """Identity attitudes ``[0, 0, 0, 1]`` of shape ``(*batch, 4)``."""
    q = torch.zeros(*batch, 4, dtype=dtype or torch.get_default_dtype(), device=device)
    q[..., 3] = 1.0
    return q


def quat_mul(q: Tensor, p: Tensor) -> Tensor:
    """Paper's quaternion product ``q ⊗ p`` (Eq. (13)); shapes broadcast, ``(..., 4)``."""
    qv, q4 = q[..., :3], q[..., 3:]
    pv, p4 = p[..., :3], p[..., 3:]
    qv, pv = torch.broadcast_tensors(qv, pv)  # linalg.cross needs operands of equal ndim
    vec = q4 * pv + p4 * qv - torch.linalg.cross(qv, pv, dim=-1)
    sca = q4 * p4 - (qv * pv).sum(-1, keepdim=True)
    return torch.cat([vec, sca], dim=-1)


# q ⊗ p = L(q) p = R(p) q: each 4×4 matrix is a signed gather of the four components (row-major index lists)
_LEFT_INDEX = (3, 2, 1, 0, 2, 3, 0, 1, 1, 0, 3, 2, 0, 1, 2, 3)
_LEFT_SIGN = (1, 1, -1, 1, -1, 1, 1, 1, 1, -1, 1, 1, -1, -1, -1, 1)
_RIGHT_SIGN = (1, -1, 1, 1, 1, 1, -1, 1, -1, 1, 1, 1, -1, -1, -1, 1)


def _signed_gather(q: Tensor, sign: tuple[int, ...]) -> Tensor:
    index = torch.tensor(_LEFT_INDEX, device=q.device)
    return (q.index_select(-1, index) * torch.tensor(sign, dtype=q.dtype, device=q.device)).unflatten(-1, (4, 4))


def quat_left_matrix(q: Tensor) -> Tensor:
    """``L(q)`` ``(..., 4, 4)`` with ``q ⊗ p = L(q) p`` for any ``p`` (the paper's product)."""
    return _signed_gather(q, _LEFT_SIGN)


def quat_right_matrix(p: Tensor) -> Tensor:
    """``R(p)`` ``(..., 4, 4)`` with ``q ⊗ p = R(p) q`` for any ``q`` (the paper's product)."""
    return _signed_gather(p, _RIGHT_SIGN)


def quat_conj(q: Tensor) -> Tensor:
    """Conjugate ``[−q̄, q4]``, shape ``(..., 4)``."""
    return torch.cat([-q[..., :3], q[..., 3:]], dim=-1)


def quat_inv(q: Tensor) -> Tensor:
    """Inverse ``q⁻¹ = q* / |q|²`` (equal to the conjugate for unit quaternions), shape ``(..., 4)``."""
    return quat_conj(q) / (q * q).sum(-1, keepdim=True)


def quat_normalize(q: Tensor) -> Tensor:
    """Scale to unit norm, shape ``(..., 4)``. A zero quaternion raises ``ValueError``."""
    norm = torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    if bool((norm == 0).any()):
        raise ValueError("cannot normalise a zero quaternion")
    return q / norm


def quat_canonical(q: Tensor) -> Tensor:
    """The sign representative with ``q4 ≥ 0`` (``q`` and ``−q`` are the same attitude), shape ``(..., 4)``."""
    return torch.where(q[..., 3:] < 0, -q, q)


def attitude_matrix(q: Tensor) -> Tensor:
    """Attitude matrix ``A(q) = (q4² − |q̄|²) I + 2 q̄ q̄ᵀ − 2 q4 [q̄×]`` (inertial → body).

    Args:
        q: unit quaternions ``(..., 4)``, scalar last.

    Returns:
        ``(..., 3, 3)`` rotation matrices with ``v_body = A(q) @ v_inertial``.
    """
    x, y, z, w = q.unbind(-1)
    xx, yy, zz, ww = x * x, y * y, z * z, w * w
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        torch.stack([ww + xx - yy - zz, 2 * (xy + wz), 2 * (xz - wy)], -1),
        torch.stack([2 * (xy - wz), ww - xx + yy - zz, 2 * (yz + wx)], -1),
        torch.stack([2 * (xz + wy), 2 * (yz - wx), ww - xx - yy + zz], -1),
    ]
    return torch.stack(rows, -2)


def matrix_to_quat(a: Tensor) -> Tensor:
    """The unit quaternion ``q`` (``q4 ≥ 0``) with ``attitude_matrix(q) = a`` for rotation matrices ``(..., 3, 3)``.

    Shepperd's method: of the four equivalent formulas the one with the largest square root is used, so the
    result is accurate for every rotation.
    """
    a11, a22, a33 = a[..., 0, 0], a[..., 1, 1], a[..., 2, 2]
    d23, d31, d12 = a[..., 1, 2] - a[..., 2, 1], a[..., 2, 0] - a[..., 0, 2], a[..., 0, 1] - a[..., 1, 0]
    s12, s13, s23 = a[..., 0, 1] + a[..., 1, 0], a[..., 0, 2] + a[..., 2, 0], a[..., 1, 2] + a[..., 2, 1]
    candidates = torch.stack([  # rows proportional to 4 q_i [q1, q2, q3, q4] for i = 4, 1, 2, 3
        torch.stack([d23, d31, d12, 1 + a11 + a22 + a33], -1),
        torch.stack([1 + a11 - a22 - a33, s12, s13, d23], -1),
        torch.stack([s12, 1 - a11 + a22 - a33, s23, d31], -1),
        torch.stack([s13, s23, 1 - a11 - a22 + a33, d12], -1),
    ], -2)
    best = torch.stack([a11 + a22 + a33, a11, a22, a33], -1).argmax(-1)
    q = torch.gather(candidates, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    return quat_canonical(q / torch.linalg.vector_norm(q, dim=-1, keepdim=True))


def rotate(q: Tensor, v: Tensor) -> Tensor:
    """Express inertial vectors in the body frame: ``A(q) v``; ``q (..., 4)``, ``v (..., 3)`` broadcast."""
    return (attitude_matrix(q) @ v.unsqueeze(-1)).squeeze(-1)


def axis_angle_to_quat(axis: Tensor, angle: Tensor) -> Tensor:
    """Quaternion ``[e sin(Φ/2), cos(Φ/2)]`` (paper Eq. (11)).

    Args:
        axis: unit rotation axes ``(..., 3)``.
        angle: rotation angles Φ in radians, shape ``(...)``; broadcasts against ``axis[..., 0]``.
    """
    half = 0.5 * angle
    return torch.cat([axis * torch.sin(half).unsqueeze(-1), torch.cos(half).unsqueeze(-1)], dim=-1)


def rotvec_to_quat(rotvec: Tensor) -> Tensor:
    """Rotation vector ``Φ e`` ``(..., 3)`` to a unit quaternion ``(..., 4)``; exact and smooth at Φ = 0."""
    angle = torch.linalg.vector_norm(rotvec, dim=-1, keepdim=True)
    half = 0.5 * angle
    # sin(Φ/2)/Φ with its Taylor series near zero, so the map is differentiable at the identity.
    small = angle < 1e-4
    safe = torch.where(small, torch.ones_like(angle), angle)
    scale = torch.where(small, 0.5 - angle * angle / 48.0, torch.sin(half) / safe)
    return torch.cat([rotvec * scale, torch.cos(half)], dim=-1)


def quat_to_rotvec(q: Tensor) -> Tensor:
    """Rotation vector ``Φ e`` (``Φ ∈ [0, π]``) of unit quaternions ``(..., 4)`` → ``(..., 3)``."""
    q = quat_canonical(q)
    vec_norm = torch.linalg.vector_norm(q[..., :3], dim=-1, keepdim=True)
    angle = 2.0 * torch.atan2(vec_norm, q[..., 3:])
    small = vec_norm < 1e-8
    scale = torch.where(small, 2.0 / q[..., 3:].clamp_min(1e-12), angle / torch.where(small, 1.0, vec_norm))
    return q[..., :3] * scale


def euler321_to_quat(euler: Tensor) -> Tensor:
    """Quaternion of 3-2-1 Euler angles ``(φ, θ, ψ)`` in radians ``(..., 3)``.

    The result satisfies ``A(q) = R_x(ψ) R_y(θ) R_z(φ)`` (paper Eq. (16)): a yaw rotation about z
    first, then pitch about the new y, then roll about the new x.
    """
    yaw, pitch, roll = (0.5 * euler).unbind(-1)
    zero = torch.zeros_like(yaw)
    qz = torch.stack([zero, zero, torch.sin(yaw), torch.cos(yaw)], -1)
    qy = torch.stack([zero, torch.sin(pitch), zero, torch.cos(pitch)], -1)
    qx = torch.stack([torch.sin(roll), zero, zero, torch.cos(roll)], -1)
    return quat_mul(qx, quat_mul(qy, qz))


def matrix_to_euler321(a: Tensor) -> Tensor:
    """3-2-1 Euler angles ``(φ, θ, ψ)`` in radians of attitude matrices ``(..., 3, 3)`` → ``(..., 3)``.

    ``φ = atan2(A12, A11)``, ``θ = −asin(A13)``, ``ψ = atan2(A23, A33)`` (1-based indices).
    """
    yaw = torch.atan2(a[..., 0, 1], a[..., 0, 0])
    pitch = -torch.asin(a[..., 0, 2].clamp(-1.0, 1.0))
    roll = torch.atan2(a[..., 1, 2], a[..., 2, 2])
    return torch.stack([yaw, pitch, roll], -1)


def quat_to_euler321(q: Tensor) -> Tensor:
    """3-2-1 Euler angles ``(φ, θ, ψ)`` in radians of unit quaternions ``(..., 4)`` → ``(..., 3)``."""
    return matrix_to_euler321(attitude_matrix(q))


def quat_to_grp(q: Tensor, a: float = 1.0, f: float | None = None) -> Tensor:
    """Generalised Rodrigues parameters ``p = f q̄ / (a + q4)`` of unit quaternions ``(..., 4)`` → ``(..., 3)``.

    The sign of ``q`` is chosen so that ``q4 ≥ 0`` first, which keeps ``p`` finite for every attitude
    when ``a = 1``. ``f`` defaults to ``2 (a + 1)``, which makes ``p`` equal to the rotation vector
    to first order.
    """
    f = 2.0 * (a + 1.0) if f is None else f
    q = quat_canonical(q)
    return f * q[..., :3] / (a + q[..., 3:])


def grp_to_quat(p: Tensor, a: float = 1.0, f: float | None = None) -> Tensor:
    """Unit quaternions ``(..., 4)`` of generalised Rodrigues parameters ``p`` ``(..., 3)`` (inverse of
    :func:`quat_to_grp`).

    ``q4 = (−a |p|² + f √(f² + (1 − a²) |p|²)) / (f² + |p|²)``, ``q̄ = (a + q4) p / f``
    (Crassidis & Markley 2003, eq. 33).
    """
    f = 2.0 * (a + 1.0) if f is None else f
    p2 = (p * p).sum(-1, keepdim=True)
    if a == 1.0:  # q = [2 f p, f² − |p|²] / (f² + |p|²): no square root
        return torch.cat([p * (2.0 * f), f * f - p2], dim=-1).div_(p2 + f * f)
    den = f * f + p2
    q4 = (-a * p2 + f * torch.sqrt(f * f + (1.0 - a * a) * p2)) / den
    return torch.cat([(a + q4) * p / f, q4], dim=-1)
