"""Truth trajectories and synthetic noisy light curves (paper section 4): ``S`` truths, one per seed.

A :class:`Scenario` holds ``S`` truths, each field with the seed dimension first, and their noisy light curves. Two
builders fill it:

* :func:`simulate_scenario` — the config's truth (the paper's case): every seed starts at ``scenario.q0`` with rate
  ``scenario.omega0_deg_s`` and the truth's material (``scenario.surface``, by default the model's ``surface``
  section at ``scenario.rho_true``), the seeds differing by noise alone;
* :func:`simulate_truths` — one random truth per seed (:func:`lightcurve_gp.simulation.truths.draw_truths`: attitude,
  spin, surface, initial error and ``σ0``), under the config's fixed geometry.

The truth is propagated by RK4 every ``dt_s`` for ``duration_s``; samples ``k = 0 … T`` lie at ``t_k = k dt``.
Observation ``k`` of seed ``s`` adds ``N(0, noise_var)`` noise drawn from a generator seeded with ``s`` alone, so a
seed's curve does not depend on which other seeds run beside it. For the config's truth the filters' initial estimate
is ``q_est,0 = q(Euler error) ⊗ q_true,0`` (docs/design.md) with ``σ0 = filter.p0_deg``, and the initial rate
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
from lightcurve_gp.attitude.rotations import euler321_to_quat, quat_mul, quat_normalize, quat_to_rotvec
from lightcurve_gp.config.load import Config
from lightcurve_gp.observations.observations import CurveInfo, Observations
from lightcurve_gp.observations.problem import Problem
from lightcurve_gp.passes.geometry import PassGeometry, pass_geometry
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.truths import TruthDraw, specular_share, truth_is_model_surface, truth_material

__all__ = ["Scenario", "simulate_scenario", "simulate_truths", "noisy_observations", "span_increments"]


@dataclass
class Scenario:
    """``S`` truths (one per seed) and their noisy light curves; every truth field leads with the seed dimension.

    Attributes:
        times: sample times ``(T+1,)`` (s), shared by the seeds.
        seeds: the seeds, length ``S``.
        q_true: true attitudes ``(S, T+1, 4)``.
        omega_true: true body rates ``(S, T+1, 3)`` (rad/s).
        increments: RK4 kinematic increments of the truths ``(S, T, 4)``: ``q_{k+1} = normalise(δ_k ⊗ q_k)``.
        m_clean: noise-free magnitudes ``(S, T+1)`` (mag), each seed rendered with its own surface.
        observations: noisy magnitudes ``(S, T+1)`` (mag).
        surface: the true surfaces, fields ``(S,)``.
        q_est0: the filters' initial estimates ``(S, 4)``: ``q(error) ⊗ q_true,0``.
        error: the initial attitude errors as rotation vectors ``(S, 3)`` (rad).
        sigma0: the filters' initial attitude standard deviation per axis ``(S,)`` (rad): ``P0 = σ0² I``.
        omega_est0: the filters' initial body rates ``(S, 3)`` (rad/s): the truth's plus the configured error.
        omega_assumed: the rate histories ``(S, T+1, 3)`` (rad/s) that start at ``omega_est0`` (the truth's when the
            error is zero): what a filter that takes ω as known believes.
        increments_assumed: the increments ``(S, T, 4)`` of those rate histories (``increments`` when the error is
            zero).
        noise_var: variance of the magnitude noise (mag²).
        rho_true: the one diffuse reflectance every seed shares when the truth is the config's (its surface at that
            ρ); ``None`` for drawn truths, whose surfaces are ``surface``.
        specular_share: time mean of specular / total flux along each truth ``(S,)`` (drawn truths; else ``None``).
        geometry: the per-sample geometry of a pass (``None`` for ``geometry.kind: fixed``).
        unobservable: samples of one truth with no observation (below the horizon limit, in shadow or with zero
            flux).
    """

    times: Tensor
    seeds: list[int]
    q_true: Tensor
    omega_true: Tensor
    increments: Tensor
    m_clean: Tensor
    observations: Tensor
    surface: Surface
    q_est0: Tensor
    error: Tensor
    sigma0: Tensor
    omega_est0: Tensor
    omega_assumed: Tensor
    increments_assumed: Tensor
    noise_var: float
    rho_true: float | None = None
    specular_share: Tensor | None = None
    geometry: PassGeometry | None = None
    unobservable: int = 0

    @property
    def steps(self) -> int:
        """The number of filter steps ``T``."""
        return self.increments.shape[1]

    def problem(self, *, oracle: bool = True) -> Problem:
        """What the estimators are given (:class:`~lightcurve_gp.observations.problem.Problem`): the noisy light
        curves with the true noise's 1σ, the filters' priors, the assumed rate and its increments; ``R`` left to the
        config's ``filter.measurement_noise`` (what the filters are tuned with). ``oracle``: the true surface goes
        with it for the oracle estimators (``matched_ukf``, ``matched_map``)."""
        sigma = torch.full_like(self.observations, math.sqrt(self.noise_var))
        obs = Observations(t=self.times.to(torch.float64), mag=self.observations, sigma=sigma,
                           curve=torch.zeros(self.times.shape[0], dtype=torch.int64, device=self.times.device),
                           curves=(CurveInfo("simulation"),),
                           sun=None if self.geometry is None else self.geometry.sun.to(self.observations),
                           observer=None if self.geometry is None else self.geometry.observer.to(self.observations),
                           range_m=None if self.geometry is None else self.geometry.range_m.to(self.observations),
                           epoch=None if self.geometry is None else self.geometry.start_utc)
        return Problem(obs=obs, q_est0=self.q_est0, sigma0=self.sigma0, omega_est0=self.omega_est0,
                       increments_assumed=self.increments_assumed, R=None,
                       surface=self.surface if oracle else None, rho_true=self.rho_true if oracle else None,
                       geometry=self.geometry)

    @property
    def P0(self) -> Tensor:
        """Initial attitude covariances ``σ0² I`` ``(S, 3, 3)`` (rad²)."""
        eye = torch.eye(3, dtype=self.sigma0.dtype, device=self.sigma0.device)
        return self.sigma0.pow(2).view(-1, 1, 1) * eye


def noisy_observations(m_clean: Tensor, noise_var: float, seeds: Sequence[int]) -> Tensor:
    """Add ``N(0, noise_var)`` noise to ``m_clean (T+1,)`` or ``(S, T+1)`` (one row per seed), one independent
    generator per seed → ``(S, T+1)``."""
    std = math.sqrt(noise_var)
    rows = []
    for i, seed in enumerate(seeds):
        clean = m_clean if m_clean.ndim == 1 else m_clean[i]
        gen = torch.Generator().manual_seed(int(seed))
        noise = torch.randn(clean.shape, generator=gen, dtype=torch.float64)
        rows.append(clean + std * noise.to(device=clean.device, dtype=clean.dtype))
    return torch.stack(rows)


def _check_seeds(cfg: Config, seeds: Sequence[int] | None) -> list[int]:
    seeds = list(range(cfg.scenario.seeds)) if seeds is None else [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds must name at least one noise seed")
    steps = cfg.scenario.duration_s / cfg.scenario.dt_s
    if abs(steps - round(steps)) > 1e-9:
        raise ValueError(f"scenario.duration_s ({cfg.scenario.duration_s:g}) must be a multiple of scenario.dt_s "
                         f"({cfg.scenario.dt_s:g})")
    return seeds


def _config_truth(cfg: Config, S: int, rho: float, like: Tensor) -> dict:
    """The seed-independent fields of the config's truth, each repeated for ``S`` seeds (expanded views)."""
    sc = cfg.scenario
    tensor = lambda values: torch.tensor(values, dtype=like.dtype, device=like.device)  # noqa: E731
    error = euler321_to_quat(torch.deg2rad(tensor(sc.initial_error_deg)))
    return {"surface": Surface(*(tensor(v).expand(S) for v in truth_material(cfg, rho))),
            "error": quat_to_rotvec(error).expand(S, 3),
            "sigma0": torch.tensor(math.radians(cfg.filter.p0_deg), dtype=torch.float64, device=like.device).expand(S),
            "noise_var": sc.noise_var,
            "rho_true": rho, "q_est0": quat_mul(error, quat_normalize(tensor(sc.q0))).expand(S, 4)}


def _per_seed(S: int, **fields: Tensor) -> dict[str, Tensor]:
    """Fields of one truth repeated for ``S`` seeds (expanded views)."""
    return {k: v.expand(S, *v.shape) for k, v in fields.items()}


def _truth_magnitude(cfg: Config, scene: Scene, q_true: Tensor, rho: float) -> Tensor:
    """Noise-free magnitudes ``(T+1,)`` of the config's truth ``q_true (T+1, 4)``: the scene's material at ``rho``,
    or the truth's own material when ``scenario.surface`` gives another (:func:`truth_material`)."""
    if truth_is_model_surface(cfg):
        return scene.magnitude(q_true, rho=torch.tensor(rho, dtype=q_true.dtype, device=q_true.device))
    material = Surface(*(torch.tensor([v], dtype=q_true.dtype, device=q_true.device) for v in truth_material(cfg, rho)))
    return scene.magnitude(q_true.unsqueeze(0), surface=material)[0]


def simulate_scenario(cfg: Config, seeds: Sequence[int] | None = None, rho_true: float | None = None,
                      scene: Scene | None = None) -> Scenario:
    """The config's truth for every seed, its clean and noisy light curves and the initial estimate.

    Args:
        cfg: validated config (``scenario``, ``shape``, ``surface``, ``geometry`` sections, ``filter.p0_deg``).
        seeds: noise seeds; default ``range(cfg.scenario.seeds)``.
        rho_true: overrides the truth's reflectance (``scenario.surface.rho``, else ``scenario.rho_true``).
        scene: renderer to use; default ``Scene.from_config(cfg)``.
    """
    sc = cfg.scenario
    dtype, device = cfg.torch_dtype, torch.device(cfg.device)
    seeds = _check_seeds(cfg, seeds)
    rho = truth_material(cfg, rho_true)[0]
    if not 0.0 <= rho <= 1.0:
        raise ValueError(f"rho_true: {rho:g} is outside [0, 1]")
    if cfg.geometry.kind == "orbit":
        return _simulate_pass(cfg, seeds, rho, scene)
    n_steps = int(round(sc.duration_s / sc.dt_s))
    scene = (scene or Scene.from_config(cfg, rho=rho)).to(device=device, dtype=dtype)

    tensor = lambda values: torch.tensor(values, dtype=dtype, device=device)  # noqa: E731
    q0 = quat_normalize(tensor(sc.q0))
    omega0 = torch.deg2rad(tensor(sc.omega0_deg_s))
    inertia = tensor(cfg.shape.inertia_kg_m2)
    q_true, omega_true = propagate(q0, omega0, inertia, sc.dt_s, n_steps)
    increments = quaternion_increments(omega0, inertia, sc.dt_s, n_steps)
    m_clean = _truth_magnitude(cfg, scene, q_true, rho)
    if not bool(torch.isfinite(m_clean).all()):
        bad = int((~torch.isfinite(m_clean)).sum())
        raise ValueError(f"the true trajectory has {bad} samples with zero flux (object not lit and visible)")
    omega_est0 = omega0 + torch.deg2rad(tensor(sc.initial_omega_error_deg_s))
    omega_assumed, increments_assumed = omega_true, increments
    if any(sc.initial_omega_error_deg_s):
        omega_assumed = propagate(q0, omega_est0, inertia, sc.dt_s, n_steps)[1]
        increments_assumed = quaternion_increments(omega_est0, inertia, sc.dt_s, n_steps)
    S = len(seeds)
    return Scenario(times=torch.arange(n_steps + 1, dtype=dtype, device=device) * sc.dt_s, seeds=seeds,
                    observations=noisy_observations(m_clean, sc.noise_var, seeds), **_config_truth(cfg, S, rho, q0),
                    **_per_seed(S, q_true=q_true, omega_true=omega_true, increments=increments, m_clean=m_clean,
                                omega_est0=omega_est0, omega_assumed=omega_assumed,
                                increments_assumed=increments_assumed))


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
    m_clean = _truth_magnitude(cfg, scene, q_true, rho)
    seen = geometry.observable.to(device) & torch.isfinite(m_clean)
    m_clean = torch.where(seen, m_clean, torch.full_like(m_clean, math.nan))
    S = len(seeds)
    return Scenario(times=(geometry.times_s - geometry.times_s[0]).to(device=device, dtype=dtype), seeds=seeds,
                    observations=noisy_observations(m_clean, sc.noise_var, seeds), **_config_truth(cfg, S, rho, q0),
                    **_per_seed(S, q_true=q_true, omega_true=omega_grid[index], increments=increments,
                                m_clean=m_clean, omega_est0=omega0, omega_assumed=omega_grid[index],
                                increments_assumed=increments),
                    geometry=geometry, unobservable=int((~seen).sum()))


def simulate_truths(cfg: Config, draw: TruthDraw, scene: Scene | None = None) -> Scenario:
    """Trajectories, increments, clean and noisy light curves of the drawn truths under ``cfg``'s fixed geometry
    (float64, CPU); ω is known exactly (``omega_assumed`` is the truth's).

    Raises:
        ValueError: a truth trajectory with zero flux somewhere (names the seed).
    """
    sc = cfg.scenario
    n_steps = int(round(sc.duration_s / sc.dt_s))
    scene = (scene or Scene.from_config(cfg)).to(dtype=torch.float64)
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=torch.float64)
    q_true, omega_true = propagate(draw.q0, draw.omega0, inertia, sc.dt_s, n_steps)
    increments = quaternion_increments(draw.omega0, inertia, sc.dt_s, n_steps)
    m_clean = scene.magnitude(q_true, surface=draw.surface)
    bad = ~torch.isfinite(m_clean).all(-1)
    if bool(bad.any()):
        raise ValueError(f"seed {draw.seeds[int(bad.nonzero()[0])]}: the true trajectory has samples with zero flux")
    return Scenario(times=torch.arange(n_steps + 1, dtype=torch.float64) * sc.dt_s, seeds=list(draw.seeds),
                    q_true=q_true, omega_true=omega_true, increments=increments, m_clean=m_clean,
                    observations=noisy_observations(m_clean, sc.noise_var, draw.seeds), surface=draw.surface,
                    q_est0=draw.q_est0, error=draw.error, sigma0=draw.sigma0, omega_est0=draw.omega0,
                    omega_assumed=omega_true, increments_assumed=increments, noise_var=float(sc.noise_var),
                    specular_share=specular_share(scene, q_true, draw.surface))


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
