"""Training sets rendered over many surfaces: the data of the surface-marginal GP (``model.target:
surface_normalised``, ``data.surfaces``).

The flux of the paper's surface is ``f = ρ (1 − F0) D(q) + S(q; F0, n_u, n_v)`` (paper Eqs. (4), (8)): the diffuse
reflectance and the Fresnel reflectance scale the diffuse part together, the specular lobe depends on F0, n_u, n_v
alone. So for a purely diffuse light curve the magnitude shifts by ``−2.5 log10(ρ (1 − F0) / (ρ0 (1 − F0,0)))``
against the reference surface (``model.rho_reference``, ``surface.f0``), exactly; the specular part is an
attitude-dependent brightening that no offset removes. The training set renders every attitude with
``data.surfaces.per_attitude`` (K) surfaces of its own and stores, as its ``rho``, the *equivalent reflectance*
``ρ (1 − F0) / (1 − F0,0)`` of each point: the reflectance the reference surface would need to have the same diffuse
part, so that :func:`lightcurve_gp.training.sets.normalised_targets` gives the surface-normalised magnitude
``y = m + 2.5 log10(ρ (1 − F0) / (ρ0 (1 − F0,0)))``. Points are surface-major (``N = K · A``, point ``k · A + a`` is
attitude ``a`` with its ``k``-th surface), which the surface-marginal GP relies on
(:func:`lightcurve_gp.observation.surface_marginal.attitude_spread`).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor
from tqdm.auto import tqdm

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.config.schema import Config, TrainingSurfacesConfig
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.training.windows import (
    TrainingSet,
    initial_attitudes,
    shape_inertia,
    training_rates,
    window_steps,
)

__all__ = ["draw_surfaces", "equivalent_reflectance", "render_over_surfaces", "generate_surface_training_set",
           "generate_surface_heldout_set"]


def draw_surfaces(spec: TrainingSurfacesConfig, shape: tuple[int, ...], *, seed: int,
                  dtype: torch.dtype = torch.float64) -> Surface:
    """Surfaces with every field of ``shape``: ρ, F0 uniform in their ranges, n_u, n_v independently log-uniform."""
    gen = torch.Generator().manual_seed(seed)

    def uniform(lo: float, hi: float) -> Tensor:
        return lo + (hi - lo) * torch.rand(shape, generator=gen, dtype=dtype)

    log_n = [math.log(v) for v in spec.n]
    return Surface(rho=uniform(*spec.rho), f0=uniform(*spec.f0), n_u=uniform(*log_n).exp(),
                   n_v=uniform(*log_n).exp())


def equivalent_reflectance(surface: Surface, f0_reference: float) -> Tensor:
    """``ρ (1 − F0) / (1 − F0,0)`` ``(...)``: the ρ of the reference surface with the same diffuse flux."""
    return surface.rho * (1.0 - surface.f0) / (1.0 - f0_reference)


def render_over_surfaces(scene: Scene, q0: Tensor, surfaces: Surface, cfg: Config, *,
                         progress: bool | None = False) -> TrainingSet:
    """Windows (see :mod:`lightcurve_gp.training.windows`) of attitudes ``q0 (A, 4)``, each rendered with its surfaces
    ``surfaces`` (fields ``(K, A)``); surface-major points, ``rho`` the equivalent reflectance. An attitude with a
    zero-flux sample is dropped for all its surfaces (zero flux is geometry: nothing lit and visible)."""
    n_steps = window_steps(cfg.data)
    omega0 = training_rates(cfg.data, q0.shape[0], dtype=q0.dtype)
    q_hist, _ = propagate(q0, omega0, shape_inertia(cfg).to(q0.dtype), cfg.data.dt_s, n_steps)  # (A, n+1, 4)
    k_count = surfaces.rho.shape[0]
    m = torch.stack([scene.magnitude(q_hist, surface=surfaces.index(k))
                     for k in tqdm(range(k_count), desc="rendering over surfaces",
                                  disable=None if progress is None else not progress)])
    ok = torch.isfinite(m).all(-1).all(0)  # (A,)
    a_ok = int(ok.sum())
    return TrainingSet(q=q_hist[ok, -1].repeat(k_count, 1), m_past=m[:, ok, :-1].mean(-1).reshape(-1),
                       y=m[:, ok, -1].reshape(-1),
                       rho=equivalent_reflectance(surfaces, cfg.surface.f0)[:, ok].reshape(-1).to(q0.dtype),
                       dropped=k_count * (q0.shape[0] - a_ok))


def generate_surface_training_set(cfg: Config, progress: bool | None = None) -> TrainingSet:
    """The training set of ``cfg`` with ``data.surfaces``: ``data.sampling`` attitudes × K surfaces each."""
    dtype = cfg.torch_dtype
    q0 = initial_attitudes(cfg.data, dtype=dtype)
    spec = cfg.data.surfaces
    surfaces = draw_surfaces(spec, (spec.per_attitude, q0.shape[0]), seed=spec.seed, dtype=dtype)
    return render_over_surfaces(Scene.from_config(cfg, dtype=dtype, device="cpu"), q0, surfaces, cfg,
                                progress=progress)


def generate_surface_heldout_set(cfg: Config) -> TrainingSet:
    """``data.heldout_size`` random attitudes (seed ``data.seed + 1``), one surface each (seed
    ``data.surfaces.seed + 1``): independent of the training set."""
    dtype = cfg.torch_dtype
    n = cfg.data.heldout_size
    q0 = random_attitudes(n, seed=cfg.data.seed + 1, dtype=dtype)
    surfaces = draw_surfaces(cfg.data.surfaces, (1, n), seed=cfg.data.surfaces.seed + 1, dtype=dtype)
    return render_over_surfaces(Scene.from_config(cfg, dtype=dtype, device="cpu"), q0, surfaces, cfg)
