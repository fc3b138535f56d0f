"""What an estimator is given: observations and what is known before them.

A :class:`Problem` is the observations of ``S`` objects at common times (:class:`~.observations.Observations`,
batched) with, per object, the prior of the initial attitude (``q_est0`` and its per-axis σ), the body rate assumed
known at the first sample and the motion it implies (the kinematic increments between samples, from the
closed-form torque-free motion of :mod:`lightcurve_gp.attitude.timeline`, any spacing, any gap). Every estimator of
:mod:`lightcurve_gp.evaluation.registry` and the commands' runs on files take one; a simulated
:class:`~lightcurve_gp.simulation.scenario.Scenario` gives one (:meth:`Scenario.problem`) whose assumed rate and
increments are the scenario's own, and a light-curve file gives one through :func:`problem_from_observations`. The
truth is not here, except the oracle estimators' one piece of it (``surface``, a simulation's true surface; ``None``
for a file).

Tensors lead with the object dimension ``S``; times in s, rates in rad/s, variances in mag².
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import quat_normalize
from lightcurve_gp.attitude.timeline import spin_increments
from lightcurve_gp.observations.observations import Observations, ObservationsError
from lightcurve_gp.passes.geometry import PassGeometry
from lightcurve_gp.photometry.brdf import Surface

__all__ = ["Problem", "problem_from_observations", "pass_geometry_of"]


@dataclass(frozen=True)
class Problem:
    """Observations of ``S`` objects and their priors (module docstring).

    Attributes:
        obs: the observations, batched (``mag (S, N)``; NaN where one object's sample is missing).
        q_est0: prior mean of the attitude at the first sample ``(S, 4)``.
        sigma0: prior 1σ of the attitude error per axis ``(S,)`` (rad).
        omega_est0: the body rate assumed at the first sample ``(S, 3)`` (rad/s).
        increments_assumed: ``(S, N − 1, 4)``: ``q_{k+1} = normalise(δ_k ⊗ q_k)`` under the assumed rate.
        R: per-sample measurement variance ``(S, N)`` (mag²), or ``None``: the config's ``filter.measurement_noise``
            (a simulation's filters are tuned with it).
        surface: the true surface ``(S,)`` fields, for the oracle estimators only (``None`` outside simulations).
        rho_true: the one true ρ every object shares when the truth is the config's surface (oracle; else ``None``).
        geometry: the per-sample geometry (``None``: the config's fixed geometry).
    """

    obs: Observations
    q_est0: Tensor
    sigma0: Tensor
    omega_est0: Tensor
    increments_assumed: Tensor
    R: Tensor | None = None
    surface: Surface | None = None
    rho_true: float | None = None
    geometry: PassGeometry | None = None

    @property
    def observations(self) -> Tensor:
        """The magnitudes ``(S, N)``."""
        return self.obs.mag

    @property
    def times(self) -> Tensor:
        """Sample times ``(N,)`` (s)."""
        return self.obs.t

    @property
    def seeds(self) -> int:
        """``S``, the number of objects."""
        return int(self.q_est0.shape[0])

    @property
    def steps(self) -> int:
        """The number of filter steps ``N − 1``."""
        return int(self.increments_assumed.shape[1])

    @property
    def P0(self) -> Tensor:
        """Initial attitude covariances ``σ0² I`` ``(S, 3, 3)`` (rad²)."""
        eye = torch.eye(3, dtype=self.sigma0.dtype, device=self.sigma0.device)
        return self.sigma0.pow(2).view(-1, 1, 1) * eye

    def noise_variance(self, default: float) -> Tensor | float:
        """``R`` when the observations give it, else ``default`` (the config's)."""
        return default if self.R is None else self.R


def pass_geometry_of(obs: Observations) -> PassGeometry | None:
    """The per-sample geometry of ``obs`` as the filters' :class:`PassGeometry` (``None`` without one)."""
    if not obs.has_geometry:
        return None
    return PassGeometry.from_columns(times_s=obs.t.cpu(), sun=obs.sun.cpu(), observer=obs.observer.cpu(),
                                     range_m=obs.range_m.cpu(), start_utc=obs.epoch, shadow_model="none")


def problem_from_observations(obs: Observations, *, q_est0: Tensor, sigma0: float, omega0: Tensor, inertia,
                              dtype: torch.dtype = torch.float64, device=None) -> Problem:
    """The :class:`Problem` of one object's observations (a file): prior mean ``q_est0 (4,)`` (normalised here),
    prior 1σ ``sigma0`` (rad) per axis, the body rate ``omega0 (3,)`` (rad/s) assumed at the first sample, the
    principal moments ``inertia (3,)`` (kg m²); ``R = σ²`` per sample. Samples at equal times are refused (the
    filters step from sample to sample)."""
    if obs.batch is not None:
        raise ObservationsError("problem_from_observations: takes one object's observations (mag (N,))")
    if len(obs) > 1 and not bool((torch.diff(obs.t) > 0).all()):
        k = int(torch.nonzero(torch.diff(obs.t) <= 0)[0])
        raise ObservationsError(f"t: samples {k + 1} and {k + 2} share the time {float(obs.t[k]):.6f} s; the "
                                f"filters step from sample to sample (merge or drop one)")
    moved = obs.batched().to(dtype=dtype, device=device)
    q0 = quat_normalize(torch.as_tensor(q_est0).to(dtype=dtype, device=device)).reshape(1, 4)
    w0 = torch.as_tensor(omega0).to(dtype=dtype, device=device).reshape(1, 3)
    t = moved.t.to(dtype=dtype)
    increments = spin_increments(t, omega0=w0[0],
                                 inertia=torch.as_tensor(inertia, dtype=dtype, device=device)).unsqueeze(0)
    return Problem(obs=moved, q_est0=q0, sigma0=torch.full((1,), float(sigma0), dtype=dtype, device=device),
                   omega_est0=w0, increments_assumed=increments, R=moved.sigma ** 2, surface=None,
                   geometry=pass_geometry_of(obs))
