"""Scores of one estimator on a scenario, per seed: every accuracy and consistency number the tables report.

An estimator gives its attitude estimates at some of the scenario's samples (a filter at every sample, the batch MAP
at its checkpoints) with their covariances. Scored over the samples inside ``evaluation.rmse_window_s``
(docs/design.md, Conventions):

* the RMSE of each Euler 3-2-1 angle of ``q_true ⊗ q_est⁻¹`` (NaN samples ignored);
* the time-averaged NEES of the GRP error (``filter.grp_a``, ``filter.grp_f``) against the attitude covariance, and
  the whitened errors ``L⁻¹ e`` (``L Lᵀ = P``) at the first and last scored sample, whose correlation tells how many
  independent draws that average holds (:func:`nees_band`);
* the body-rate error (the filter's ω when estimated, else the rate it assumed);
* for a filter, the RMSE of its predicted light curve against the noisy and the noise-free curve, and the NEES of
  its whole estimated state ``[δp, ω]``;
* the same attitude scores against the nearest image of the truth under the scenario's exact ambiguity group
  (:class:`~lightcurve_gp.photometry.ambiguity.AmbiguityGroup`, derived per scenario by
  :func:`lightcurve_gp.evaluation.harness.scenario_ambiguity_group`): the truth ``q_R ⊗ q_true(t) ⊗ q_C`` turning at
  ``R ω_true(t)`` (:func:`nearest_symmetric_rmse`). A right product ``q_C`` (an inertial turn) commutes with the
  propagation and keeps the body rate; a body turn ``q_R`` turns the rate with it, so it is an image only where the
  rate is estimated (with ω known the group holds the inertial turns alone). "Modulo symmetry" below means modulo
  that group.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

from lightcurve_gp.attitude.metrics import (
    attitude_error_vector,
    attitude_errors_deg,
    chi2_band,
    lightcurve_rmse,
    nees,
    rmse_over_window,
)
from lightcurve_gp.filters.state import FilterHistory
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup
from lightcurve_gp.simulation.scenario import Scenario

__all__ = ["Estimate", "EstimatorResult", "nees_band", "nearest_symmetric_rmse", "score"]


@dataclass
class Estimate:
    """What an estimator returns for ``S`` seeds, before scoring.

    Attributes:
        q_est: attitude estimates ``(S, K, 4)`` at the scenario's samples ``samples``.
        P: their GRP-error covariances ``(S, K, 3, 3)`` (rad²), or ``None``.
        samples: indices ``(K,)`` into the scenario's samples; ``None``: every sample (``K = T+1``).
        history: a filter's history (``None`` for other estimators).
        offset_final: the final magnitude-offset estimate ``(S,)`` (mag) of estimators that carry one, else ``None``.
        uses_observations: ``False`` for an estimate that never looks at the light curve (its covariance is its
            unchanged prior).
    """

    q_est: Tensor
    P: Tensor | None
    samples: Tensor | None = None
    history: FilterHistory | None = None
    offset_final: Tensor | None = None
    uses_observations: bool = True

    @classmethod
    def of_filter(cls, history: FilterHistory) -> Estimate:
        """The estimate of a filter run: every sample, its final offset when it carried one."""
        offset = None if history.offset is None else history.offset[:, -1]
        return cls(history.q_est, history.P, history=history, offset_final=offset)


@dataclass
class EstimatorResult:
    """One estimator on ``S`` seeds, scored (module docstring).

    Attributes:
        q_est: estimates ``(S, K, 4)`` at ``samples`` (``(K,)`` indices into the scenario's samples).
        errors_deg: Euler 3-2-1 errors (yaw, pitch, roll) of ``q_true ⊗ q_est⁻¹`` ``(S, K, 3)`` (deg).
        rmse_deg: RMSE of each Euler error over the scored samples ``(S, 3)`` (deg).
        nees_mean: mean NEES of the attitude over the scored samples ``(S,)``; NaN without a covariance.
        white_first, white_last: whitened errors at the first and last scored sample ``(S, 3)``.
        lc_rmse_noisy, lc_rmse_clean: RMSE of a filter's predicted light curve against the noisy observations and
            the noise-free curve over the window ``(S,)`` (mag); NaN for other estimators.
        omega_rmse_deg_s: RMSE of the body-rate error norm over the scored samples ``(S,)`` (deg/s).
        omega_error_final_deg_s: the body-rate error norm at the last sample ``(S,)`` (deg/s).
        nees_full_mean: a filter's mean NEES of ``[δp, ω]`` (ω estimated) or ``δp`` ``(S,)``; NaN otherwise.
        nees_full_dof: the dimension of that NEES (6 or 3).
        rmse_mod_symmetry_deg: the RMSE against the truth's nearest image under the ambiguity group ``(S, 3)`` (deg).
        symmetry_index: that image's index into the group ``(S,)`` (0: the truth itself).
        omega_error_final_mod_symmetry_deg_s: the final body-rate error norm against that truth's rate ``(S,)``.
        nees_full_mean_mod_symmetry: ``nees_full_mean`` against that truth ``(S,)``; ``None`` for non-filters.
        offset_final: the final offset estimate ``(S,)`` (mag), or ``None``.
        seconds: wall time of the batched run (s).
        samples: the scored estimate's sample indices ``(K,)``.
        uses_observations: as :attr:`Estimate.uses_observations`.
        history: the filter history (``None`` for other estimators).
        crb_deg: the Cramér–Rao bound of the same problem ``(S, 3)`` (deg; RMS over the window of each Euler
            angle's bound, :mod:`lightcurve_gp.evaluation.bounds`), or ``None`` when not computed.
    """

    q_est: Tensor
    errors_deg: Tensor
    rmse_deg: Tensor
    nees_mean: Tensor
    white_first: Tensor
    white_last: Tensor
    lc_rmse_noisy: Tensor
    lc_rmse_clean: Tensor
    omega_rmse_deg_s: Tensor
    omega_error_final_deg_s: Tensor
    nees_full_mean: Tensor
    nees_full_dof: int
    rmse_mod_symmetry_deg: Tensor
    symmetry_index: Tensor
    omega_error_final_mod_symmetry_deg_s: Tensor
    nees_full_mean_mod_symmetry: Tensor | None
    offset_final: Tensor | None
    seconds: float
    samples: Tensor
    uses_observations: bool = True
    history: FilterHistory | None = None
    crb_deg: Tensor | None = None

    @property
    def trajectory(self) -> bool:
        """Whether the estimate covers every sample of the scenario (a filter or the no-update baseline)."""
        return self.history is not None or not self.uses_observations


def nees_band(independent_samples: int = 1, confidence: float = 0.95) -> tuple[float, float]:
    """The single-run band of a time-averaged NEES that holds ``independent_samples`` independent χ²(3) draws.

    A filter's attitude error is strongly autocorrelated: with ω known and no process noise it is one random vector
    turned by the known motion and corrected a little by each sample. On the suite's held-out seeds the whitened
    errors at the two ends of the 200 s window still correlate 0.26-0.52 (Spearman, pooled; neighbouring samples far
    more), so the average of the ~200 NEES samples holds one to two independent draws, not 200. The default is the
    band of one draw, ``[0.22, 9.35]`` (two: ``[0.62, 7.22]``); the band of 200 independent draws, ``[2.67, 3.35]``,
    would reject a consistent filter in most runs. Check: the no-update baseline, whose ``P0`` matches its initial
    error by construction, has 94 % of its held-out seeds inside the one-draw band.
    """
    return chi2_band(3, independent_samples, confidence)


def nearest_symmetric_rmse(q_true: Tensor, q_est: Tensor, group: AmbiguityGroup, times: Tensor,
                           window: Sequence[float]) -> tuple[Tensor, Tensor]:
    """The Euler-angle RMSE of each estimate against the nearest of the truth's images ``q_R ⊗ q_true ⊗ q_C`` under
    the scenario's exact ambiguity ``group`` (the identity first; module docstring).

    Args:
        q_true: true attitudes ``(T, 4)`` or ``(S, T, 4)``; q_est: estimates ``(S, T, 4)``.
        group: the scenario's images (:func:`lightcurve_gp.evaluation.harness.scenario_ambiguity_group`).
        times: ``(T,)`` s; window: inclusive ``(start, end)`` s of the RMSE.

    Returns:
        The RMSE (yaw, pitch, roll) against the nearest image ``(S, 3)`` (deg) — the one with the smallest sum of
        squared per-axis RMSEs, the identity on ties — and its index into ``group`` ``(S,)``.
    """
    truths = group.attitudes(q_true.expand_as(q_est))  # (K, S, T, 4)
    rmse = rmse_over_window(attitude_errors_deg(truths, q_est.unsqueeze(0)).transpose(-1, -2), times, window)
    best = rmse.pow(2).sum(-1).argmin(0)  # (S,): argmin returns the first of equal values
    return rmse[best, torch.arange(q_est.shape[0], device=q_est.device)], best


def _whitened(err: Tensor, P: Tensor) -> Tensor:
    """``L⁻¹ e`` with ``L Lᵀ = P`` for errors ``(..., 3)`` and covariances ``(..., 3, 3)``; NaN where ``P`` is not
    positive definite."""
    L, info = torch.linalg.cholesky_ex(P)
    white = torch.linalg.solve_triangular(L, err.unsqueeze(-1), upper=False).squeeze(-1)
    return torch.where((info == 0).unsqueeze(-1), white, torch.full_like(white, float("nan")))


def _full_nees(q_true: Tensor, omega_err_deg_s: Tensor, q_est: Tensor, history: FilterHistory, inside: Tensor,
               grp: tuple[float, float]) -> tuple[Tensor, int]:
    """Mean NEES over the window ``(S,)`` of a filter's whole estimated state ``[δp, ω]`` (``δp`` when ω is known)
    and that state's dimension; ``q_true (S, T+1, 4)``, ``omega_err_deg_s (S, T+1, 3)``."""
    err_vec = attitude_error_vector(q_true, q_est, kind="grp", a=grp[0], f=grp[1])
    if history.omega is None:
        return nees(err_vec[:, inside], history.P[:, inside]).mean(-1), 3
    full_err = torch.cat([err_vec, torch.deg2rad(omega_err_deg_s)], dim=-1)
    return nees(full_err[:, inside], history.P_full[:, inside, :6, :6]).mean(-1), 6


def score(sc: Scenario, est: Estimate, *, window: Sequence[float], group: AmbiguityGroup,
          grp: tuple[float, float], seconds: float) -> EstimatorResult:
    """Score ``est`` on ``sc`` over ``window`` (s) with the scenario's exact ambiguity ``group`` (identity first) and
    the GRP parameters ``grp = (a, f)`` of the NEES (module docstring)."""
    samples = torch.arange(sc.times.shape[0], device=sc.times.device) if est.samples is None else est.samples
    times, q_true, q_est = sc.times[samples], sc.q_true[:, samples], est.q_est
    S, nan = q_est.shape[0], torch.full((q_est.shape[0],), float("nan"), dtype=q_est.dtype, device=q_est.device)
    inside = (times >= window[0]) & (times <= window[1])
    errors = attitude_errors_deg(q_true, q_est)
    h = est.history
    omega_est = sc.omega_assumed[:, samples] if h is None or h.omega is None else h.omega
    omega_err = torch.rad2deg(sc.omega_true[:, samples] - omega_est)  # (S, K, 3)
    omega_norm = torch.linalg.vector_norm(omega_err, dim=-1)
    nees_mean, white = nan, torch.full((2, S, 3), float("nan"), dtype=q_est.dtype, device=q_est.device)
    if est.P is not None and bool(inside.any()):
        err_vec = attitude_error_vector(q_true, q_est, kind="grp", a=grp[0], f=grp[1])[:, inside]
        P = est.P[:, inside]
        nees_mean, white = nees(err_vec, P).mean(-1), _whitened(err_vec[:, [0, -1]], P[:, [0, -1]]).unbind(1)
    lc_noisy, lc_clean, nees_full, dof = nan, nan, nan, 3
    if h is not None:
        lc_noisy = lightcurve_rmse(h.y_pred, sc.observations, sc.times, window)
        lc_clean = lightcurve_rmse(h.y_pred, sc.m_clean, sc.times, window)
        nees_full, dof = _full_nees(q_true, omega_err, q_est, h, inside, grp)
    return EstimatorResult(
        q_est=q_est, errors_deg=errors, rmse_deg=rmse_over_window(errors.transpose(-1, -2), times, window),
        nees_mean=nees_mean, white_first=white[0], white_last=white[1], lc_rmse_noisy=lc_noisy,
        lc_rmse_clean=lc_clean, omega_rmse_deg_s=rmse_over_window(omega_norm, times, window),
        omega_error_final_deg_s=omega_norm[:, -1], nees_full_mean=nees_full, nees_full_dof=dof,
        **_symmetric_scores(sc, est, samples, omega_est, group, window, inside, grp),
        offset_final=est.offset_final, seconds=seconds, samples=samples,
        uses_observations=est.uses_observations, history=h)


def _symmetric_scores(sc: Scenario, est: Estimate, samples: Tensor, omega_est: Tensor, group: AmbiguityGroup,
                      window: Sequence[float], inside: Tensor, grp: tuple[float, float]) -> dict[str, Tensor | None]:
    """The :class:`EstimatorResult` fields against the truth's nearest image ``q_R ⊗ q_true ⊗ q_C`` turning at
    ``R ω_true`` (``omega_est (S, K, 3)``, rad/s)."""
    q_est = est.q_est
    group = group.to(device=q_est.device, dtype=q_est.dtype)
    q_true, seeds = sc.q_true[:, samples], torch.arange(q_est.shape[0], device=q_est.device)
    rmse, best = nearest_symmetric_rmse(q_true, q_est, group, sc.times[samples], window)
    omega_sym = group.rates(sc.omega_true[:, samples])[best, seeds]  # (S, K, 3)
    omega_err = torch.rad2deg(omega_sym - omega_est)
    full = None
    if est.history is not None:
        q_true_sym = group.attitudes(q_true)[best, seeds]
        full = _full_nees(q_true_sym, omega_err, q_est, est.history, inside, grp)[0]
    return {"rmse_mod_symmetry_deg": rmse, "symmetry_index": best,
            "omega_error_final_mod_symmetry_deg_s": torch.linalg.vector_norm(omega_err[:, -1], dim=-1),
            "nees_full_mean_mod_symmetry": full}
