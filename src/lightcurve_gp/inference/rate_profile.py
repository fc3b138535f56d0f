"""The rate profile of a slow tumbler's family: how well the light curve fixes the rate's magnitude.

Below one turn over the arc (:func:`~.probe_starts.below_one_turn`) the periodogram has no resolution and the
posterior *may* be a ridge along the rate: states at other rates that fit as well once the attitude and the axis
follow. Whether it is one is a property of the light curve, not of the turn count (a box-wing turning 325° in
600 s at 0.05 mag fixes its rate to 0.3 %), and the Laplace covariance at one point of a ridge cannot say: it is
local. The profile measures it.

**The profile.** For rate magnitudes ``r_j = f_j · |ω_f|`` (:data:`PROFILE_FACTORS`, inside the rate range) the
family is restarted at ``r_j`` about its own axis (keeping its attitude at the middle of the arc,
:func:`~.probe_starts.restarted_at`) and polished by Levenberg–Marquardt with the magnitude pinned: one more
residual, ``(|ω| − r_j) / (PIN_REL · r_j)``, which leaves the axis, the attitude and ln ρ free and holds ``|ω|`` at
``r_j`` to a few ``PIN_REL``. The profile is the data cost ``c_j = ½ Σ r²`` of each point (the pin's own term left out),
``Δ_j = c_j − min c``.

**What it reports** (:class:`RateProfile`):

* the **rate interval**: the rates whose ``Δ ≤`` :data:`PROFILE_CUT_NATS` (``χ²₁``'s 95 % point over 2: a 95 %
  likelihood-ratio interval of one parameter), the outer crossings interpolated linearly in ``ln r``; an end at the
  grid's last point is *open* (the ridge goes on);
* **resolved**: the interval lies within the tolerance of "right" (:data:`~.families.RIGHT_RATE_REL`) about the
  family's rate — the rate is fixed, the family is not on a ridge, whatever its turn count;
* the **share**: the posterior mass of the rates within that tolerance of the family's, under
  ``p(ln r) ∝ exp(−Δ(ln r)) · r³`` (the uniform prior over the rate ball, ``p(r) ∝ r²``; ``Δ`` interpolated
  linearly in ``ln r``; the other directions' Laplace volume taken as constant along the profile).
  :func:`ridge_rule` caps the family's probability of being right at its weight times this share: on a ridge the
  Gaussian mass about one point can claim a tolerance the profile does not hold.

A profile point below the family (``Δ < 0`` at another rate) is a better state the search did not keep:
:mod:`.answer` polishes it freely and joins it to the solutions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.inference.families import RIGHT_RATE_REL
from lightcurve_gp.inference.probe_starts import restarted_at
from lightcurve_gp.inference.solver import LeastSquaresOptions, batch_least_squares
from lightcurve_gp.inference.trajectory import TrajectoryProblem

__all__ = ["PROFILE_FACTORS", "PROFILE_CUT_NATS", "PROFILE_ITERATIONS", "PIN_REL", "RateProfile", "rate_profile",
           "profile_interval", "profile_share", "capped_p_right", "ridge_rule"]

#: the profile's rate factors: 0.5–2 in steps of 2^(1/8) (9 %), and 0.5–7 % about the family's own rate
PROFILE_FACTORS = tuple(sorted({round(2.0 ** (k / 8), 12) for k in range(-8, 9)}
                               | {1.0 + s * d for s in (-1, 1) for d in (0.005, 0.01, 0.02, 0.03, 0.05, 0.07)}))
#: a profile point within this many nats of the profile's minimum is inside the rate interval (χ²₁ 0.95 / 2)
PROFILE_CUT_NATS = 1.92
#: Levenberg–Marquardt iterations of each profile point
PROFILE_ITERATIONS = 30
#: the pin's 1σ on the rate's magnitude, as a share of it
PIN_REL = 1e-4


@dataclass(frozen=True)
class RateProfile:
    """A family's rate profile (module docstring).

    Attributes:
        rate_deg_s: the family's own rate ``|ω_f|`` (°/s).
        rates_deg_s: the polished points' rates ``(P,)`` (°/s, increasing); cost: their data cost ``½ Σ r²``
            ``(P,)`` (nats); family_cost: the family's own cost.
        q0: the points' initial attitudes ``(P, 4)``; x: their states ``(P, 7)`` (``θ = 0``, ω in rad/s, ln ρ).
        interval_deg_s: the 95 % rate interval ``(lo, hi)`` (°/s); open: whether each end reached the grid's end.
        resolved: the interval within :data:`~.families.RIGHT_RATE_REL` of ``rate_deg_s``.
        share: the profile's posterior mass within that tolerance of ``rate_deg_s``.
    """

    rate_deg_s: float
    rates_deg_s: Tensor
    cost: Tensor
    family_cost: float
    q0: Tensor
    x: Tensor
    interval_deg_s: tuple[float, float]
    open: tuple[bool, bool]
    resolved: bool
    share: float

    @property
    def gain_nats(self) -> float:
        """By how much the profile's best point fits better than the family (nats, ≥ 0)."""
        return max(0.0, self.family_cost - float(self.cost.min()))

    def as_dict(self) -> dict:
        return {"rate_deg_s": self.rate_deg_s, "rates_deg_s": self.rates_deg_s.tolist(),
                "delta_nats": (self.cost - self.cost.min()).tolist(), "interval_deg_s": list(self.interval_deg_s),
                "open": list(self.open), "resolved": self.resolved, "share": self.share,
                "gain_nats": self.gain_nats}


@dataclass(frozen=True)
class _Pinned:
    """``problem``'s whitened residuals ``(A, K)`` and one more column, ``(|ω| − target) / (PIN_REL · target)``,
    with their Jacobian (the solver's ``jacobian="provided"``); ``target (P,)`` (rad/s) per row."""

    problem: TrajectoryProblem
    target: Tensor

    def __call__(self, x: Tensor, rows: Tensor) -> Tensor:
        return torch.cat([self.problem.residual(x, rows), self._pin(x, rows)[0]], -1)

    def _pin(self, x: Tensor, rows: Tensor) -> tuple[Tensor, Tensor]:
        size = torch.linalg.vector_norm(x[:, 3:6], dim=-1)
        scale = PIN_REL * self.target[rows]
        jac = torch.zeros_like(x)
        jac[:, 3:6] = x[:, 3:6] / (size * scale)[:, None]
        return ((size - self.target[rows]) / scale)[:, None], jac[:, None, :]

    def linearize(self, x: Tensor, rows: Tensor) -> tuple[Tensor, Tensor]:
        r, jac = self.problem.linearize(x, rows)
        pin, pin_jac = self._pin(x, rows)
        return torch.cat([r, pin], -1), torch.cat([jac, pin_jac], -2)


def _pinned(problem: TrajectoryProblem, q0: Tensor, x: Tensor, target: Tensor, *,
            iterations: int) -> tuple[Tensor, Tensor]:
    """States ``x (P, 7)`` about ``q0 (P, 4)`` polished with ``|ω|`` pinned to ``target (P,)`` (rad/s); the polished
    initial attitudes and states (``θ = 0``)."""
    tolerance = torch.tensor([1e-7] * 3 + [1e-10] * 3 + [1e-6], dtype=x.dtype, device=x.device)
    options = LeastSquaresOptions(method="levenberg_marquardt", iterations=iterations, jacobian="provided",
                                  tolerance=tolerance, covariance="none")
    res = batch_least_squares(_Pinned(problem.with_anchors(q0), target), x, options=options)
    rows = torch.arange(x.shape[0], device=x.device)
    anchors = problem.with_anchors(q0).initial_attitudes(res.x, rows)
    return anchors, torch.cat([torch.zeros_like(res.x[:, :3]), res.x[:, 3:]], -1)


def profile_interval(log_rate: Tensor, delta: Tensor, *, cut: float = PROFILE_CUT_NATS
                     ) -> tuple[float, float, bool, bool]:
    """The interval ``(lo, hi)`` (units of ``exp(log_rate)``) of the points ``log_rate (P,)`` (increasing) whose
    ``delta (P,) ≤ cut``, the outer crossings interpolated linearly in ``log_rate``, and whether each end is the
    grid's (open)."""
    inside = torch.nonzero(delta <= cut).squeeze(-1)
    a, b = int(inside.min()), int(inside.max())

    def crossing(i: int, j: int) -> float:  # i inside, j outside
        t = (cut - float(delta[i])) / (float(delta[j]) - float(delta[i]))
        return math.exp(float(log_rate[i]) + t * (float(log_rate[j]) - float(log_rate[i])))

    last = log_rate.shape[0] - 1
    lo = math.exp(float(log_rate[0])) if a == 0 else crossing(a, a - 1)
    hi = math.exp(float(log_rate[last])) if b == last else crossing(b, b + 1)
    return lo, hi, a == 0, b == last


def profile_share(log_rate: Tensor, delta: Tensor, *, rate: float, rate_rel: float = RIGHT_RATE_REL,
                  points: int = 4001) -> float:
    """The mass of ``p(ln r) ∝ exp(−Δ(ln r)) r³`` (``Δ`` linear between the points ``log_rate (P,)``, increasing,
    of ``delta (P,)``) over the rates within ``rate_rel`` of ``rate`` (``|r − rate| < rate_rel · r``), on a grid
    of ``points`` over the profile's span."""
    grid = torch.linspace(float(log_rate[0]), float(log_rate[-1]), points, dtype=torch.float64)
    lr, d = log_rate.detach().to(torch.float64).cpu(), delta.detach().to(torch.float64).cpu()
    k = torch.searchsorted(lr, grid).clamp(1, lr.shape[0] - 1)
    t = (grid - lr[k - 1]) / (lr[k] - lr[k - 1])
    value = d[k - 1] + t * (d[k] - d[k - 1])
    log_density = -value + 3.0 * grid
    density = torch.exp(log_density - log_density.max())
    r = torch.exp(grid)
    near = (r - rate).abs() < rate_rel * r
    return float(density[near].sum() / density.sum())


def rate_profile(problem: TrajectoryProblem, *, q0: Tensor, omega0: Tensor, log_rho: Tensor, span_s: float,
                 rate_range_deg_s: tuple[float, float], factors=PROFILE_FACTORS,
                 iterations: int = PROFILE_ITERATIONS) -> RateProfile:
    """The rate profile (module docstring) of the family ``q0 (4,)``, ``omega0 (3,)`` (rad/s), ``log_rho ()``
    of ``problem``, over ``factors`` of its rate inside ``rate_range_deg_s`` (°/s; widened to the family's own rate
    when it lies outside); ``span_s`` the arc (s), whose middle keeps the restarts' attitude.

    Raises:
        ValueError: fewer than two factors inside the range (no profile to read).
    """
    rate = float(torch.linalg.vector_norm(omega0))
    lo, hi = (math.radians(v) for v in rate_range_deg_s)
    lo, hi = min(lo, rate), max(hi, rate)  # a family outside the range is profiled on its side of it
    scale = torch.tensor([f for f in factors if lo <= f * rate <= hi], dtype=omega0.dtype, device=omega0.device)
    omega = omega0[None, None, :] * scale[None, :, None]
    q, x = restarted_at(omega, q0=q0[None], omega0=omega0[None], log_rho=log_rho.reshape(1), span_s=span_s)
    if scale.numel() < 2:
        raise ValueError(f"rate profile: {scale.numel()} of the factors put the rate {math.degrees(rate):.4g} deg/s "
                         f"inside {rate_range_deg_s} deg/s; it needs two")
    q, x = _pinned(problem, q, x, scale * rate, iterations=iterations)
    rows = torch.arange(x.shape[0], device=x.device)
    r = problem.with_anchors(q).residual(x, rows)
    cost = 0.5 * torch.where(torch.isfinite(r), r, torch.zeros_like(r)).pow(2).sum(-1)
    cost = torch.where(torch.isfinite(cost), cost, torch.full_like(cost, math.inf))
    family = problem.with_anchors(q0[None]).residual(torch.cat([torch.zeros(3).to(omega0), omega0,
                                                                log_rho.reshape(1)])[None], rows[:1])
    family_cost = float(0.5 * family.pow(2).sum())
    rates = torch.rad2deg(torch.linalg.vector_norm(x[:, 3:6], dim=-1))
    order = torch.argsort(rates)
    rates, cost, q, x = rates[order], cost[order], q[order], x[order]
    delta = cost - torch.minimum(cost.min(), torch.tensor(family_cost).to(cost))
    log_rate = torch.log(rates)
    a, b, open_lo, open_hi = profile_interval(log_rate, delta)
    own = math.degrees(rate)
    resolved = (not (open_lo or open_hi)) and abs(a - own) < RIGHT_RATE_REL * a and abs(b - own) < RIGHT_RATE_REL * b
    return RateProfile(rate_deg_s=own, rates_deg_s=rates, cost=cost, family_cost=family_cost, q0=q, x=x,
                       interval_deg_s=(a, b), open=(open_lo, open_hi), resolved=resolved,
                       share=profile_share(log_rate, delta, rate=own))


def capped_p_right(share: float, *, weight: float, p_right: float) -> float:
    """A family's probability of being right capped by its profile's share within the tolerance:
    ``min(p_right, weight · share)`` (a kept profile's ``share`` is enough)."""
    return min(p_right, weight * share)


def ridge_rule(profile: RateProfile, *, weight: float, p_right: float) -> tuple[float, bool]:
    """The family's probability of being right capped by its profile (:func:`capped_p_right`) and whether it is on
    a ridge (its rate not resolved)."""
    return capped_p_right(profile.share, weight=weight, p_right=p_right), not profile.resolved
