"""Truth trajectories and synthetic noisy light curves (paper section 4), batched over noise seeds.

The truth starts at ``scenario.q0`` with rate ``scenario.omega0_deg_s`` and is propagated by RK4 every ``dt_s``
for ``duration_s``; samples ``k = 0 … T`` lie at ``t_k = k dt``. Its light curve is rendered with
``scenario.rho_true``; observation ``k`` of seed ``s`` adds ``N(0, noise_var)`` noise drawn from a generator seeded
with ``s`` alone, so a seed's curve does not depend on which other seeds run beside it.
The filter's initial estimate is ``q_est,0 = q(Euler error) ⊗ q_true,0`` (docs/design.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

from .config import Config
from .dynamics import propagate, quaternion_increments
from .render import Scene
from .rotations import euler321_to_quat, quat_mul, quat_normalize

__all__ = ["Scenario", "simulate_scenario", "noisy_observations"]


@dataclass
class Scenario:
    """One truth trajectory and its noisy light curves for ``S`` seeds.

    Attributes:
        times: sample times ``(T+1,)`` (s).
        q_true: true attitudes ``(T+1, 4)``.
        omega_true: true body rates ``(T+1, 3)`` (rad/s), known to the filter.
        increments: RK4 kinematic increments ``(T, 4)``: ``q_{k+1} = normalise(δ_k ⊗ q_k)``.
        m_clean: noise-free magnitudes ``(T+1,)`` (mag) rendered with ``rho_true``.
        observations: noisy magnitudes ``(S, T+1)`` (mag).
        seeds: the noise seeds, length ``S``.
        q_est0: the filters' initial estimate ``(4,)``.
        rho_true: the object's diffuse reflectance.
        noise_var: variance of the magnitude noise (mag²).
    """

    times: Tensor
    q_true: Tensor
    omega_true: Tensor
    increments: Tensor
    m_clean: Tensor
    observations: Tensor
    seeds: list[int]
    q_est0: Tensor
    rho_true: float
    noise_var: float


def noisy_observations(m_clean: Tensor, noise_var: float, seeds: Sequence[int]) -> Tensor:
    """Add ``N(0, noise_var)`` noise to ``m_clean (T+1,)``, one independent generator per seed → ``(S, T+1)``."""
    std = math.sqrt(noise_var)
    rows = []
    for seed in seeds:
        gen = torch.Generator().manual_seed(int(seed))
        noise = torch.randn(m_clean.shape, generator=gen, dtype=torch.float64)
        rows.append(m_clean + std * noise.to(device=m_clean.device, dtype=m_clean.dtype))
    return torch.stack(rows)


def simulate_scenario(cfg: Config, seeds: Sequence[int] | None = None, rho_true: float | None = None,
                      scene: Scene | None = None) -> Scenario:
    """Truth trajectory, clean and noisy light curves and the initial estimate of ``cfg.scenario``.

    Args:
        cfg: validated config (``scenario``, ``shape``, ``surface``, ``geometry`` sections are used).
        seeds: noise seeds; default ``range(cfg.scenario.seeds)``.
        rho_true: overrides ``cfg.scenario.rho_true``.
        scene: renderer to use; default ``Scene.from_config(cfg)``.
    """
    sc = cfg.scenario
    dtype, device = cfg.torch_dtype, torch.device(cfg.device)
    seeds = list(range(sc.seeds)) if seeds is None else [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds must name at least one noise seed")
    rho = sc.rho_true if rho_true is None else float(rho_true)
    if not 0.0 <= rho <= 1.0:
        raise ValueError(f"rho_true: {rho:g} is outside [0, 1]")
    steps = sc.duration_s / sc.dt_s
    if abs(steps - round(steps)) > 1e-9:
        raise ValueError(f"scenario.duration_s ({sc.duration_s:g}) must be a multiple of scenario.dt_s ({sc.dt_s:g})")
    n_steps = int(round(steps))
    scene = (scene or Scene.from_config(cfg, rho=rho)).to(device=device, dtype=dtype)

    tensor = lambda values: torch.tensor(values, dtype=dtype, device=device)  # noqa: E731
    q0 = quat_normalize(tensor(sc.q0))
    omega0 = torch.deg2rad(tensor(sc.omega0_deg_s))
    inertia = tensor(cfg.shape.inertia_kg_m2)
    q_true, omega_true = propagate(q0, omega0, inertia, sc.dt_s, n_steps)
    increments = quaternion_increments(omega0, inertia, sc.dt_s, n_steps)
    m_clean = scene.magnitude(q_true, rho=tensor(rho))
    if not bool(torch.isfinite(m_clean).all()):
        bad = int((~torch.isfinite(m_clean)).sum())
        raise ValueError(f"the true trajectory has {bad} samples with zero flux (object not lit and visible)")
    error = euler321_to_quat(torch.deg2rad(tensor(sc.initial_error_deg)))
    return Scenario(
        times=torch.arange(n_steps + 1, dtype=dtype, device=device) * sc.dt_s,
        q_true=q_true,
        omega_true=omega_true,
        increments=increments,
        m_clean=m_clean,
        observations=noisy_observations(m_clean, sc.noise_var, seeds),
        seeds=seeds,
        q_est0=quat_mul(error, q0),
        rho_true=rho,
        noise_var=sc.noise_var,
    )
