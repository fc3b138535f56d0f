"""Kinematic increments between the samples of an observed light curve, from a known torque-free spin.

A filter on a file steps from sample to sample, whatever the spacing: gaps and irregular timestamps are kept as
they are. Between samples ``t_k`` and ``t_{k+1}`` the attitude moves by ``q_{k+1} = normalise(δ_k ⊗ q_k)``; ``δ_k``
composes RK4 increments (:func:`lightcurve_gp.attitude.dynamics.quaternion_increments`) of equal sub-steps no longer
than
``max_step`` (the config's ``scenario.dt_s``), so a long gap is integrated as accurately as a regular stretch.
On a regular grid whose step is ``max_step`` the increments are exactly those of the simulated scenario.

The spin is the config's (``scenario.omega0_deg_s`` at the first sample, ``shape.inertia_kg_m2``): known, not
estimated. This is where an estimated spin would supply per-filter increments ``(B, T, 4)`` instead.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from lightcurve_gp.attitude.dynamics import propagate, quaternion_increments
from lightcurve_gp.attitude.rotations import identity_quat, quat_mul

__all__ = ["sub_steps", "spin_increments"]


def sub_steps(t: Tensor, max_step: float) -> tuple[Tensor, Tensor]:
    """Number of equal sub-steps ``(T,)`` (int64) and their length ``(T,)`` (s) of each interval of the sample
    times ``t (T+1,)`` (s, strictly increasing), none longer than ``max_step``."""
    dt = torch.diff(t)
    if not bool((dt > 0).all()):
        raise ValueError("sample times must increase strictly")
    count = torch.ceil(dt / max_step - 1e-9).clamp_min(1).to(torch.int64)
    return count, dt / count


def _runs(count: Tensor, h: Tensor) -> list[tuple[int, int, float, int]]:
    """Consecutive intervals sharing a sub-step length: ``(first, end, h, sub-steps per interval)``."""
    runs, start = [], 0
    for k in range(1, count.numel() + 1):
        if k == count.numel() or h[k] != h[start] or count[k] != count[start]:
            runs.append((start, k, float(h[start]), int(count[start])))
            start = k
    return runs


def spin_increments(t: Tensor, *, omega0: Tensor, inertia, max_step: float) -> Tensor:
    """Increments ``δ_0 … δ_{T−1}`` ``(T, 4)`` between the sample times ``t (T+1,)`` (s) for the torque-free motion
    that has body rate ``omega0 (3,)`` (rad/s) at ``t_0`` (inertia ``(3,)`` or ``(3, 3)``, kg m²); sub-steps of at
    most ``max_step`` s (module docstring). Not unit quaternions; the filter normalises them."""
    if not math.isfinite(max_step) or max_step <= 0:
        raise ValueError(f"max_step must be > 0 s, got {max_step}")
    count, h = sub_steps(t, max_step)
    if bool((count == 1).all()) and bool((h == max_step).all()):
        return quaternion_increments(omega0, inertia, max_step, t.numel() - 1)  # the scenario's own increments
    out, w = [], omega0
    one = identity_quat(dtype=omega0.dtype, device=omega0.device)
    for first, end, step, n_sub in _runs(count, h):
        n = (end - first) * n_sub
        sub = quaternion_increments(w, inertia, step, n).reshape(end - first, n_sub, 4)
        w = propagate(one, w, inertia, step, n)[1][-1]
        delta = sub[:, 0]
        for j in range(1, n_sub):
            delta = quat_mul(sub[:, j], delta)
        out.append(delta)
    return torch.cat(out)
