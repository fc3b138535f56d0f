"""Torque-free dynamics: conservation laws, agreement with an adaptive integrator, batching, RK4 increments."""

import math

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp

from lightcurve_gp.attitude.dynamics import euler_rates, propagate, quaternion_increments, quaternion_rates, rk4_step
from lightcurve_gp.attitude.rotations import attitude_matrix, axis_angle_to_quat, quat_mul, quat_normalize

F64 = torch.float64
OMEGA0 = torch.deg2rad(torch.tensor([0.1, -0.1, -0.25], dtype=F64))  # the paper's ω0 (rad/s)
J_DIAG = torch.tensor([55.0, 40.0, 65.0], dtype=F64)  # the paper's J (kg m²)


def random_quats(n: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return quat_normalize(torch.randn(n, 4, generator=g, dtype=F64))


def test_euler_rates_match_the_component_form():
    w = torch.tensor([0.3, -0.2, 0.5], dtype=F64)
    j1, j2, j3 = J_DIAG.tolist()
    expected = torch.tensor([(j2 - j3) / j1 * w[1] * w[2], (j3 - j1) / j2 * w[2] * w[0], (j1 - j2) / j3 * w[0] * w[1]])
    torch.testing.assert_close(euler_rates(w, J_DIAG), expected.to(F64), rtol=1e-14, atol=0)
    torch.testing.assert_close(euler_rates(w, torch.diag(J_DIAG)), expected.to(F64), rtol=1e-13, atol=1e-17)


def test_quaternion_rates_match_the_omega_matrix():
    q = random_quats(5)
    w = torch.tensor([0.3, -0.2, 0.5], dtype=F64)
    wx = torch.tensor([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]], dtype=F64)
    omega = torch.zeros(4, 4, dtype=F64)  # Ω(ω) = [[−[ω×], ω], [−ωᵀ, 0]]
    omega[:3, :3], omega[:3, 3], omega[3, :3] = -wx, w, -w
    torch.testing.assert_close(quaternion_rates(q, w), 0.5 * q @ omega.T, rtol=0, atol=1e-16)


@pytest.fixture(scope="module")
def paper_run():
    q0 = axis_angle_to_quat(torch.tensor([1.0, 2.0, -2.0], dtype=F64) / 3.0, torch.tensor(1.1, dtype=F64))
    q, w = propagate(q0, OMEGA0, J_DIAG, 1.0, 600)
    return q0, q, w


def test_shapes_and_unit_norm(paper_run):
    q0, q, w = paper_run
    assert q.shape == (601, 4) and w.shape == (601, 3)
    assert torch.equal(q[0], q0) and torch.equal(w[0], OMEGA0)
    torch.testing.assert_close(torch.linalg.vector_norm(q, dim=-1), torch.ones(601, dtype=F64), rtol=0, atol=1e-14)


def test_energy_and_momentum_magnitude_are_conserved(paper_run):
    _, q, w = paper_run
    h = torch.linalg.vector_norm(J_DIAG * w, dim=-1)
    energy = 0.5 * (w * J_DIAG * w).sum(-1)
    assert float((h / h[0] - 1).abs().max()) < 1e-9
    assert float((energy / energy[0] - 1).abs().max()) < 1e-9
    assert float((w - w[0]).abs().max()) > 1e-5  # ω really moves (J is not symmetric), so the test means something


def test_inertial_angular_momentum_is_constant(paper_run):
    _, q, w = paper_run
    h_i = (attitude_matrix(q).transpose(-1, -2) @ (J_DIAG * w).unsqueeze(-1)).squeeze(-1)  # A(q)ᵀ J ω
    assert float(torch.linalg.vector_norm(h_i - h_i[0], dim=-1).max() / torch.linalg.vector_norm(h_i[0])) < 1e-9


def _rhs_numpy(_t, x, j):
    """Independent NumPy right-hand side: q̇ = ½ Ω(ω) q, ω̇ = J⁻¹(−ω × Jω)."""
    q, w = x[:4], x[4:]
    wx = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    omega = np.zeros((4, 4))
    omega[:3, :3], omega[:3, 3], omega[3, :3] = -wx, w, -w
    return np.concatenate([0.5 * omega @ q, np.linalg.solve(j, -np.cross(w, j @ w))])


@pytest.mark.parametrize("matrix", [False, True])
def test_agrees_with_dop853(paper_run, matrix):
    q0, q, w = paper_run
    j = np.diag(J_DIAG.numpy())
    if matrix:  # the (3, 3) path gives the same trajectory for a diagonal matrix
        q, w = propagate(q0, OMEGA0, torch.diag(J_DIAG), 1.0, 600)
    sol = solve_ivp(_rhs_numpy, (0.0, 600.0), np.concatenate([q0.numpy(), OMEGA0.numpy()]), method="DOP853",
                    rtol=1e-12, atol=1e-12, t_eval=np.arange(601.0), args=(j,))
    assert sol.success
    np.testing.assert_allclose(q.numpy(), sol.y[:4].T, rtol=0, atol=1e-9)
    np.testing.assert_allclose(w.numpy(), sol.y[4:].T, rtol=0, atol=1e-9)


def test_full_inertia_matrix_equals_a_rotated_principal_frame():
    """Body axes rotated by a constant C: J' = C J Cᵀ, ω' = C ω, q' = q_C ⊗ q (since A(q') = C A(q))."""
    q_c = axis_angle_to_quat(torch.tensor([0.6, 0.0, 0.8], dtype=F64), torch.tensor(0.7, dtype=F64))
    c = attitude_matrix(q_c)
    w0 = torch.tensor([0.2, -0.1, 0.3], dtype=F64)
    q0 = random_quats(3, seed=1)
    q, w = propagate(q0, w0, J_DIAG, 0.5, 200)
    q2, w2 = propagate(quat_mul(q_c, q0), c @ w0, c @ torch.diag(J_DIAG) @ c.T, 0.5, 200)
    torch.testing.assert_close(w2, w @ c.T, rtol=0, atol=1e-13)
    torch.testing.assert_close(q2, quat_mul(q_c, q), rtol=0, atol=1e-13)


def test_batch_equals_separate_runs_and_broadcasts():
    q0 = random_quats(6, seed=2).reshape(2, 3, 4)
    w0 = torch.randn(2, 3, 3, generator=torch.Generator().manual_seed(3), dtype=F64) * 0.1
    q, w = propagate(q0, w0, J_DIAG, 1.0, 50)
    assert q.shape == (2, 3, 51, 4) and w.shape == (2, 3, 51, 3)
    for i in range(2):
        for k in range(3):
            qs, ws = propagate(q0[i, k], w0[i, k], J_DIAG, 1.0, 50)
            torch.testing.assert_close(q[i, k], qs, rtol=0, atol=1e-15)
            torch.testing.assert_close(w[i, k], ws, rtol=0, atol=1e-15)
    # q0 (A, 4) with a shared ω0 (3,), as data.py uses it
    qa, wa = propagate(q0[0], OMEGA0, J_DIAG, 1.0, 10)
    assert qa.shape == (3, 11, 4) and wa.shape == (3, 11, 3)
    torch.testing.assert_close(qa[1], propagate(q0[0, 1], OMEGA0, J_DIAG, 1.0, 10)[0], rtol=0, atol=1e-15)


def test_propagate_equals_repeated_rk4_steps():
    q0, w0 = random_quats(4, seed=4), torch.tensor([0.3, -0.4, 0.2], dtype=F64)
    q_hist, w_hist = propagate(q0, w0, J_DIAG, 2.0, 30)
    q, w = q0, w0
    for k in range(30):
        q, w = rk4_step(q, w, J_DIAG, 2.0)
        torch.testing.assert_close(q_hist[:, k + 1], q, rtol=0, atol=1e-14)
        torch.testing.assert_close(w_hist[:, k + 1], w, rtol=0, atol=1e-15)


@pytest.mark.parametrize("inertia", [J_DIAG, torch.tensor([[50.0, 3.0, -2.0], [3.0, 40.0, 1.0], [-2.0, 1.0, 60.0]],
                                                         dtype=F64)])
def test_increments_reproduce_rk4_steps(inertia):
    """normalise(δ_k ⊗ q_k) is the q of rk4_step for any q_k, with a rate large enough for RK4 to be inexact."""
    w0 = torch.tensor([0.4, -0.3, 0.6], dtype=F64)
    dt, n = 1.0, 25
    delta = quaternion_increments(w0, inertia, dt, n)
    assert delta.shape == (n, 4)
    q, w = random_quats(64, seed=5), w0
    for k in range(n):
        q_ref, w = rk4_step(q, w, inertia, dt)
        q_inc = quat_mul(delta[k], q)
        q_inc = q_inc / torch.linalg.vector_norm(q_inc, dim=-1, keepdim=True)
        torch.testing.assert_close(q_inc, q_ref, rtol=0, atol=1e-14)
        q = q_ref
    # batched ω0: one δ history per rate
    w_batch = torch.stack([w0, -w0, 0.5 * w0])
    d_batch = quaternion_increments(w_batch, inertia, dt, n)
    assert d_batch.shape == (3, n, 4)
    torch.testing.assert_close(d_batch[0], delta, rtol=0, atol=1e-15)
    assert quaternion_increments(w0, inertia, dt, 0).shape == (0, 4)


def test_float32_and_zero_steps():
    q0 = random_quats(3).float()
    q, w = propagate(q0, OMEGA0.float(), J_DIAG.float(), 1.0, 20)
    assert q.dtype == torch.float32 and w.dtype == torch.float32
    q64, _ = propagate(q0.double(), OMEGA0, J_DIAG, 1.0, 20)
    torch.testing.assert_close(q.double(), q64, rtol=0, atol=1e-5)
    q, w = propagate(q0, OMEGA0.float(), J_DIAG, 1.0, 0)
    assert q.shape == (3, 1, 4) and torch.equal(q[:, 0], q0)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(q0=torch.zeros(5, 3)), r"q0 must have shape \(\.\.\., 4\), got \(5, 3\)"),
        (dict(omega0=torch.zeros(4)), r"omega0 must have shape \(\.\.\., 3\), got \(4,\)"),
        (dict(dt=0.0), "dt must be a finite time step > 0 s, got 0.0"),
        (dict(dt=-1.0), "dt must be a finite time step > 0 s, got -1.0"),
        (dict(dt=math.nan), "dt must be a finite time step > 0 s"),
        (dict(n_steps=-1), "n_steps must be an integer >= 0, got -1"),
        (dict(n_steps=2.5), "n_steps must be an integer >= 0, got 2.5"),
        (dict(inertia=torch.tensor([55.0, 0.0, 65.0])), "principal moments must be finite and > 0"),
        (dict(inertia=torch.tensor([55.0, -40.0, 65.0])), "principal moments must be finite and > 0"),
        (dict(inertia=torch.ones(4)), r"inertia must be a \(3,\) diagonal or a \(3, 3\) matrix, got shape \(4,\)"),
        (dict(inertia=torch.tensor([[1.0, 2.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])), "must be symmetric"),
        (dict(inertia=-torch.eye(3)), "must be positive definite"),
    ],
)
def test_bad_inputs_raise_clear_errors(kwargs, message):
    args = dict(q0=torch.tensor([0.0, 0.0, 0.0, 1.0]), omega0=torch.zeros(3), inertia=J_DIAG, dt=1.0, n_steps=3)
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        propagate(**args)


def test_bad_inputs_of_the_other_entry_points():
    with pytest.raises(ValueError, match="dt must be"):
        rk4_step(torch.tensor([0.0, 0.0, 0.0, 1.0]), torch.zeros(3), J_DIAG, 0)
    with pytest.raises(ValueError, match="dt must be"):
        quaternion_increments(torch.zeros(3), J_DIAG, -0.5, 3)
    with pytest.raises(ValueError, match="principal moments"):
        euler_rates(torch.zeros(3), [1.0, 0.0, 1.0])
    with pytest.raises(ValueError, match=r"omega must have shape \(\.\.\., 3\)"):
        quaternion_rates(torch.tensor([0.0, 0.0, 0.0, 1.0]), torch.zeros(2))
