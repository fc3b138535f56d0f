"""Random truths of the generalisation suite: one attitude, spin, surface and initial error per seed.

Each seed ``s`` draws its truth from its own generator, seeded with ``TRUTH_STREAM + s`` (the light-curve noise of
the seed uses the generator seeded with ``s``, :func:`lightcurve_gp.simulation.scenario.noisy_observations`), always
in the same
order, so a seed's truth is reproducible and does not depend on the other seeds drawn beside it:

* initial attitude ``q_0`` uniform on SO(3) (a normalised 4-d standard normal);
* spin ``ω_0``: uniform direction, ``|ω_0|`` log-uniform in ``TruthRanges.omega_deg_s`` (0.05–1.5 °/s);
* surface ``ρ ~ U[0.1, 0.9]``, ``F0 ~ U[0.05, 0.95]``, ``n_u``, ``n_v`` independently log-uniform in ``[10, 10⁴]``;
* initial error. Rule: a typical angle ``θ_typ ~ U[5°, 20°]`` is drawn, ``σ0 = θ_typ / √3`` and the error is the
  rotation vector ``e = σ0 z``, ``z ~ N(0, I₃)``; the filters get ``P0 = σ0² I`` exactly, so the error is a draw from
  the filters' own prior and ``θ_typ = √E|e|²`` is its RMS angle (the median angle is 0.89 θ_typ). In the
  fixed-angle mode (``error_deg=θ``) the same ``z`` gives the axis only: ``e = θ z/|z|``, ``P0 = (θ/√3)² I`` (again
  ``E|e|² = θ²``), so every seed keeps its attitude, spin and surface across the angles.

The estimate starts at ``q_est,0 = q(e) ⊗ q_0`` (the scenario's convention). :func:`paper_case_draw` gives the
paper's case in the same form (every seed the config's truth, the seeds differing by noise alone). A draw becomes a
:class:`~lightcurve_gp.simulation.scenario.Scenario` through
:func:`~lightcurve_gp.simulation.scenario.simulate_truths`: the geometry, the time grid, the inertia and the noise
variance are those of the config (the paper's: fixed Sun and observer, 600 s at 1 Hz, variance 0.5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import euler321_to_quat, quat_mul, quat_normalize, quat_to_rotvec, rotvec_to_quat
from lightcurve_gp.config.load import Config
from lightcurve_gp.observation.surface_state import SURFACE_RANGES
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene

__all__ = ["TRUTH_STREAM", "SPECULAR_CLASSES", "TruthRanges", "TruthDraw", "draw_truths", "paper_case_draw",
           "truth_material", "truth_is_model_surface", "specular_share", "specular_class"]

#: offset of the truth generators' seeds from the noise seeds
TRUTH_STREAM = 1 << 40
#: surface classes by the specular share of the flux along the truth: (label, lower bound, upper bound)
SPECULAR_CLASSES = (("<1 %", 0.0, 0.01), ("1-30 %", 0.01, 0.30), (">30 %", 0.30, 1.0))


@dataclass(frozen=True)
class TruthRanges:
    """Ranges of the random truths (see the module docstring); the surfaces' are those the surface-state prior
    expects (:data:`~lightcurve_gp.observation.surface_state.SURFACE_RANGES`)."""

    omega_deg_s: tuple[float, float] = (0.05, 1.5)
    rho: tuple[float, float] = SURFACE_RANGES.rho
    f0: tuple[float, float] = SURFACE_RANGES.f0
    lobe_exponent: tuple[float, float] = SURFACE_RANGES.lobe_exponent
    typical_error_deg: tuple[float, float] = (5.0, 20.0)


@dataclass
class TruthDraw:
    """The random parameters of ``S`` seeds (float64, CPU).

    Attributes:
        seeds: the seeds, length ``S``.
        q0: true initial attitudes ``(S, 4)``.
        omega0: true initial body rates ``(S, 3)`` (rad/s).
        surface: true surfaces, fields ``(S,)``.
        error: initial attitude errors, rotation vectors ``(S, 3)`` (rad): ``q_est,0 = q(error) ⊗ q0``.
        sigma0: initial standard deviation per axis ``(S,)`` (rad): ``P0 = σ0² I``.
    """

    seeds: list[int]
    q0: Tensor
    omega0: Tensor
    surface: Surface
    error: Tensor
    sigma0: Tensor

    @property
    def q_est0(self) -> Tensor:
        """Initial estimates ``q(error) ⊗ q0`` ``(S, 4)``."""
        return quat_mul(rotvec_to_quat(self.error), self.q0)


def _log_uniform(u: Tensor, bounds: tuple[float, float]) -> Tensor:
    lo, hi = math.log(bounds[0]), math.log(bounds[1])
    return torch.exp(lo + (hi - lo) * u)


def _uniform(u: Tensor, bounds: tuple[float, float]) -> Tensor:
    return bounds[0] + (bounds[1] - bounds[0]) * u


def _draw_one(seed: int, ranges: TruthRanges) -> tuple[Tensor, Tensor]:
    """Ten standard normals and six uniforms of one seed, in the fixed order of the module docstring."""
    gen = torch.Generator().manual_seed(TRUTH_STREAM + int(seed))
    normals = torch.randn(10, generator=gen, dtype=torch.float64)
    uniforms = torch.rand(6, generator=gen, dtype=torch.float64)
    return normals, uniforms


def draw_truths(seeds: Sequence[int], *, ranges: TruthRanges = TruthRanges(),
                error_deg: float | None = None) -> TruthDraw:
    """Draw the truth of every seed (see the module docstring); ``error_deg`` selects the fixed-angle mode."""
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds must name at least one seed")
    if error_deg is not None and not 0.0 < float(error_deg) < 180.0:
        raise ValueError(f"error_deg: {error_deg!r} must lie in (0, 180) deg")
    normals, uniforms = (torch.stack(t) for t in zip(*(_draw_one(s, ranges) for s in seeds)))
    q0 = normals[:, 0:4] / torch.linalg.vector_norm(normals[:, 0:4], dim=-1, keepdim=True)
    spin_axis = normals[:, 4:7] / torch.linalg.vector_norm(normals[:, 4:7], dim=-1, keepdim=True)
    omega0 = spin_axis * torch.deg2rad(_log_uniform(uniforms[:, 0], ranges.omega_deg_s)).unsqueeze(-1)
    surface = Surface(rho=_uniform(uniforms[:, 1], ranges.rho), f0=_uniform(uniforms[:, 2], ranges.f0),
                      n_u=_log_uniform(uniforms[:, 3], ranges.lobe_exponent),
                      n_v=_log_uniform(uniforms[:, 4], ranges.lobe_exponent))
    z = normals[:, 7:10]
    if error_deg is None:
        sigma0 = torch.deg2rad(_uniform(uniforms[:, 5], ranges.typical_error_deg)) / math.sqrt(3.0)
        error = sigma0.unsqueeze(-1) * z
    else:
        theta = math.radians(float(error_deg))
        sigma0 = torch.full((len(seeds),), theta / math.sqrt(3.0), dtype=torch.float64)
        error = theta * z / torch.linalg.vector_norm(z, dim=-1, keepdim=True)
    return TruthDraw(seeds, q0, omega0, surface, error, sigma0)


def truth_material(cfg: Config, rho: float | None = None) -> tuple[float, float, float, float]:
    """``(ρ, F0, n_u, n_v)`` of the config's truth: ``rho`` when given, else ``scenario.surface.rho`` or
    ``scenario.rho_true``; F0, n_u, n_v from ``scenario.surface`` where set, else the model's ``surface`` section."""
    own = cfg.scenario.surface
    rho = (cfg.scenario.rho_true if own.rho is None else own.rho) if rho is None else rho
    return (float(rho), *(float(getattr(cfg.surface, k) if getattr(own, k) is None else getattr(own, k))
                          for k in ("f0", "n_u", "n_v")))


def truth_is_model_surface(cfg: Config) -> bool:
    """Whether the config's truth has the material the models assume (its F0, n_u, n_v those of ``surface``)."""
    return truth_material(cfg, 1.0)[1:] == tuple(float(getattr(cfg.surface, k)) for k in ("f0", "n_u", "n_v"))


def paper_case_draw(cfg: Config, seeds: Sequence[int], *, rho: float) -> TruthDraw:
    """The scenario of ``cfg`` for every seed: attitude ``scenario.q0``, spin ``scenario.omega0_deg_s``, the truth's
    material (:func:`truth_material`) with reflectance ``rho``, the initial error ``scenario.initial_error_deg``
    (yaw, pitch, roll) and ``σ0 = filter.p0_deg``. With the noise seeded per seed as in
    :func:`lightcurve_gp.simulation.scenario.simulate_scenario`, seed ``s`` is that command's seed ``s`` (the paper's
    case with ``cfg = configs/boxwing*.yaml``)."""
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds must name at least one seed")
    if not 0.0 < float(rho) <= 1.0:
        raise ValueError(f"rho: {rho!r} must lie in (0, 1]")
    sc, S = cfg.scenario, len(seeds)
    full = lambda values: torch.tensor(values, dtype=torch.float64).expand(S, -1).clone()  # noqa: E731
    material = truth_material(cfg, float(rho))
    error = quat_to_rotvec(euler321_to_quat(torch.deg2rad(torch.tensor(sc.initial_error_deg, dtype=torch.float64))))
    return TruthDraw(seeds, quat_normalize(full(sc.q0)), torch.deg2rad(full(sc.omega0_deg_s)),
                     Surface(*(torch.full((S,), v, dtype=torch.float64) for v in material)), error.expand(S, 3).clone(),
                     torch.full((S,), math.radians(cfg.filter.p0_deg), dtype=torch.float64))


def specular_share(scene: Scene, q: Tensor, surface: Surface) -> Tensor:
    """Time mean of specular / total flux along trajectories ``q (S, T+1, 4)`` with surfaces ``(S,)`` → ``(S,)``."""
    diffuse, specular = scene.flux_parts(q, surface=surface)
    return (specular / (diffuse + specular)).mean(-1)


def specular_class(share: Tensor) -> Tensor:
    """Index into :data:`SPECULAR_CLASSES` of specular shares ``(...)``: ``< 0.01``, ``[0.01, 0.30]``, ``> 0.30``."""
    return (share >= SPECULAR_CLASSES[1][1]).long() + (share > SPECULAR_CLASSES[2][1]).long()
