"""Truth trajectories and synthetic noisy light curves (paper section 4), batched over noise seeds.

The truth starts at ``scenario.q0`` with rate ``scenario.omega0_deg_s`` and is propagated by RK4 every ``dt_s``
for ``duration_s``; samples ``k = 0 … T`` lie at ``t_k = k dt``. Its light curve is rendered with
``scenario.rho_true``; observation ``k`` of seed ``s`` adds ``N(0, noise_var)`` noise drawn from a generator seeded
with ``s`` alone, so a seed's curve does not depend on which other seeds run beside it.
The filter's initial estimate is ``q_est,0 = q(Euler error) ⊗ q_true,0`` (docs/design.md) and its initial rate
``ω_est,0 = ω_0 + scenario.initial_omega_error_deg_s``; filters that take ω as known propagate with that rate.

Along a pass (``geometry.kind: orbit``) the truth is still integrated every ``dt_s``, but it is sampled at the
pass's times (:func:`~lightcurve_gp.passes.geometry.sample_times`: gaps and explicit timestamps lie on that grid) and
rendered with each sample's geometry; the increment of a longer step is the product of the ``dt_s`` increments it
spans. A sample below the minimum elevation, in the Earth's shadow or with zero flux has no observation (NaN in
``observations`` and ``m_clean``) and is counted in ``Scenario.unobservable``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

from lightcurve_gp.attitude.dynamics import propagate, quaternion_increments
from lightcurve_gp.attitude.rotations import euler321_to_quat, quat_mul, quat_normalize
from lightcurve_gp.config.load import Config
from lightcurve_gp.passes.geometry import PassGeometry, pass_geometry
from lightcurve_gp.photometry.render import Scene

__all__ = ["Scenario", "simulate_scenario", "noisy_observations", "span_increments"]


@dataclass
class Scenario:
    """One truth trajectory and its noisy light curves for ``S`` seeds.

    Attributes:
        times: sample times ``(T+1,)`` (s).
        q_true: true attitudes ``(T+1, 4)``.
        omega_true: true body rates ``(T+1, 3)`` (rad/s), known to the filter.
        increments: RK4 kinematic increments ``(T, 4)`` of the truth: ``q_{k+1} = normalise(δ_k ⊗ q_k)``.
        m_clean: noise-free magnitudes ``(T+1,)`` (mag) rendered with ``rho_true``.
        observations: noisy magnitudes ``(S, T+1)`` (mag).
        seeds: the noise seeds, length ``S``.
        q_est0: the filters' initial estimate ``(4,)``.
        rho_true: the object's diffuse reflectance.
        noise_var: variance of the magnitude noise (mag²).
        geometry: the per-sample geometry of a pass (``None`` for ``geometry.kind: fixed``).
        unobservable: samples with no observation (below the horizon limit, in shadow or with zero flux).
        omega_est0: the filters' initial body rate ``(3,)`` (rad/s): the truth's plus the configured error.
        omega_assumed: the rate history ``(T+1, 3)`` (rad/s) that starts at ``omega_est0`` (the truth's when the
            error is zero): what a filter that takes ω as known believes.
        increments_assumed: the increments ``(T, 4)`` of that rate history (``increments`` when the error is zero).
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
    omega_est0: Tensor
    omega_assumed: Tensor
    increments_assumed: Tensor
    geometry: PassGeometry | None = None
    unobservable: int = 0


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
    if cfg.geometry.kind == "orbit":
        return _simulate_pass(cfg, seeds, rho, scene)
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
    omega_est0 = omega0 + torch.deg2rad(tensor(sc.initial_omega_error_deg_s))
    omega_assumed, increments_assumed = omega_true, increments
    if any(sc.initial_omega_error_deg_s):
        omega_assumed = propagate(q0, omega_est0, inertia, sc.dt_s, n_steps)[1]
        increments_assumed = quaternion_increments(omega_est0, inertia, sc.dt_s, n_steps)
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
        omega_est0=omega_est0,
        omega_assumed=omega_assumed,
        increments_assumed=increments_assumed,
    )


def _simulate_pass(cfg: Config, seeds: list[int], rho: float, scene: Scene | None) -> Scenario:
    """:func:`simulate_scenario` along a pass: the truth on the ``dt_s`` grid, sampled and rendered at the pass."""
    sc = cfg.scenario
    dtype, device = cfg.torch_dtype, torch.device(cfg.device)
    geometry = pass_geometry(cfg)
    if scene is None:
        scene = Scene.from_config(cfg, rho=rho).with_geometry(geometry.sun, geometry.observer, geometry.range_m)
    scene = scene.to(device=device, dtype=dtype)
    if not scene.per_sample or scene.sun.shape[0] != len(geometry):
        raise ValueError(f"scene: a pass of {len(geometry)} samples needs a per-sample scene of as many samples")
    tensor = lambda values: torch.tensor(values, dtype=dtype, device=device)  # noqa: E731
    if any(sc.initial_omega_error_deg_s):
        raise ValueError("scenario.initial_omega_error_deg_s: not supported along a pass (geometry.kind: orbit) yet")
    index = torch.round(geometry.times_s / sc.dt_s).long()
    q0 = quat_normalize(tensor(sc.q0))
    omega0 = torch.deg2rad(tensor(sc.omega0_deg_s))
    inertia = tensor(cfg.shape.inertia_kg_m2)
    q_grid, omega_grid = propagate(q0, omega0, inertia, sc.dt_s, int(index[-1]))
    increments = span_increments(quaternion_increments(omega0, inertia, sc.dt_s, int(index[-1])), index)
    q_true = q_grid[index]
    m_clean = scene.magnitude(q_true, rho=tensor(rho))
    seen = geometry.observable.to(device) & torch.isfinite(m_clean)
    m_clean = torch.where(seen, m_clean, torch.full_like(m_clean, math.nan))
    error = euler321_to_quat(torch.deg2rad(tensor(sc.initial_error_deg)))
    return Scenario(times=(geometry.times_s - geometry.times_s[0]).to(device=device, dtype=dtype), q_true=q_true,
                    omega_true=omega_grid[index], increments=increments, m_clean=m_clean,
                    observations=noisy_observations(m_clean, sc.noise_var, seeds), seeds=seeds,
                    q_est0=quat_mul(error, q0), rho_true=rho, noise_var=sc.noise_var, omega_est0=omega0,
                    omega_assumed=omega_grid[index], increments_assumed=increments, geometry=geometry,
                    unobservable=int((~seen).sum()))


def span_increments(grid_increments: Tensor, index: Tensor) -> Tensor:
    """Increments ``(T−1, 4)`` between grid samples ``index (T,)`` (increasing) from the per-grid-step increments
    ``(n, 4)``: ``δ_{i→j} = δ_{j−1} ⊗ … ⊗ δ_i`` (not normalised: ``normalise(δ ⊗ q)`` is the same either way)."""
    out = grid_increments[index[:-1]].clone()
    for j in torch.nonzero(index[1:] - index[:-1] > 1).flatten().tolist():
        delta = out[j]
        for k in range(int(index[j]) + 1, int(index[j + 1])):
            delta = quat_mul(grid_increments[k], delta)
        out[j] = delta
    return out
