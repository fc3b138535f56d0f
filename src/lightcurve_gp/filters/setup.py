"""From a config to a running filter: ``P0``, ``b0``, ``θ0``, ``m_past,0`` and :class:`UsqueParams`, in one place.

Every filter of the project starts the same way (docs/design.md):

* ``P0``: ``σ0² I₃`` on the attitude, ``σ0`` per filter (a scenario's, matched to its initial error) or
  ``filter.p0_deg`` for all; ``(filter.p0_omega_deg_s)² I₃`` on ω (rad²/s²) when ω is estimated;
  ``filter.offset_prior_std²`` on the offset ``b``; the surface state's prior variances on ``θ``
  (:func:`~lightcurve_gp.observation.surface_state.surface_state_prior`);
* ``m_past,0``: each light curve's first finite observation (``ỹ_0`` unless the first samples are missing);
* ``b0 = ỹ_0 − h(q̂_0)`` (:func:`~lightcurve_gp.filters.offset.initial_offset`, ``h`` the model of sample 0);
* :class:`UsqueParams` from the ``filter`` section; ``R`` is ``filter.measurement_noise`` (or a given per-filter or
  per-sample ``R``; ``filter.surface_measurement_noise`` for the surface-state filter when set) plus what
  ``filter.model_error`` adds for the trained model (:func:`~lightcurve_gp.filters.usque.model_error_variance`);
* along a pass every step predicts with its own sample's geometry
  (:func:`~lightcurve_gp.observation.along_pass.pass_models`); under a fixed geometry a model that takes geometry
  is bound to the scene's once.
"""

from __future__ import annotations

import dataclasses
import math

import torch
from torch import Tensor

from lightcurve_gp.config.load import Config
from lightcurve_gp.filters.offset import initial_offset
from lightcurve_gp.filters.state import FilterHistory, StateLayout
from lightcurve_gp.filters.usque import UsqueParams, model_error_variance, run_usque
from lightcurve_gp.observation.along_pass import bind_geometry, pass_models
from lightcurve_gp.observation.base import ObservationModel, Variance
from lightcurve_gp.observation.parametric import SurfaceStateRenderer
from lightcurve_gp.observation.surface_state import reference_surface, surface_state_prior
from lightcurve_gp.photometry.render import Scene

__all__ = ["first_observation", "prior_covariance", "filter_params", "step_models", "run_filter",
           "run_surface_filter"]


def first_observation(observations: Tensor) -> Tensor:
    """Each row's first finite observation ``(B,)`` of ``observations (B, T+1)`` (0 for a row without one): the
    filters' ``m_past,0``. With the fixed geometry this is ``ỹ_0``; along a pass the first samples may be
    unobservable (NaN)."""
    finite = torch.isfinite(observations)
    first = finite.double().argmax(-1, keepdim=True)
    value = torch.gather(observations, -1, first).squeeze(-1)
    return torch.where(finite.any(-1), value, torch.zeros_like(value))


def prior_covariance(cfg: Config, *, sigma0: Tensor | None = None, offset: bool = False, omega: bool | None = None,
                     parameter_std: Tensor | None = None, dtype: torch.dtype | None = None,
                     device=None) -> Tensor:
    """The filters' ``P0`` of the state ``[δp, ω?, b?, θ?]`` (module docstring): ``(n, n)`` with
    ``σ0 = filter.p0_deg`` when ``sigma0`` is ``None``, else ``(S, n, n)`` with ``sigma0 (S,)`` (rad).

    Args:
        offset: the offset ``b`` in the state. omega: ω in the state (default ``filter.estimate_omega``).
        parameter_std: prior standard deviations ``(p,)`` of ``p`` model parameters in the state, or ``None``.
    """
    omega = cfg.filter.estimate_omega if omega is None else omega
    layout = StateLayout(offset=offset, omega=omega, parameters=0 if parameter_std is None else parameter_std.numel())
    dtype = dtype or torch.get_default_dtype()
    eye = torch.eye(3, dtype=dtype, device=device)
    if sigma0 is None:
        batch, attitude = (), math.radians(cfg.filter.p0_deg) ** 2 * eye
    else:
        batch, attitude = sigma0.shape, sigma0.to(device=device).pow(2).view(-1, 1, 1) * eye
    P0 = torch.zeros(*batch, layout.dim, layout.dim, dtype=dtype, device=device)
    P0[..., :3, :3] = attitude
    if layout.omega:
        P0[..., 3:6, 3:6] = math.radians(cfg.filter.p0_omega_deg_s) ** 2 * eye
    if layout.offset:
        P0[..., layout.offset_index, layout.offset_index] = cfg.filter.offset_prior_std ** 2
    if parameter_std is not None:
        block = layout.parameter_slice
        P0[..., block, block] = torch.diag(parameter_std.pow(2)).to(P0)
    return P0


def filter_params(cfg: Config, model: ObservationModel | None = None, *, R: Tensor | float | None = None,
                  variance: Variance | None = None, surface: bool = False) -> UsqueParams:
    """``cfg``'s USQUE settings for the trained ``model`` (its ``filter.model_error`` is added to ``R``; pass the
    model itself, not a wrapper along a pass): ``R`` (scalar, ``(B,)`` or ``(B, T+1)``, mag²) replaces
    ``filter.measurement_noise`` when given, ``filter.surface_measurement_noise`` does for the surface-state filter
    (``surface``) when set; ``variance`` replaces the model variance the filter asks for."""
    params = UsqueParams.from_config(cfg, model=model)
    noise = cfg.filter.surface_measurement_noise if surface else None
    if R is not None:
        params = dataclasses.replace(params, R=R + model_error_variance(cfg, model))
    elif noise is not None:
        params = dataclasses.replace(params, R=float(noise) + model_error_variance(cfg, model))
    if variance is not None:
        params = dataclasses.replace(params, variance=variance)
    return params


def step_models(model: ObservationModel, *, geometry=None,
                scene: Scene | None = None) -> tuple[ObservationModel, ObservationModel]:
    """``(model of sample 0, model of steps 1 … T)``: along a pass (``geometry``, a
    :class:`~lightcurve_gp.passes.geometry.PassGeometry`) bound sample by sample; under the fixed geometry of
    ``scene`` a model that takes geometry (``model.inputs: body_geometry``) bound to it once; else ``model``
    itself twice."""
    if geometry is not None:
        return pass_models(model, geometry)
    if scene is None or getattr(model, "config", {}).get("inputs") != "body_geometry":
        return model, model
    bound = bind_geometry(model, sun=scene.sun, observer=scene.observer, range_m=scene.r_obs)
    return bound, bound


def run_filter(cfg: Config, model: ObservationModel, *, q_est0: Tensor, observations: Tensor,
               increments: Tensor | None = None, sigma0: Tensor | None = None, offset: bool | None = None,
               omega0: Tensor | None = None, R: Tensor | float | None = None, variance: Variance | None = None,
               geometry=None, scene: Scene | None = None) -> FilterHistory:
    """The USQUE of ``cfg`` with ``model`` from ``q_est0 (B, 4)`` on ``observations (B, T+1)`` (mag).

    Args:
        increments: ``(T, 4)`` or ``(B, T, 4)``: ω known (ignored when ``omega0`` is given).
        sigma0: per-filter initial attitude std ``(B,)`` (rad); default ``filter.p0_deg``.
        offset: the offset ``b`` in the state (default ``filter.estimate_offset``).
        omega0: initial body rates ``(B, 3)`` (rad/s) to estimate ω; ``None``: ω known.
        R, variance: as :func:`filter_params`.
        geometry, scene: the pass or the fixed scene the model predicts under (:func:`step_models`).
    """
    offset = cfg.filter.estimate_offset if offset is None else offset
    params = filter_params(cfg, model, R=R, variance=variance)
    start_model, model = step_models(model, geometry=geometry, scene=scene)
    m_past0 = first_observation(observations)
    P0 = prior_covariance(cfg, sigma0=sigma0, offset=offset, omega=omega0 is not None, dtype=q_est0.dtype,
                          device=q_est0.device)
    b0 = initial_offset(start_model, q_est0, observations[:, 0], m_past0) if offset else None
    return run_usque(model=model, q_est0=q_est0, P0=P0, observations=observations, m_past0=m_past0,
                     increments=None if omega0 is not None else increments, params=params, offset0=b0,
                     omega0=omega0)


def run_surface_filter(cfg: Config, scene: Scene, *, q_est0: Tensor, observations: Tensor, increments: Tensor,
                       sigma0: Tensor | None = None, geometry=None, R: Tensor | float | None = None
                       ) -> FilterHistory:
    """The USQUE on ``[δp, θ]`` with the surface state ``θ`` (:mod:`lightcurve_gp.observation.surface_state`): the
    renderer of ``scene`` (the known shape) with every sigma point's surface, ``θ0`` and its prior about ``cfg``'s
    reference surface, ``R`` from ``filter.surface_measurement_noise`` when set; ω known.

    Args:
        scene: the renderer: fixed, or per sample along the pass ``geometry`` (its first sample gives ``θ0``).
        observations: ``(B, T+1)`` (mag); q_est0: ``(B, 4)``; increments: ``(T, 4)`` or ``(B, T, 4)``.
        sigma0: per-filter initial attitude std ``(B,)`` (rad); default ``filter.p0_deg``.
        R: the observations' own noise variance (scalar or ``(B, T+1)``, mag², a file's ``mag_err²``), which
            replaces ``filter.measurement_noise`` and ``filter.surface_measurement_noise``.
    """
    first = scene.sample(0) if scene.per_sample else scene
    theta0, std = surface_state_prior(scene=first, q_est0=q_est0, y0=observations[:, 0],
                                      reference=reference_surface(cfg), offset_std=cfg.filter.offset_prior_std)
    P0 = prior_covariance(cfg, sigma0=sigma0, omega=False, parameter_std=std, dtype=q_est0.dtype,
                          device=q_est0.device)
    model = SurfaceStateRenderer(scene)
    return run_usque(model=step_models(model, geometry=geometry)[1], q_est0=q_est0, P0=P0, observations=observations,
                     m_past0=first_observation(observations), increments=increments,
                     params=filter_params(cfg, model, R=R, surface=True), theta0=theta0)
