"""Run the paper's estimators side by side on one scenario, all noise seeds batched in each filter.

Estimators (names used in tables, figures and JSON):

* ``gpukf`` — USQUE with the GP observation model (paper section 3.3); with ``filter.estimate_offset`` the GP
  models the reference light curve (``model.target: rho_normalised``) and the filter carries the unknown
  magnitude offset of ρ in its state (:mod:`lightcurve_gp.filters.offset`);
* ``ukf`` — the conventional UKF: USQUE with the renderer and the assumed ``filter.rho_assumed``;
* ``matched_ukf`` — an oracle UKF whose renderer knows ``rho_true`` (a reference the paper does not show);
* ``joint_ukf`` — the renderer at ``model.rho_reference`` with the offset in the state: a conventional UKF that
  estimates ρ (it needs every other surface parameter);
* ``surface_ukf`` — the renderer with the surface as states (log ρ, logit F0, log n_u, log n_v beside the attitude,
  :mod:`lightcurve_gp.observation.surface_state`): surface unknown, shape known (ω taken as known);
* ``surface_ukf_select`` — the same filter run with the paper's ``λ = 0`` and with Julier's ``λ = 3 − n``, each
  seed's run of higher innovation likelihood kept (:func:`run_surface_filter_selected`);
* ``no_update`` — the initial estimate merely propagated with the initial rate (a filter that learned nothing).

With ``filter.estimate_omega`` every filter carries the body rate in its state (``[δp, ω, b?]``,
:mod:`lightcurve_gp.filters.rates`), starting from ``ω_est,0 = ω_0 + scenario.initial_omega_error_deg_s`` with the prior
std ``filter.p0_omega_deg_s`` per axis; otherwise the filters propagate with ``ω_est,0`` as if it were exact.

Every filter starts from ``q_est,0 = q(error) ⊗ q_true,0`` with ``P0 = (p0_deg)² I`` and ``m_past,0 = ỹ_0``
(the first observation); updates use ``ỹ_1 … ỹ_T``. The offset filters start from ``b0 = ỹ_0 − h(q̂_0)`` with
variance ``filter.offset_prior_std²``; ``b`` is a random walk of variance ``filter.offset_process_noise`` per step.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Sequence

import torch
from torch import Tensor

from lightcurve_gp.attitude.dynamics import propagate_only
from lightcurve_gp.attitude.metrics import (
    attitude_error_vector,
    attitude_errors_deg,
    chi2_band,
    lightcurve_rmse,
    nearest_symmetric_rmse,
    nees,
    rmse_over_window,
)
from lightcurve_gp.attitude.rotations import attitude_matrix, quat_mul
from lightcurve_gp.config.load import Config
from lightcurve_gp.evaluation.reporting import quantiles
from lightcurve_gp.filters.offset import initial_offset, offset_covariance
from lightcurve_gp.filters.selection import select_by_likelihood
from lightcurve_gp.filters.usque import FilterHistory, UsqueParams, initial_covariance, run_usque
from lightcurve_gp.observation.along_pass import bind_geometry, pass_models
from lightcurve_gp.observation.base import ObservationModel
from lightcurve_gp.observation.parametric import Parametric, SurfaceStateRenderer
from lightcurve_gp.observation.surface_state import reference_surface, surface_state_prior
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.photometry.symmetry import symmetry_quaternions
from lightcurve_gp.simulation.scenario import Scenario, simulate_scenario

__all__ = ["ESTIMATORS", "DEFAULT_ESTIMATORS", "EstimatorResult", "ScenarioResult",
           "prior_covariance", "run_filter", "run_offset_filter", "run_surface_filter", "surface_filter_params",
           "run_estimators", "score_estimator", "first_observation"]

ESTIMATORS = ("gpukf", "ukf", "matched_ukf", "joint_ukf", "surface_ukf", "surface_ukf_select", "no_update")
#: the λ rules the selecting surface-state filter runs with (``filter.lam_rule``)
SELECTED_LAM_RULES = ("given", "julier")
#: what the tables and the estimate command run unless told otherwise
DEFAULT_ESTIMATORS = ("gpukf", "ukf", "matched_ukf", "no_update")


@dataclass
class EstimatorResult:
    """One estimator over ``S`` seeds.

    Attributes:
        q_est: estimates ``(S, T+1, 4)``.
        errors_deg: Euler 3-2-1 errors (yaw, pitch, roll) of ``q_true ⊗ q_est⁻¹`` ``(S, T+1, 3)`` (deg).
        rmse_deg: RMSE of each Euler error over the scoring window ``(S, 3)`` (deg).
        lc_rmse_noisy / lc_rmse_clean: RMSE of the predicted light curve against the noisy observations and the
            noise-free curve over the window ``(S,)`` (mag); NaN for ``no_update``.
        nees_mean: mean NEES over the window per seed ``(S,)`` (GRP error against ``P``); NaN for ``no_update``.
        seconds: wall time of the whole batched run (s).
        history: the filter history (``None`` for ``no_update``).
        omega_rmse_deg_s: RMSE of the body-rate error norm over the window ``(S,)`` (deg/s).
        omega_error_final_deg_s: the body-rate error norm at the last sample ``(S,)`` (deg/s).
        nees_full_mean: mean NEES over the window of ``[δp, ω]`` (ω estimated) or ``δp`` ``(S,)``; NaN for
            ``no_update``.
        nees_full_dof: the dimension of that NEES (6 or 3).
        rmse_mod_symmetry_deg: the RMSE against the nearest truth ``q_R ⊗ q_true`` the shape's symmetries allow
            ``(S, 3)`` (deg; :func:`~lightcurve_gp.attitude.metrics.nearest_symmetric_rmse`): what a light curve can
            tell.
        symmetry_index: that truth's index ``(S,)`` (0: the truth itself).
        omega_error_final_mod_symmetry_deg_s: the final body-rate error norm against that truth's rate
            ``A(q_R) ω_true`` ``(S,)`` (deg/s): ``q_R ⊗ q(t)`` turns at ``A(q_R) ω(t)``.
        nees_full_mean_mod_symmetry: ``nees_full_mean`` against that truth ``(S,)``; ``None`` for ``no_update``.
    """

    q_est: Tensor
    errors_deg: Tensor
    rmse_deg: Tensor
    lc_rmse_noisy: Tensor
    lc_rmse_clean: Tensor
    nees_mean: Tensor
    seconds: float
    history: FilterHistory | None = None
    omega_rmse_deg_s: Tensor | None = None
    omega_error_final_deg_s: Tensor | None = None
    nees_full_mean: Tensor | None = None
    nees_full_dof: int = 3
    rmse_mod_symmetry_deg: Tensor | None = None
    symmetry_index: Tensor | None = None
    omega_error_final_mod_symmetry_deg_s: Tensor | None = None
    nees_full_mean_mod_symmetry: Tensor | None = None


@dataclass
class ScenarioResult:
    """All estimators on one scenario; ``steps`` filter steps of ``len(scenario.seeds)`` filters each."""

    scenario: Scenario
    window: tuple[float, float]
    results: dict[str, EstimatorResult] = field(default_factory=dict)

    @property
    def steps(self) -> int:
        return self.scenario.increments.shape[0]

    def nees_band(self) -> tuple[float, float]:
        """95 % band of the seed-mean of time-averaged NEES (treats each seed's average as one χ²(3) draw)."""
        return chi2_band(3, len(self.scenario.seeds))

    def summary(self) -> dict:
        """Plain-python summary: per estimator median and IQR of the RMSE per axis over the seeds
        (:func:`~lightcurve_gp.evaluation.reporting.quantiles`, NaN ignored), light-curve RMSE, NEES and timing."""
        out = {"rho_true": self.scenario.rho_true, "seeds": len(self.scenario.seeds), "window_s": list(self.window),
               "nees_band_95": list(self.nees_band()), "estimators": {},
               "omega_estimated": any(r.history is not None and r.history.omega is not None
                                      for r in self.results.values())}
        S = len(self.scenario.seeds)
        for name, r in self.results.items():
            per_axis = [quantiles(r.rmse_deg[:, i]) for i in range(3)]
            mod_sym = {} if r.rmse_mod_symmetry_deg is None else {
                "rmse_deg_median_mod_symmetry": [quantiles(r.rmse_mod_symmetry_deg[:, i]).median for i in range(3)],
                "fraction_all_axes_below_10deg_mod_symmetry":
                    float((r.rmse_mod_symmetry_deg < 10).all(-1).double().mean()),
                "fraction_nearest_symmetric_not_truth": float((r.symmetry_index != 0).double().mean()),
                "omega_error_final_mod_symmetry_deg_s_median": quantiles(r.omega_error_final_mod_symmetry_deg_s).median,
                "nees_full_mean_mod_symmetry": _nanmean(r.nees_full_mean_mod_symmetry)
                if r.nees_full_mean_mod_symmetry is not None else float("nan")}
            out["estimators"][name] = {
                "rmse_deg_median": [q.median for q in per_axis],
                "rmse_deg_q25": [q.q25 for q in per_axis],
                "rmse_deg_q75": [q.q75 for q in per_axis],
                "fraction_all_axes_below_10deg": float((r.rmse_deg < 10).all(-1).double().mean()),
                "lc_rmse_noisy_median": quantiles(r.lc_rmse_noisy).median,
                "lc_rmse_clean_median": quantiles(r.lc_rmse_clean).median,
                "nees_mean": _nanmean(r.nees_mean),
                "nees_full_mean": _nanmean(r.nees_full_mean),
                "nees_full_band_95": list(chi2_band(r.nees_full_dof, S)),
                "omega_rmse_deg_s_median": quantiles(r.omega_rmse_deg_s).median,
                "omega_error_final_deg_s_median": quantiles(r.omega_error_final_deg_s).median,
                "seconds": r.seconds,
                "seconds_per_step": r.seconds / self.steps,
                "seconds_per_filter_step": r.seconds / (self.steps * S),
                "sqrt_fallbacks": int(r.history.fallbacks.sum()) if r.history is not None else 0,
                "rejected_updates": int(r.history.rejected.sum()) if r.history is not None else 0,
                **mod_sym,
            }
        return out


def _nanmean(x: Tensor) -> float:
    return float(torch.nanmean(x)) if x.numel() else float("nan")




def score_estimator(sc: Scenario, q_est: Tensor, window, history: FilterHistory | None, seconds: float, *,
                    q_sym: Tensor | None = None) -> EstimatorResult:
    """Errors, windowed RMSE, light-curve RMSE, NEES and body-rate errors of estimates ``q_est (S, T+1, 4)`` on
    scenario ``sc`` (the rates of ``history.omega`` when ω was estimated, else ``sc.omega_assumed``); with the
    shape's symmetries ``q_sym (K, 4)`` (identity first) also the errors against the nearest symmetric truth."""
    S = len(sc.seeds)
    q_true = sc.q_true.expand(S, -1, -1)
    errors = attitude_errors_deg(q_true, q_est)
    rmse = rmse_over_window(errors.transpose(-1, -2), sc.times, window)  # (S, 3)
    omega_est = sc.omega_assumed if history is None or history.omega is None else history.omega
    omega_err = torch.rad2deg(sc.omega_true - omega_est).expand(S, -1, -1)  # (S, T+1, 3)
    omega_norm = torch.linalg.vector_norm(omega_err, dim=-1)
    omega_rmse = rmse_over_window(omega_norm, sc.times, window)
    in_window = (sc.times >= window[0]) & (sc.times <= window[1])
    symmetric = {} if q_sym is None else _symmetric_scores(sc, q_est, omega_est, q_sym, window, history, in_window)
    nan = torch.full((S,), float("nan"), dtype=q_est.dtype)
    if history is None:
        return EstimatorResult(q_est, errors, rmse, nan, nan, nan, seconds, None, omega_rmse, omega_norm[:, -1], nan,
                               **symmetric)
    lc_noisy = lightcurve_rmse(history.y_pred, sc.observations, sc.times, window)
    lc_clean = lightcurve_rmse(history.y_pred, sc.m_clean.expand(S, -1), sc.times, window)
    nees_w, nees_full, dof = _window_nees(q_true, omega_err, q_est, history, in_window)
    return EstimatorResult(q_est, errors, rmse, lc_noisy, lc_clean, nees_w, seconds, history, omega_rmse,
                           omega_norm[:, -1], nees_full, dof, **symmetric)


def _window_nees(q_true: Tensor, omega_err_deg_s: Tensor, q_est: Tensor, history: FilterHistory,
                 in_window: Tensor) -> tuple[Tensor, Tensor, int]:
    """Mean NEES over the window ``(S,)`` of the attitude (GRP error against ``P``) and of the whole estimated
    state ``[δp, ω]`` (the attitude's when ω is known) and that state's dimension; ``q_true (S, T+1, 4)``,
    ``omega_err_deg_s (S, T+1, 3)``."""
    err_vec = attitude_error_vector(q_true, q_est, kind="grp")
    nees_w = nees(err_vec[:, in_window], history.P[:, in_window]).mean(-1)
    if history.omega is None:
        return nees_w, nees_w, 3
    full_err = torch.cat([err_vec, torch.deg2rad(omega_err_deg_s)], dim=-1)
    return nees_w, nees(full_err[:, in_window], history.P_full[:, in_window, :6, :6]).mean(-1), 6


def _symmetric_scores(sc: Scenario, q_est: Tensor, omega_est: Tensor, q_sym: Tensor, window,
                      history: FilterHistory | None, in_window: Tensor) -> dict[str, Tensor]:
    """The :class:`EstimatorResult` fields against the nearest symmetric truth ``q_R ⊗ q_true`` turning at
    ``A(q_R) ω_true`` (``omega_est (S, T+1, 3)`` or ``(T+1, 3)``, rad/s)."""
    q_sym = q_sym.to(q_est)
    rmse, best = nearest_symmetric_rmse(sc.q_true, q_est, q_sym, sc.times, window)
    omega_sym = sc.omega_true.unsqueeze(0) @ attitude_matrix(q_sym[best]).mT  # (S, T+1, 3)
    omega_err = torch.rad2deg(omega_sym - omega_est)
    out = {"rmse_mod_symmetry_deg": rmse, "symmetry_index": best,
           "omega_error_final_mod_symmetry_deg_s": torch.linalg.vector_norm(omega_err[:, -1], dim=-1)}
    if history is not None:
        q_true_sym = quat_mul(q_sym[best].unsqueeze(1), sc.q_true.unsqueeze(0))
        out["nees_full_mean_mod_symmetry"] = _window_nees(q_true_sym, omega_err, q_est, history, in_window)[1]
    return out


def run_offset_filter(cfg: Config, model: ObservationModel, observations: Tensor, q_est0: Tensor,
                      increments: Tensor, *, start_model: ObservationModel | None = None) -> FilterHistory:
    """One batched offset-augmented USQUE run with the tuning of ``cfg`` (``b0 = ỹ_0 − h(q̂_0)``, ``h`` =
    ``start_model``, default ``model``: along a pass the model of sample 0 while ``model`` serves steps 1 … T)."""
    m_past0 = first_observation(observations)
    b0 = initial_offset(start_model or model, q_est0, observations[:, 0], m_past0)
    P0 = offset_covariance(cfg.filter.p0_deg, cfg.filter.offset_prior_std, dtype=q_est0.dtype, device=q_est0.device)
    return run_usque(model=model, q_est0=q_est0, P0=P0, observations=observations, m_past0=m_past0,
                     increments=increments, params=UsqueParams.from_config(cfg), offset0=b0)


def prior_covariance(cfg: Config, *, offset: bool, dtype=None, device=None) -> Tensor:
    """The filters' ``P0 (n, n)``: ``(p0_deg)² I₃`` on the attitude, ``(p0_omega_deg_s)² I₃`` on ω (rad²/s²) with
    ``filter.estimate_omega``, ``offset_prior_std²`` on ``b`` when ``offset``."""
    P_att = offset_covariance(cfg.filter.p0_deg, cfg.filter.offset_prior_std, dtype=dtype, device=device) if offset \
        else initial_covariance(cfg.filter.p0_deg, dtype=dtype, device=device)
    if not cfg.filter.estimate_omega:
        return P_att
    n = P_att.shape[0] + 3
    P0 = torch.zeros(n, n, dtype=P_att.dtype, device=P_att.device)
    P0[:3, :3] = P_att[:3, :3]
    P0[3:6, 3:6] = math.radians(cfg.filter.p0_omega_deg_s) ** 2 * torch.eye(3, dtype=P_att.dtype, device=device)
    P0[6:, 6:] = P_att[3:, 3:]
    return P0


def run_filter(cfg: Config, model: ObservationModel, sc: Scenario, q_est0: Tensor, *, offset: bool,
               start_model: ObservationModel | None = None, params: UsqueParams | None = None) -> FilterHistory:
    """One batched USQUE run on ``sc`` with the tuning of ``cfg`` (or ``params``): ω in the state with
    ``filter.estimate_omega`` (from ``sc.omega_est0``), else the increments of ``sc.omega_assumed``; the offset ``b``
    in the state when ``offset`` (``b0 = ỹ_0 − h(q̂_0)``, ``h`` = ``start_model``, default ``model``, as
    :func:`run_offset_filter`)."""
    obs = sc.observations
    m_past0 = first_observation(obs)
    P0 = prior_covariance(cfg, offset=offset, dtype=q_est0.dtype, device=q_est0.device)
    b0 = initial_offset(start_model or model, q_est0, obs[:, 0], m_past0) if offset else None
    motion = {"omega0": sc.omega_est0.expand(q_est0.shape[0], 3)} if cfg.filter.estimate_omega \
        else {"increments": sc.increments_assumed}
    return run_usque(model=model, q_est0=q_est0, P0=P0, observations=obs, m_past0=m_past0,
                     params=params or UsqueParams.from_config(cfg), offset0=b0, **motion)


def run_surface_filter(cfg: Config, scene: Scene, *, observations: Tensor, q_est0: Tensor, increments: Tensor,
                       P0_attitude: Tensor, model: ObservationModel | None = None) -> FilterHistory:
    """One batched USQUE run on ``[δp, θ]`` with the surface state ``θ``
    (:mod:`lightcurve_gp.observation.surface_state`): the
    renderer of ``scene`` (the known shape) with every sigma point's surface, the prior of
    :func:`~lightcurve_gp.observation.surface_state.surface_state_prior` about ``cfg``'s reference surface.

    Args:
        observations: ``(B, T+1)`` (mag); q_est0: ``(B, 4)``; increments: ``(T, 4)`` or ``(B, T, 4)``.
        P0_attitude: the attitude block of ``P0`` ``(3, 3)`` or ``(B, 3, 3)`` (rad²).
        model: the filter's observation model (default ``SurfaceStateRenderer(scene)``; along a pass an
            :class:`~lightcurve_gp.observation.along_pass.AlongPass` of it, ``scene`` then the first sample's).
    """
    B = q_est0.shape[0]
    theta0, std = surface_state_prior(scene=scene, q_est0=q_est0, y0=observations[:, 0],
                                      reference=reference_surface(cfg), offset_std=cfg.filter.offset_prior_std)
    P0 = torch.zeros(B, 7, 7, dtype=q_est0.dtype, device=q_est0.device)
    P0[:, :3, :3] = P0_attitude
    P0[:, 3:, 3:] = torch.diag(std.pow(2)).to(P0)
    return run_usque(model=model or SurfaceStateRenderer(scene), q_est0=q_est0, P0=P0, observations=observations,
                     m_past0=first_observation(observations), increments=increments,
                     params=surface_filter_params(cfg), theta0=theta0)


def surface_filter_params(cfg: Config) -> UsqueParams:
    """The USQUE settings of the surface-state filters: ``cfg``'s, with ``R`` from
    ``filter.surface_measurement_noise`` when it is set (experiments/README.md says how the robust config's value
    was chosen)."""
    params = UsqueParams.from_config(cfg)
    R = cfg.filter.surface_measurement_noise
    return params if R is None else dataclasses.replace(params, R=float(R))


def run_surface_filter_selected(cfg: Config, scene: Scene, *, observations: Tensor, q_est0: Tensor,
                                increments: Tensor, P0_attitude: Tensor,
                                model: ObservationModel | None = None) -> tuple[FilterHistory, Tensor]:
    """:func:`run_surface_filter` with ``cfg``'s filter under each rule of :data:`SELECTED_LAM_RULES` (the paper's
    ``λ`` as the config gives it, and ``λ = 3 − n``) on the same observations; per seed the run of higher
    innovation log-likelihood (:func:`lightcurve_gp.filters.selection.select_by_likelihood`) and which rule
    that was ``(B,)`` (an index into :data:`SELECTED_LAM_RULES`). Arguments as :func:`run_surface_filter`'s."""
    runs = [run_surface_filter(dataclasses.replace(cfg, filter=dataclasses.replace(cfg.filter, lam_rule=rule)), scene,
                               observations=observations, q_est0=q_est0, increments=increments,
                               P0_attitude=P0_attitude, model=model)
            for rule in SELECTED_LAM_RULES]
    return select_by_likelihood(runs)


def first_observation(observations: Tensor) -> Tensor:
    """Each row's first finite observation ``(S,)`` (0 for a row without one): the filters' ``m_past,0``. With the
    fixed geometry this is ``ỹ_0``; along a pass the first samples may be unobservable (NaN)."""
    finite = torch.isfinite(observations)
    first = finite.double().argmax(-1, keepdim=True)
    value = torch.gather(observations, -1, first).squeeze(-1)
    return torch.where(finite.any(-1), value, torch.zeros_like(value))


def _pass_models(model: ObservationModel, sc: Scenario, scene: Scene) -> tuple[ObservationModel, ObservationModel]:
    """``(model at sample 0, model of steps 1 … T)``: along a pass bound sample by sample (:class:`AlongPass`);
    under the fixed geometry a geometry-aware model bound to it once."""
    if sc.geometry is not None:
        return pass_models(model, sc.geometry)
    if getattr(model, "config", {}).get("inputs") != "body_geometry":  # the renderers hold the fixed geometry
        return model, model
    bound = bind_geometry(model, sun=scene.sun, observer=scene.observer, range_m=scene.r_obs)
    return bound, bound


def _surface_history(name: str, cfg: Config, scene: Scene, sc: Scenario, q_est0: Tensor,
                     model: ObservationModel) -> FilterHistory:
    """The run of ``surface_ukf`` or ``surface_ukf_select`` on the scenario (``P0`` from ``filter.p0_deg``)."""
    run = dict(observations=sc.observations, q_est0=q_est0, increments=sc.increments_assumed, model=model,
               P0_attitude=initial_covariance(cfg.filter.p0_deg, dtype=q_est0.dtype, device=q_est0.device))
    first = scene.sample(0) if scene.per_sample else scene
    if name == "surface_ukf":
        return run_surface_filter(cfg, first, **run)
    return run_surface_filter_selected(cfg, first, **run)[0]


def run_estimators(cfg: Config, gp_model: ObservationModel | None = None, *, seeds: Sequence[int] | None = None,
                   rho_true: float | None = None, estimators: Sequence[str] = DEFAULT_ESTIMATORS,
                   scene: Scene | None = None) -> ScenarioResult:
    """Simulate ``cfg.scenario`` (optionally with another ``rho_true``) and run the chosen estimators.

    Args:
        cfg: validated config; ``filter`` gives the USQUE tuning, ``data.t_span_past`` the ``m_past`` recursion.
        gp_model: the trained GP observation model (required for ``gpukf``).
        seeds: noise seeds (default ``range(cfg.scenario.seeds)``); all run as one batch per estimator.
        rho_true: overrides ``cfg.scenario.rho_true``.
        estimators: any of :data:`ESTIMATORS`.
        scene: renderer (default ``Scene.from_config(cfg)``), shared by the truth and the parametric filters.

    Along a pass (``geometry.kind: orbit``) every filter's model predicts step ``k`` with the geometry of sample
    ``k`` (:class:`~lightcurve_gp.observation.along_pass.AlongPass`): the renderer of the UKFs and a
    ``body_geometry`` GP; a GP trained under one fixed geometry keeps its assumption.
    """
    unknown = [e for e in estimators if e not in ESTIMATORS]
    if unknown:
        raise ValueError(f"unknown estimator {unknown[0]!r}; choose from {', '.join(ESTIMATORS)}")
    if "gpukf" in estimators and gp_model is None:
        raise ValueError("the gpukf estimator needs a trained GP model (train one with python -m lightcurve_gp.train)")
    trained_on = getattr(gp_model, "config", {}).get("target", "magnitude") if gp_model is not None else None
    if "gpukf" in estimators and trained_on != cfg.model.target:
        raise ValueError(f"model.target: the GP was trained on target {trained_on!r}, the config says "
                         f"{cfg.model.target!r}; train a model with this config")
    dtype, device = cfg.torch_dtype, torch.device(cfg.device)
    scene = (scene or Scene.from_config(cfg)).to(device=device, dtype=dtype)
    sc = simulate_scenario(cfg, seeds=seeds, rho_true=rho_true, scene=scene)
    window = tuple(cfg.evaluation.rmse_window_s)
    S = len(sc.seeds)
    q_est0 = sc.q_est0.expand(S, 4)
    models = {"gpukf": gp_model, "ukf": Parametric(scene, cfg.filter.rho_assumed),
              "matched_ukf": Parametric(scene, sc.rho_true), "joint_ukf": Parametric(scene, cfg.model.rho_reference),
              "surface_ukf": SurfaceStateRenderer(scene), "surface_ukf_select": SurfaceStateRenderer(scene)}
    surface = [e for e in estimators if e in ("surface_ukf", "surface_ukf_select")]
    if surface and cfg.filter.estimate_omega:
        raise ValueError(f"{surface[0]}: the surface-state filter takes ω as known; run it with "
                         "filter.estimate_omega false")
    with_offset = {"joint_ukf", "gpukf"} if cfg.filter.estimate_offset else {"joint_ukf"}
    out = ScenarioResult(sc, window)
    q_sym = symmetry_quaternions(scene.facets)
    for name in estimators:
        start = time.perf_counter()
        if name == "no_update":
            q_est, history = propagate_only(sc.q_est0, sc.increments_assumed).expand(S, -1, -1), None
        else:
            model = models[name].to(device=device, dtype=dtype) if name != "gpukf" else models[name].to(device)
            params = UsqueParams.from_config(cfg, model=model)  # before the pass wrapper: the GP's model error
            start_model, model = _pass_models(model, sc, scene)
            if name in ("surface_ukf", "surface_ukf_select"):
                history = _surface_history(name, cfg, scene, sc, q_est0, model)
            else:
                history = run_filter(cfg, model, sc, q_est0, offset=name in with_offset, start_model=start_model,
                                     params=params)
            q_est = history.q_est
        out.results[name] = score_estimator(sc, q_est, window, history, time.perf_counter() - start, q_sym=q_sym)
    return out
