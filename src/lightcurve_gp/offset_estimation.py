"""Estimators for an unknown reflectance: the magnitude offset carried in the filter state.

Mirrors :func:`lightcurve_gp.estimation.run_estimators` (same scenario, scoring and :class:`ScenarioResult`) for:

* ``joint_ukf`` — USQUE on ``[δp, b]`` with the renderer at ``model.rho_reference`` (a conventional UKF that
  estimates ρ; exact here because ρ only shifts a diffuse-dominated light curve, see :mod:`.ukf_offset`);
* ``gpukf_offset`` — USQUE on ``[δp, b]`` with a GP trained on ρ-normalised magnitudes (``model.target:
  rho_normalised``), typically with the attitude-only input ``model.inputs: attitude_matrix``.

Both start from ``b0 = ỹ_0 − h(q̂_0)`` with variance ``filter.offset_prior_std²``, the attitude block of ``P0`` being
``(filter.p0_deg)² I``; ``b`` is a random walk of variance ``filter.offset_process_noise`` per step.
"""

from __future__ import annotations

import time
from typing import Sequence

import torch
from torch import Tensor

from .config import Config, ModelConfig
from .data import TrainingSet
from .estimation import ScenarioResult, score_estimator, run_estimators
from .observation.base import ObservationModel
from .observation.parametric import Parametric
from .render import Scene
from .ukf import UsqueParams, initial_covariance
from .ukf_offset import initial_offset, run_usque_offset

__all__ = ["OFFSET_ESTIMATORS", "normalised_targets", "training_arrays", "offset_covariance",
           "run_offset_filter", "run_offset_estimators"]

OFFSET_ESTIMATORS = ("joint_ukf", "gpukf_offset")


def normalised_targets(y: Tensor, rho: Tensor, rho_reference: float) -> Tensor:
    """ρ-normalised magnitudes ``y + 2.5 log10(ρ / ρ0)`` ``(N,)``: the magnitude the attitude would have at ``ρ0``."""
    if not bool((rho > 0).all()):
        raise ValueError("rho: every training reflectance must be positive to normalise magnitudes")
    return y + 2.5 * torch.log10(rho.to(y) / rho_reference)


def training_arrays(ts: TrainingSet, model_cfg: ModelConfig) -> tuple[Tensor, Tensor, Tensor]:
    """GP training arrays ``(q (N, 4), m_past (N,), y (N,))`` with ``model.target`` applied to ``y``.

    ``rho_normalised`` also normalises ``m_past`` (the window mean shifts by the same offset), so a model that
    uses it sees the reference curve only.
    """
    if model_cfg.target == "magnitude":
        return ts.q, ts.m_past, ts.y
    return (ts.q, normalised_targets(ts.m_past, ts.rho, model_cfg.rho_reference),
            normalised_targets(ts.y, ts.rho, model_cfg.rho_reference))


def offset_covariance(p0_deg: float, offset_prior_std: float, *, dtype=None, device=None) -> Tensor:
    """``P0 = diag((p0_deg in rad)² I₃, offset_prior_std²)`` ``(4, 4)`` for the state ``[δp, b]``."""
    P0 = torch.zeros(4, 4, dtype=dtype or torch.get_default_dtype(), device=device)
    P0[:3, :3] = initial_covariance(p0_deg, dtype=P0.dtype, device=device)
    P0[3, 3] = offset_prior_std**2
    return P0


def run_offset_filter(cfg: Config, model: ObservationModel, observations: Tensor, q_est0: Tensor,
                      increments: Tensor):
    """One batched offset-augmented USQUE run with the tuning of ``cfg.filter``; returns its history."""
    params = UsqueParams.from_config(cfg.filter, cfg.data.t_span_past)
    dtype, device = q_est0.dtype, q_est0.device
    m_past0 = observations[:, 0]  # raw magnitudes: attitude-only models ignore the running mean
    b0 = initial_offset(model, q_est0, observations[:, 0], m_past0)
    P0 = offset_covariance(cfg.filter.p0_deg, cfg.filter.offset_prior_std, dtype=dtype, device=device)
    return run_usque_offset(model, q_est0, P0, b0, observations, m_past0, increments, params,
                            offset_process_noise=cfg.filter.offset_process_noise)


def run_offset_estimators(cfg: Config, gp_model: ObservationModel | None = None, *,
                          seeds: Sequence[int] | None = None, rho_true: float | None = None,
                          estimators: Sequence[str] = OFFSET_ESTIMATORS, baselines: Sequence[str] = (),
                          base_gp_model: ObservationModel | None = None,
                          scene: Scene | None = None) -> ScenarioResult:
    """Run ``baselines`` (names of :data:`lightcurve_gp.estimation.ESTIMATORS`) and the offset ``estimators``.

    Args:
        cfg: validated config (``filter`` tuning, ``model.rho_reference`` for ``joint_ukf``).
        gp_model: GP of the reference curve (required for ``gpukf_offset``).
        seeds, rho_true, scene: as in :func:`~lightcurve_gp.estimation.run_estimators`.
        baselines: e.g. ``("gpukf", "ukf", "matched_ukf", "no_update")``, run first on the same scenario.
        base_gp_model: the paper's GP for the ``gpukf`` baseline.
    """
    unknown = [e for e in estimators if e not in OFFSET_ESTIMATORS]
    if unknown:
        raise ValueError(f"unknown offset estimator {unknown[0]!r}; choose from {', '.join(OFFSET_ESTIMATORS)}")
    if "gpukf_offset" in estimators and gp_model is None:
        raise ValueError("the gpukf_offset estimator needs a GP trained on rho-normalised magnitudes")
    dtype, device = cfg.torch_dtype, torch.device(cfg.device)
    scene = (scene or Scene.from_config(cfg)).to(device=device, dtype=dtype)
    out = run_estimators(cfg, base_gp_model, seeds=seeds, rho_true=rho_true, estimators=tuple(baselines),
                         scene=scene)
    sc = out.scenario
    S = len(sc.seeds)
    q_est0 = sc.q_est0.expand(S, 4)
    for name in estimators:
        model = (Parametric(scene, cfg.model.rho_reference).to(device=device, dtype=dtype) if name == "joint_ukf"
                 else gp_model.to(device))
        start = time.perf_counter()
        history = run_offset_filter(cfg, model, sc.observations, q_est0, sc.increments)
        out.results[name] = score_estimator(sc, history.q_est, out.window, history, time.perf_counter() - start)
    return out
