"""Identities of the rotations module: products, attitude matrices, Euler 3-2-1 angles, GRP, rotation vectors."""

import math

import pytest
import torch

from lightcurve_gp.attitude.rotations import (
    attitude_matrix,
    axis_angle_to_quat,
    euler321_to_quat,
    grp_to_quat,
    identity_quat,
    quat_canonical,
    quat_conj,
    quat_inv,
    quat_mul,
    quat_normalize,
    quat_to_euler321,
    quat_to_grp,
    quat_to_rotvec,
    rotate,
    rotvec_to_quat,
)

F64 = torch.float64


def random_quats(*shape: int, seed: int = 0, dtype=F64) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return quat_normalize(torch.randn(*shape, 4, generator=g, dtype=F64)).to(dtype)


def random_euler(n: int, seed: int = 0) -> torch.Tensor:
    """Yaw, roll in (−π, π), pitch in (−π/2, π/2), kept 0.1 rad away from gimbal lock and the ±π cut."""
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, 3, generator=g, dtype=F64) * 2 - 1
    return u * torch.tensor([math.pi - 0.1, math.pi / 2 - 0.1, math.pi - 0.1], dtype=F64)


def test_product_composes_attitude_matrices():
    q, p = random_quats(50, seed=1), random_quats(50, seed=2)
    torch.testing.assert_close(attitude_matrix(quat_mul(q, p)), attitude_matrix(q) @ attitude_matrix(p),
                               rtol=0, atol=1e-14)


def test_product_matches_the_papers_formula():
    q, p = random_quats(10, seed=3), random_quats(10, seed=4)
    qv, q4, pv, p4 = q[:, :3], q[:, 3:], p[:, :3], p[:, 3:]
    expected = torch.cat([q4 * pv + p4 * qv - torch.linalg.cross(qv, pv),
                          q4 * p4 - (qv * pv).sum(-1, keepdim=True)], -1)
    torch.testing.assert_close(quat_mul(q, p), expected, rtol=0, atol=1e-15)


def test_attitude_matrix_is_a_rotation():
    a = attitude_matrix(random_quats(100, seed=5))
    eye = torch.eye(3, dtype=F64).expand(100, 3, 3)
    torch.testing.assert_close(a @ a.transpose(-1, -2), eye, rtol=0, atol=1e-14)
    torch.testing.assert_close(torch.linalg.det(a), torch.ones(100, dtype=F64), rtol=0, atol=1e-14)


def test_attitude_matrix_matches_its_closed_form():
    """A(q) = (q4² − |q̄|²) I + 2 q̄ q̄ᵀ − 2 q4 [q̄×]."""
    q = random_quats(20, seed=6)
    qv, q4 = q[:, :3], q[:, 3]
    x, y, z = qv.unbind(-1)
    zero = torch.zeros_like(x)
    cross = torch.stack([torch.stack([zero, -z, y], -1), torch.stack([z, zero, -x], -1),
                         torch.stack([-y, x, zero], -1)], -2)
    expected = ((q4 * q4 - (qv * qv).sum(-1))[:, None, None] * torch.eye(3, dtype=F64)
                + 2 * qv[:, :, None] * qv[:, None, :] - 2 * q4[:, None, None] * cross)
    torch.testing.assert_close(attitude_matrix(q), expected, rtol=0, atol=1e-15)
    v = torch.randn(20, 3, generator=torch.Generator().manual_seed(0), dtype=F64)
    torch.testing.assert_close(rotate(q, v), (expected @ v[:, :, None])[:, :, 0], rtol=0, atol=1e-15)


def test_inverse_and_conjugate_give_the_identity():
    q = random_quats(30, seed=7)
    ident = identity_quat(30, dtype=F64)
    torch.testing.assert_close(quat_mul(q, quat_inv(q)), ident, rtol=0, atol=1e-15)
    torch.testing.assert_close(quat_mul(quat_inv(q), q), ident, rtol=0, atol=1e-15)
    torch.testing.assert_close(quat_mul(q, quat_conj(q)), ident, rtol=0, atol=1e-15)
    scaled = 3.0 * q  # the inverse of a non-unit quaternion
    torch.testing.assert_close(quat_mul(scaled, quat_inv(scaled)), ident, rtol=0, atol=1e-15)
    torch.testing.assert_close(attitude_matrix(identity_quat(dtype=F64)), torch.eye(3, dtype=F64))


def test_conjugation_keeps_the_scalar_part_and_rotates_the_vector_part_by_the_attitude_matrix():
    """δ ⊗ [v; s] ⊗ δ⁻¹ = [A(δ) v; s]: why a USQUE error GRP propagates as A(δ) p under a known rotation δ."""
    delta = random_quats(40, seed=11)
    x = torch.randn(40, 4, generator=torch.Generator().manual_seed(12), dtype=F64)  # any quaternion
    conj = quat_mul(quat_mul(delta, x), quat_conj(delta))
    torch.testing.assert_close(conj[:, 3], x[:, 3], rtol=0, atol=1e-14)
    torch.testing.assert_close(conj[:, :3], (attitude_matrix(delta) @ x[:, :3, None])[..., 0], rtol=0, atol=1e-14)
    p = quat_to_grp(quat_normalize(x))
    torch.testing.assert_close(quat_to_grp(quat_normalize(conj)), (attitude_matrix(delta) @ p[..., None])[..., 0],
                               rtol=0, atol=1e-13)


def test_normalize_rejects_a_zero_quaternion():
    with pytest.raises(ValueError, match="zero quaternion"):
        quat_normalize(torch.zeros(2, 4))


def test_euler_round_trip():
    euler = random_euler(200, seed=8)
    q = euler321_to_quat(euler)
    torch.testing.assert_close(torch.linalg.vector_norm(q, dim=-1), torch.ones(200, dtype=F64), rtol=0, atol=1e-15)
    torch.testing.assert_close(quat_to_euler321(q), euler, rtol=0, atol=1e-12)
    # quaternion → Euler → quaternion gives the same attitude (up to sign)
    qr = random_quats(200, seed=9)
    torch.testing.assert_close(quat_canonical(euler321_to_quat(quat_to_euler321(qr))), quat_canonical(qr),
                               rtol=0, atol=1e-12)


def test_euler_matrix_is_the_papers_r_b_i():
    """Paper Eq. (16), written out entry by entry, with φ = yaw, θ = pitch, ψ = roll."""
    euler = random_euler(50, seed=10)
    phi, theta, psi = euler.unbind(-1)
    c, s = torch.cos, torch.sin
    r = torch.stack([
        torch.stack([c(theta) * c(phi), c(theta) * s(phi), -s(theta)], -1),
        torch.stack([s(theta) * s(psi) * c(phi) - c(psi) * s(phi), s(theta) * s(psi) * s(phi) + c(psi) * c(phi),
                     c(theta) * s(psi)], -1),
        torch.stack([s(theta) * c(psi) * c(phi) + s(psi) * s(phi), s(theta) * c(psi) * s(phi) - s(psi) * c(phi),
                     c(theta) * c(psi)], -1),
    ], -2)
    torch.testing.assert_close(attitude_matrix(euler321_to_quat(euler)), r, rtol=0, atol=1e-14)


@pytest.mark.parametrize(
    "axis, angle_deg, expected_deg",
    [
        ([0.0, 0.0, 1.0], 30.0, [30.0, 0.0, 0.0]),  # pure yaw
        ([0.0, 0.0, 1.0], -135.0, [-135.0, 0.0, 0.0]),
        ([0.0, 1.0, 0.0], 40.0, [0.0, 40.0, 0.0]),  # pure pitch
        ([0.0, 1.0, 0.0], -75.0, [0.0, -75.0, 0.0]),
        ([1.0, 0.0, 0.0], 120.0, [0.0, 0.0, 120.0]),  # pure roll
        ([1.0, 0.0, 0.0], -20.0, [0.0, 0.0, -20.0]),
    ],
)
def test_euler_angles_of_single_axis_rotations(axis, angle_deg, expected_deg):
    q = axis_angle_to_quat(torch.tensor(axis, dtype=F64), torch.deg2rad(torch.tensor(angle_deg, dtype=F64)))
    torch.testing.assert_close(torch.rad2deg(quat_to_euler321(q)), torch.tensor(expected_deg, dtype=F64),
                               rtol=0, atol=1e-12)


def test_euler_sequence_is_yaw_then_pitch_then_roll():
    """q(φ, θ, ψ) = q_x(ψ) ⊗ q_y(θ) ⊗ q_z(φ): the yaw is applied first."""
    yaw, pitch, roll = 0.3, -0.4, 1.1
    ax = lambda v, a: axis_angle_to_quat(torch.tensor(v, dtype=F64), torch.tensor(a, dtype=F64))  # noqa: E731
    expected = quat_mul(ax([1.0, 0, 0], roll), quat_mul(ax([0, 1.0, 0], pitch), ax([0, 0, 1.0], yaw)))
    torch.testing.assert_close(euler321_to_quat(torch.tensor([yaw, pitch, roll], dtype=F64)), expected,
                               rtol=0, atol=1e-15)


@pytest.mark.parametrize("a, f", [(1.0, None), (1.0, 4.0), (0.5, 3.0), (0.0, 1.0)])
def test_grp_round_trip(a, f):
    q = quat_canonical(random_quats(200, seed=11))
    q = q[q[:, 3] > 0.05]  # a = 0 (Gibbs vector) is singular at 180°
    p = quat_to_grp(q, a=a, f=f)
    torch.testing.assert_close(grp_to_quat(p, a=a, f=f), q, rtol=0, atol=1e-13)
    torch.testing.assert_close(quat_to_grp(grp_to_quat(p, a=a, f=f), a=a, f=f), p, rtol=0, atol=1e-12)


def test_grp_definition_and_default_scale():
    q = quat_canonical(random_quats(10, seed=12))
    torch.testing.assert_close(quat_to_grp(q), 4.0 * q[:, :3] / (1.0 + q[:, 3:]), rtol=0, atol=1e-15)
    torch.testing.assert_close(quat_to_grp(q, a=0.5), 3.0 * q[:, :3] / (0.5 + q[:, 3:]), rtol=0, atol=1e-15)


def test_grp_is_the_rotation_vector_to_first_order():
    """With a = 1, f = 4: p = 4 tan(Φ/4) e = Φ e + Φ³/48 e + …, so |p − Φe| = O(Φ³)."""
    e = torch.tensor([1.0, -2.0, 2.0], dtype=F64) / 3.0
    for angle in (1e-1, 1e-2, 1e-3):
        rotvec = angle * e
        err = torch.linalg.vector_norm(quat_to_grp(rotvec_to_quat(rotvec)) - rotvec)
        assert float(err) == pytest.approx(angle**3 / 48.0, rel=1e-2)


def test_q_and_minus_q_are_the_same_attitude():
    q = random_quats(40, seed=13)
    torch.testing.assert_close(attitude_matrix(-q), attitude_matrix(q), rtol=0, atol=0)
    torch.testing.assert_close(quat_to_grp(-q), quat_to_grp(q), rtol=0, atol=0)
    torch.testing.assert_close(quat_to_rotvec(-q), quat_to_rotvec(q), rtol=0, atol=0)
    assert bool((quat_canonical(q)[:, 3] >= 0).all())


def test_rotvec_round_trip():
    g = torch.Generator().manual_seed(14)
    axes = torch.randn(100, 3, generator=g, dtype=F64)
    axes = axes / torch.linalg.vector_norm(axes, dim=-1, keepdim=True)
    angles = torch.rand(100, generator=g, dtype=F64) * (math.pi - 1e-3)
    angles[:5] = torch.tensor([0.0, 1e-12, 1e-8, 1e-5, 1e-3], dtype=F64)  # small angles, exact and smooth
    rotvec = axes * angles[:, None]
    q = rotvec_to_quat(rotvec)
    torch.testing.assert_close(q, axis_angle_to_quat(axes, angles), rtol=0, atol=1e-15)
    torch.testing.assert_close(quat_to_rotvec(q), rotvec, rtol=0, atol=1e-12)
    qr = random_quats(100, seed=15)
    torch.testing.assert_close(rotvec_to_quat(quat_to_rotvec(qr)), quat_canonical(qr), rtol=0, atol=1e-14)


def test_batched_shapes_with_several_leading_dims():
    q = random_quats(2, 3, 5, seed=16)
    assert quat_mul(q, q).shape == (2, 3, 5, 4)
    assert quat_mul(q, q[0, 0, 0]).shape == (2, 3, 5, 4)  # broadcasting
    assert attitude_matrix(q).shape == (2, 3, 5, 3, 3)
    assert quat_to_euler321(q).shape == (2, 3, 5, 3)
    assert euler321_to_quat(quat_to_euler321(q)).shape == (2, 3, 5, 4)
    assert quat_to_grp(q).shape == grp_to_quat(quat_to_grp(q)).shape[:-1] + (3,)
    assert quat_to_rotvec(q).shape == (2, 3, 5, 3) and rotvec_to_quat(quat_to_rotvec(q)).shape == (2, 3, 5, 4)
    assert rotate(q, torch.ones(3, dtype=F64)).shape == (2, 3, 5, 3)
    assert identity_quat(2, 3).shape == (2, 3, 4)
    # batched results equal the flattened ones
    flat = q.reshape(-1, 4)
    torch.testing.assert_close(attitude_matrix(q).reshape(-1, 3, 3), attitude_matrix(flat), rtol=0, atol=0)
    torch.testing.assert_close(quat_to_grp(q).reshape(-1, 3), quat_to_grp(flat), rtol=0, atol=0)


def test_float32_works():
    q = random_quats(100, seed=17, dtype=torch.float32)
    a = attitude_matrix(q)
    assert a.dtype == torch.float32
    torch.testing.assert_close(a @ a.transpose(-1, -2), torch.eye(3).expand(100, 3, 3), rtol=0, atol=1e-5)
    for out in (quat_mul(q, q), quat_to_euler321(q), quat_to_grp(q), grp_to_quat(quat_to_grp(q)), quat_to_rotvec(q),
                rotvec_to_quat(quat_to_rotvec(q)), euler321_to_quat(quat_to_euler321(q)), quat_inv(q)):
        assert out.dtype == torch.float32 and bool(torch.isfinite(out).all())
    torch.testing.assert_close(grp_to_quat(quat_to_grp(q)), quat_canonical(q), rtol=0, atol=1e-5)
    torch.testing.assert_close(rotvec_to_quat(quat_to_rotvec(q)), quat_canonical(q), rtol=0, atol=1e-5)
    torch.testing.assert_close(attitude_matrix(euler321_to_quat(quat_to_euler321(q))), a, rtol=0, atol=1e-4)
    assert identity_quat(3, dtype=torch.float32).dtype == torch.float32


def test_gradients_flow():
    q = random_quats(4, seed=18).requires_grad_(True)
    assert torch.autograd.gradcheck(attitude_matrix, (q,))
    p = quat_to_grp(random_quats(4, seed=19)).requires_grad_(True)
    assert torch.autograd.gradcheck(grp_to_quat, (p,))
    assert torch.autograd.gradcheck(lambda x: grp_to_quat(x, a=0.5, f=3.0), (p,))
    # the identity is a smooth point of the rotation-vector map
    r = torch.zeros(2, 3, dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(rotvec_to_quat, (r,))


def test_product_matrices_are_the_papers_product():
    """``q ⊗ p = L(q) p = R(p) q`` for batches of arbitrary (not unit) quaternions."""
    from lightcurve_gp.attitude.rotations import quat_left_matrix, quat_right_matrix

    g = torch.Generator().manual_seed(11)
    q, p = torch.randn(2, 6, 4, generator=g, dtype=torch.float64)
    qp = quat_mul(q, p)
    torch.testing.assert_close((quat_left_matrix(q) @ p.unsqueeze(-1)).squeeze(-1), qp, rtol=0, atol=1e-15)
    torch.testing.assert_close((quat_right_matrix(p) @ q.unsqueeze(-1)).squeeze(-1), qp, rtol=0, atol=1e-15)
    assert quat_left_matrix(q).shape == (6, 4, 4)
