"""Torque-free rigid-body dynamics: Euler's equations, quaternion kinematics, fixed-step RK4.

Equations (paper Sec. 2.3; docs/design.md):

* Euler's equations with ``τ = 0`` (Eq. (18)): ``J ω̇ = −ω × J ω``, ω the body-frame rate;
* kinematics (Eq. (14)): ``q̇ = ½ [ω; 0] ⊗ q`` with the paper's product (``rotations.quat_mul``).

Units: rad, rad/s, s, kg m². Quaternions are scalar last. Every function is batched over leading dimensions
and works on any device and floating dtype.

Because ω does not depend on q and the kinematics are linear in q through a *left* product with ``[ω; 0]``,
one joint RK4 step maps ``q`` to ``δ_k ⊗ q``, where the (non-unit) quaternion ``δ_k`` depends only on
ω_k, J and dt (see :func:`quaternion_increments`). :func:`propagate` uses that: it integrates ω once on ω's
own batch shape and moves every attitude with one quaternion product per step.
"""

from __future__ import annotations

import math
from numbers import Integral, Real

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import quat_mul, quat_normalize

__all__ = ["euler_rates", "quaternion_rates", "rk4_rate_stages", "rk4_step", "rk4_stepper", "propagate",
           "quaternion_increments", "propagate_only"]


# --------------------------------------------------------------------------------------------- validation

def _check_last_dim(x: Tensor, n: int, name: str) -> None:
    if not isinstance(x, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if x.ndim == 0 or x.shape[-1] != n:
        raise ValueError(f"{name} must have shape (..., {n}), got {tuple(x.shape)}")
    if not x.is_floating_point():
        raise ValueError(f"{name} must be a floating tensor, got dtype {x.dtype}")


def _check_dt(dt) -> float:
    if isinstance(dt, Tensor):
        if dt.numel() != 1:
            raise ValueError(f"dt must be a scalar time step in seconds, got a tensor of shape {tuple(dt.shape)}")
        dt = float(dt)
    if isinstance(dt, bool) or not isinstance(dt, Real):
        raise ValueError(f"dt must be a real number of seconds, got {dt!r}")
    dt = float(dt)
    if not math.isfinite(dt) or dt <= 0.0:
        raise ValueError(f"dt must be a finite time step > 0 s, got {dt}")
    return dt


def _check_steps(n_steps) -> int:
    if isinstance(n_steps, bool) or not isinstance(n_steps, Integral) or n_steps < 0:
        raise ValueError(f"n_steps must be an integer >= 0, got {n_steps!r}")
    return int(n_steps)


def _as_inertia(inertia, like: Tensor) -> Tensor:
    """Validated inertia on ``like``'s dtype/device: ``(3,)`` principal moments or a ``(3, 3)`` tensor."""
    j = torch.as_tensor(inertia, dtype=like.dtype, device=like.device)
    if j.shape == (3,):
        if not bool(torch.isfinite(j).all()) or bool((j <= 0).any()):
            raise ValueError(f"inertia: principal moments must be finite and > 0 kg m^2, got {j.tolist()}")
        return j
    if j.shape == (3, 3):
        if not bool(torch.isfinite(j).all()):
            raise ValueError(f"inertia: the matrix must be finite, got {j.tolist()}")
        if not torch.allclose(j, j.T, rtol=1e-10, atol=1e-12 * float(j.abs().max())):
            raise ValueError(f"inertia: the matrix must be symmetric, got {j.tolist()}")
        if bool((torch.linalg.eigvalsh(j.double()) <= 0).any()):
            raise ValueError(f"inertia: the matrix must be positive definite, got {j.tolist()}")
        return j
    raise ValueError(f"inertia must be a (3,) diagonal or a (3, 3) matrix, got shape {tuple(j.shape)}")


# --------------------------------------------------------------------------------------------- rates

def _rates_fn(j: Tensor):
    """A cheap ``ω ↦ ω̇`` for a validated inertia (the diagonal case needs no cross product or solve)."""
    if j.ndim == 1:
        # ω̇1 = (J2 − J3)/J1 ω2 ω3, ω̇2 = (J3 − J1)/J2 ω3 ω1, ω̇3 = (J1 − J2)/J3 ω1 ω2
        c = (j.roll(-1) - j.roll(-2)) / j
        return lambda w: c * w.roll(-1, dims=-1) * w.roll(-2, dims=-1)
    j_inv = torch.linalg.inv(j)
    return lambda w: -(torch.linalg.cross(w, w @ j.T, dim=-1) @ j_inv.T)


def euler_rates(omega: Tensor, inertia) -> Tensor:
    """Torque-free Euler equations ``ω̇ = J⁻¹ (−ω × J ω)``.

    Args:
        omega: body rates ``(..., 3)`` in rad/s.
        inertia: ``(3,)`` principal moments or a symmetric positive-definite ``(3, 3)`` matrix (kg m²).

    Returns:
        ``ω̇`` ``(..., 3)`` in rad/s².
    """
    _check_last_dim(omega, 3, "omega")
    return _rates_fn(_as_inertia(inertia, omega))(omega)


def _pure(omega: Tensor) -> Tensor:
    """The pure quaternion ``[ω; 0]``."""
    return torch.cat([omega, torch.zeros_like(omega[..., :1])], dim=-1)


def quaternion_rates(q: Tensor, omega: Tensor) -> Tensor:
    """Kinematics ``q̇ = ½ [ω; 0] ⊗ q`` (paper Eq. (14)); ``q (..., 4)``, ``ω (..., 3)`` broadcast."""
    _check_last_dim(q, 4, "q")
    _check_last_dim(omega, 3, "omega")
    return 0.5 * quat_mul(_pure(omega), q)


# --------------------------------------------------------------------------------------------- RK4

def rk4_rate_stages(omega: Tensor, rates, dt: float):
    """The four RK4 stage rates ``ω_1..ω_4`` and the stepped ω of ``ω̇ = rates(ω)``, in whatever layout ``rates``
    takes (``(..., 3)`` here; components first ``(3, ...)`` works the same)."""
    k1 = rates(omega)
    w2 = omega + (0.5 * dt) * k1
    k2 = rates(w2)
    w3 = omega + (0.5 * dt) * k2
    k3 = rates(w3)
    w4 = omega + dt * k3
    k4 = rates(w4)
    return (omega, w2, w3, w4), omega + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def rk4_step(q: Tensor, omega: Tensor, inertia, dt: float) -> tuple[Tensor, Tensor]:
    """One classical RK4 step of the joint state ``(q, ω)``; ``q`` is normalised afterwards.

    Args:
        q: unit quaternions ``(..., 4)``.
        omega: body rates ``(..., 3)`` in rad/s; broadcasts against ``q[..., :3]``.
        inertia: ``(3,)`` principal moments or a ``(3, 3)`` matrix (kg m²).
        dt: step in seconds (> 0).

    Returns:
        ``(q_next, omega_next)`` with the broadcast batch shape.
    """
    _check_last_dim(q, 4, "q")
    _check_last_dim(omega, 3, "omega")
    return rk4_stepper(inertia, dt, like=omega)(q, omega)


def rk4_stepper(inertia, dt: float, *, like: Tensor):
    """:func:`rk4_step` with the inertia and step validated once: a function ``(q, ω) ↦ (q_next, ω_next)``
    (shapes as :func:`rk4_step`; ``like`` gives the dtype and device of the inertia). A filter that moves every
    sigma point with its own rate calls it once per step on all of them."""
    dt = _check_dt(dt)
    rates = _rates_fn(_as_inertia(inertia, like))

    def step(q: Tensor, omega: Tensor) -> tuple[Tensor, Tensor]:
        (w1, w2, w3, w4), omega_next = rk4_rate_stages(omega, rates, dt)
        kq1 = 0.5 * quat_mul(_pure(w1), q)
        kq2 = 0.5 * quat_mul(_pure(w2), q + (0.5 * dt) * kq1)
        kq3 = 0.5 * quat_mul(_pure(w3), q + (0.5 * dt) * kq2)
        kq4 = 0.5 * quat_mul(_pure(w4), q + dt * kq3)
        q_next = q + (dt / 6.0) * (kq1 + 2.0 * kq2 + 2.0 * kq3 + kq4)
        q_next = q_next / torch.linalg.vector_norm(q_next, dim=-1, keepdim=True)
        batch = torch.broadcast_shapes(q.shape[:-1], omega.shape[:-1])
        return q_next.expand(*batch, 4), omega_next.expand(*batch, 3)

    return step


def _increment(stages: tuple[Tensor, Tensor, Tensor, Tensor], dt: float) -> Tensor:
    """``δ`` with ``RK4(q) = δ ⊗ q`` from the stage rates (pure quaternions ``w̃_i = [ω_i; 0]``).

    With ``p_1 = 1``, ``p_2 = 1 + dt/4 w̃_1``, ``p_3 = 1 + dt/4 w̃_2 ⊗ p_2``, ``p_4 = 1 + dt/2 w̃_3 ⊗ p_3``
    (the stage points are ``p_i ⊗ q``), ``δ = 1 + dt/12 (w̃_1 + 2 w̃_2 ⊗ p_2 + 2 w̃_3 ⊗ p_3 + w̃_4 ⊗ p_4)``.
    The products of a pure quaternion with ``1 + v`` are written out, which is cheaper than general products.
    """
    w1, w2, w3, w4 = stages

    def pure_times(w: Tensor, p: Tensor) -> Tensor:
        # [w; 0] ⊗ [pv; p4] = [p4 w − w × pv ; −w·pv]
        pv, p4 = p[..., :3], p[..., 3:]
        return torch.cat([p4 * w - torch.linalg.cross(w, pv, dim=-1), -(w * pv).sum(-1, keepdim=True)], dim=-1)

    one = torch.zeros_like(_pure(w1))
    one[..., 3] = 1.0
    p2 = one + (0.25 * dt) * _pure(w1)
    t2 = pure_times(w2, p2)
    p3 = one + (0.25 * dt) * t2
    t3 = pure_times(w3, p3)
    p4 = one + (0.5 * dt) * t3
    t4 = pure_times(w4, p4)
    return one + (dt / 12.0) * (_pure(w1) + 2.0 * t2 + 2.0 * t3 + t4)


def _omega_and_increments(omega0: Tensor, inertia, dt: float, n_steps: int) -> tuple[Tensor, Tensor]:
    """ω history ``(..., n_steps + 1, 3)`` and increments ``(..., n_steps, 4)`` on ω0's batch shape.

    Only the (cheap, 3-vector) rate integration is sequential; the increments of all steps are then
    built at once from the stacked stage rates.
    """
    rates = _rates_fn(_as_inertia(inertia, omega0))
    omegas, stages = [omega0], []
    w = omega0
    for _ in range(n_steps):
        st, w = rk4_rate_stages(w, rates, dt)
        stages.append(torch.stack(st, dim=-2))  # (..., 4 stages, 3)
        omegas.append(w)
    omega_hist = torch.stack(omegas, dim=-2)
    if n_steps == 0:
        return omega_hist, omega0.new_zeros(*omega0.shape[:-1], 0, 4)
    st = torch.stack(stages, dim=-3)  # (..., n_steps, 4, 3)
    return omega_hist, _increment(st.unbind(-2), dt)


def quaternion_increments(omega0: Tensor, inertia, dt: float, n_steps: int) -> Tensor:
    """Per-step RK4 increments ``δ_k`` of the kinematics for a known rate history.

    For the rate trajectory starting at ``omega0``, step ``k`` of :func:`rk4_step` maps any attitude
    ``q_k`` to ``normalise(δ_k ⊗ q_k)``. A filter whose sigma points share ω can thus move any number of
    attitudes with one ``quat_mul`` (and a normalisation) per step.

    Args:
        omega0: initial body rates ``(..., 3)`` in rad/s.
        inertia: ``(3,)`` principal moments or a ``(3, 3)`` matrix (kg m²).
        dt: step in seconds (> 0).
        n_steps: number of steps (>= 0).

    Returns:
        ``δ`` ``(..., n_steps, 4)`` (not unit quaternions; ``|δ_k| = 1 + O(dt⁵)``).
    """
    _check_last_dim(omega0, 3, "omega0")
    return _omega_and_increments(omega0, inertia, _check_dt(dt), _check_steps(n_steps))[1]


def propagate(q0: Tensor, omega0: Tensor, inertia, dt: float, n_steps: int) -> tuple[Tensor, Tensor]:
    """Propagate torque-free attitude motion with fixed-step RK4.

    Args:
        q0: initial unit quaternions ``(..., 4)``.
        omega0: initial body rates ``(..., 3)`` in rad/s; the batch shapes of ``q0`` and ``omega0`` broadcast
            (e.g. ``q0 (A, 4)`` with ``omega0 (3,)``).
        inertia: ``(3,)`` principal moments or a ``(3, 3)`` matrix (kg m²), shared by the batch.
        dt: step in seconds (> 0).
        n_steps: number of steps (>= 0).

    Returns:
        ``(q_hist, omega_hist)`` of shapes ``(..., n_steps + 1, 4)`` and ``(..., n_steps + 1, 3)`` with the
        broadcast batch shape; index 0 holds the initial state (``q0`` as given, not renormalised).
        ``omega_hist`` may be an expanded view when ``omega0`` has fewer batch elements than ``q0``.
    """
    _check_last_dim(q0, 4, "q0")
    _check_last_dim(omega0, 3, "omega0")
    dt, n_steps = _check_dt(dt), _check_steps(n_steps)
    batch = torch.broadcast_shapes(q0.shape[:-1], omega0.shape[:-1])
    # ω is integrated on its own (usually much smaller) batch shape; q follows with one product per step.
    omega_hist, delta = _omega_and_increments(omega0, inertia, dt, n_steps)
    q = q0.expand(*batch, 4)
    qs = [q]
    for k in range(n_steps):
        q = quat_mul(delta[..., k, :], q)
        q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
        qs.append(q)
    q_hist = torch.stack(qs, dim=-2)
    return q_hist, omega_hist.expand(*batch, n_steps + 1, 3)


def propagate_only(q_est0: Tensor, increments: Tensor) -> Tensor:
    """Attitudes moved by known increments alone (the no-update baseline): ``q_{k+1} = normalise(δ_k ⊗ q_k)`` from
    ``q_est0 (..., 4)`` → ``(..., T+1, 4)``."""
    out = [q_est0]
    for delta in increments:
        out.append(quat_normalize(quat_mul(delta, out[-1])))
    return torch.stack(out, dim=-2)
