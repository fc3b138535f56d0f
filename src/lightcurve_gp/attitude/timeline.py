"""Kinematic increments between the samples of an observed light curve, from a known torque-free spin.

A filter on a file steps from sample to sample, whatever the spacing: gaps and irregular timestamps are kept as
they are. Between samples ``t_k`` and ``t_{k+1}`` the attitude moves by ``q_{k+1} = normalise(δ_k ⊗ q_k)`` with
``δ_k = Δ(t_{k+1}) ⊗ Δ(t_k)⁻¹``, ``Δ`` the closed-form motion from the first sample
(:func:`lightcurve_gp.attitude.torque_free.torque_free_motion`): every increment is exact and costs the same
whatever the gap before it (a file spanning days takes no steps through its gaps). On a regular grid of step
``scenario.dt_s`` the increments agree with the simulated scenario's RK4 increments to RK4's own error.

The spin is the config's (``scenario.omega0_deg_s`` at the first sample, ``shape.inertia_kg_m2``): known, not
estimated. This is where an estimated spin would supply per-filter increments ``(B, T, 4)`` instead.
"""

from __future__ import annotations

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import quat_conj, quat_mul
from lightcurve_gp.attitude.torque_free import torque_free_motion

__all__ = ["spin_increments"]


def spin_increments(t: Tensor, *, omega0: Tensor, inertia) -> Tensor:
    """Increments ``δ_0 … δ_{T−1}`` ``(T, 4)`` (unit quaternions, ``omega0``'s dtype) between the sample times
    ``t (T+1,)`` (s, strictly increasing; float64 keeps a long file's late samples apart) for the torque-free motion
    that has body rate ``omega0 (3,)`` (rad/s) at ``t_0`` (principal moments ``inertia (3,)``, kg m²); module
    docstring."""
    if t.ndim != 1 or not bool((torch.diff(t) > 0).all()):
        raise ValueError("sample times must increase strictly")
    # in float64 whatever the run's dtype: an increment is the difference of two rotations that grow with t
    t64 = t.to(torch.float64)
    delta, _ = torque_free_motion(omega0.to(torch.float64), inertia=torch.as_tensor(inertia, dtype=torch.float64),
                                  times=t64 - t64[0])
    return quat_mul(delta[1:], quat_conj(delta[:-1])).to(omega0.dtype)
