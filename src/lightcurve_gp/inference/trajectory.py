"""One light curve as a least-squares problem in the initial state ``x = [θ, ω_0, β]`` of many trajectories.

State of a row ``a`` (7 numbers): ``θ`` the rotation vector (rad) of the initial attitude about the row's anchor,
``q_0 = exp(θ) ⊗ q_ref,a``; ``ω_0`` the initial body rate (rad/s); ``β = ln ρ``. The prediction at sample ``k`` is
the magnitude of ``q(t_k) = Δ(t_k; ω_0) ⊗ q_0`` with the flux ``ρ D + S`` (:mod:`.forward`), the whitened
residual ``r_k = (ỹ_k − m_k) / σ_k``. A sample whose prediction has no flux gets the residual
``INVALID_RESIDUAL`` (a trajectory that hides a seen object is not a fit). Every row of a batch may have its own
anchor and rate; rows index the anchors, so a solver may pass any subset.

The Jacobian is exact (forward-differenced only in the rate propagation, :func:`.forward.rate_sensitivity`): the body
perturbation at ``t_k`` is ``A(Δ_k) J_l(θ) dθ + Φ_k dω``, with ``J_l`` the left Jacobian of the rotation vector
(``exp(θ + dθ) ≈ exp(J_l(θ) dθ) ⊗ exp(θ)``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import attitude_matrix, quat_mul, rotvec_to_quat
from lightcurve_gp.inference.forward import M_PER_LN, GroupRenderer, propagate_rates, rate_sensitivity
from lightcurve_gp.inference.zero_points import profile_zero_points
from lightcurve_gp.photometry.render import SUN_MAGNITUDE

__all__ = ["INVALID_RESIDUAL", "TrajectoryProblem", "left_jacobian", "profile_log_rho"]

#: the whitened residual of a sample whose prediction has no flux
INVALID_RESIDUAL = 100.0


def left_jacobian(theta: Tensor) -> Tensor:
    """``J_l(θ) (..., 3, 3)`` with ``exp(θ + dθ) = exp(J_l(θ) dθ) ⊗ exp(θ)`` to first order, for the toolkit's
    quaternion product (where ``A(exp(θ)) ≈ I − [θ×]``): ``I − a [θ×] + b [θ×]²``, ``a = (1 − cos φ)/φ²``,
    ``b = (φ − sin φ)/φ³``, ``φ = |θ|`` (series below 1e-4 rad)."""
    phi = torch.linalg.vector_norm(theta, dim=-1)[..., None, None]
    small = phi < 1e-4
    safe = torch.where(small, torch.ones_like(phi), phi)
    a = torch.where(small, 0.5 - phi ** 2 / 24.0, (1.0 - torch.cos(safe)) / safe ** 2)
    b = torch.where(small, 1.0 / 6.0 - phi ** 2 / 120.0, (safe - torch.sin(safe)) / safe ** 3)
    x, y, z = theta.unbind(-1)
    zero = torch.zeros_like(x)
    skew = torch.stack([torch.stack([zero, -z, y], -1), torch.stack([z, zero, -x], -1),
                        torch.stack([-y, x, zero], -1)], -2)
    eye = torch.eye(3, dtype=theta.dtype, device=theta.device)
    return eye - a * skew + b * (skew @ skew)


def profile_log_rho(D: Tensor, S: Tensor, *, y: Tensor, weight: Tensor, log_r2: Tensor, steps: int = 2) -> Tensor:
    """``β = ln ρ`` ``(...)`` that fits magnitudes ``y (K,)`` best for fluxes ``ρ D + S`` ``(..., K)`` (weights
    ``(K,)``, e.g. ``1/σ²``): the diffuse-only value, then ``steps`` Gauss–Newton steps with the specular part."""
    log_f = (SUN_MAGNITUDE - y) / M_PER_LN + log_r2  # the flux the data say, ln
    ok = (D > 0) & torch.isfinite(y)
    w = torch.where(ok, weight, torch.zeros((), dtype=D.dtype))
    beta = (w * torch.where(ok, log_f - torch.log(D.clamp_min(1e-300)), 0.0)).sum(-1) / w.sum(-1).clamp_min(1e-300)
    for _ in range(steps):
        rho_d = torch.exp(beta).unsqueeze(-1) * D
        f = rho_d + S
        r = torch.where(ok, log_f - torch.log(f.clamp_min(1e-300)), 0.0)
        g = torch.where(ok, rho_d / f.clamp_min(1e-300), 0.0)
        beta = beta + (w * g * r).sum(-1) / (w * g * g).sum(-1).clamp_min(1e-300)
    return beta


@dataclass(frozen=True)
class TrajectoryProblem:
    """A light curve and its forward model.

    Attributes:
        renderer: the facet groups under the light curve's geometry (per sample: one row per sample of ``times``).
        times: the sample times ``(K,)`` (s from the first sample, the epoch of ``q_0`` and ``ω_0``; increasing, any
            spacing: the propagation is closed form).
        y: magnitudes ``(K,)``; sigma: their 1σ ``(K,)`` (mag).
        inertia: principal moments ``(3,)`` (kg m²).
        anchors: the rows' reference attitudes ``q_ref (A, 4)``.
        zero_points: ``(K, C)`` indicator of the samples of each light curve whose zero point is unknown (relative
            photometry), or ``None``: each such curve's offset is profiled out of the residuals and the Jacobian
            (:mod:`.zero_points`), so the state stays ``[θ, ω_0, β]`` (β then sets the other curves' level).
    """

    renderer: GroupRenderer
    times: Tensor
    y: Tensor
    sigma: Tensor
    inertia: Tensor
    anchors: Tensor
    zero_points: Tensor | None = None

    def arc(self, n: int) -> "TrajectoryProblem":
        """The same problem on its first ``n`` samples."""
        n = min(int(n), self.times.shape[0])
        return replace(self, renderer=self.renderer.restrict(slice(0, n)), times=self.times[:n], y=self.y[:n],
                       sigma=self.sigma[:n], zero_points=None if self.zero_points is None else self.zero_points[:n])

    def window(self, start: int, stop: int) -> "TrajectoryProblem":
        """The same problem on samples ``start:stop``, their epoch (``t = 0``) at sample ``start``."""
        cut = slice(int(start), int(stop))
        return replace(self, renderer=self.renderer.restrict(cut), times=self.times[cut] - self.times[cut][0],
                       y=self.y[cut], sigma=self.sigma[cut],
                       zero_points=None if self.zero_points is None else self.zero_points[cut])

    def with_epoch(self, index: int) -> "TrajectoryProblem":
        """Every sample, the epoch of ``q_0`` and ``ω_0`` moved to sample ``index`` (earlier samples at ``t < 0``:
        the propagation is closed form in both directions)."""
        return replace(self, times=self.times - self.times[int(index)])

    def with_anchors(self, anchors: Tensor) -> "TrajectoryProblem":
        return replace(self, anchors=anchors)

    def initial_attitudes(self, x: Tensor, rows: Tensor) -> Tensor:
        """``q_0 = exp(θ) ⊗ q_ref`` ``(A, 4)`` of states ``x (A, 7)`` of rows ``rows (A,)``."""
        return quat_mul(rotvec_to_quat(x[:, :3]), self.anchors[rows])

    def _residual(self, phot, beta: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        rho_d = torch.exp(beta).unsqueeze(-1) * phot.D
        f = rho_d + phot.S
        return self._whitened(self.renderer.magnitude(f)), rho_d, f

    def _whitened(self, m: Tensor, jacobian: Tensor | None = None) -> Tensor | tuple[Tensor, Tensor]:
        """``(ỹ − m)/σ`` with the relative curves' offsets profiled out (and ``jacobian`` projected with it), then
        :data:`INVALID_RESIDUAL` where ``m`` is not finite."""
        r = (self.y - m) / self.sigma
        if self.zero_points is not None:
            r, _, jacobian = profile_zero_points(r, 1.0 / self.sigma, self.zero_points, jacobian=jacobian)
        r = torch.where(torch.isfinite(m), r, torch.full_like(r, INVALID_RESIDUAL))
        return r if jacobian is None else (r, jacobian)

    def offsets(self, x: Tensor, rows: Tensor) -> Tensor | None:
        """The relative light curves' fitted magnitude offsets ``(A, C)`` (added to the prediction) of states
        ``x (A, 7)``, or ``None`` without relative curves."""
        if self.zero_points is None:
            return None
        delta = propagate_rates(x[:, 3:6], inertia=self.inertia, times=self.times)
        phot = self.renderer(quat_mul(delta, self.initial_attitudes(x, rows).unsqueeze(-2)))
        m = self.renderer.magnitude(torch.exp(x[:, 6]).unsqueeze(-1) * phot.D + phot.S)
        return profile_zero_points((self.y - m) / self.sigma, 1.0 / self.sigma, self.zero_points)[1]

    def __call__(self, x: Tensor, rows: Tensor) -> Tensor:
        """:meth:`residual`: the problem is the solver's residual function (with ``jacobian="provided"``)."""
        return self.residual(x, rows)

    def residual(self, x: Tensor, rows: Tensor) -> Tensor:
        """Whitened residuals ``(A, K)`` of states ``x (A, 7)``."""
        delta = propagate_rates(x[:, 3:6], inertia=self.inertia, times=self.times)  # (A, K, 4)
        q = quat_mul(delta, self.initial_attitudes(x, rows).unsqueeze(-2))
        return self._residual(self.renderer(q), x[:, 6])[0]

    def linearize(self, x: Tensor, rows: Tensor) -> tuple[Tensor, Tensor]:
        """Residuals ``(A, K)`` and their Jacobian ``∂r/∂x`` ``(A, K, 7)`` (module docstring)."""
        delta, phi = rate_sensitivity(x[:, 3:6], inertia=self.inertia, times=self.times)
        q = quat_mul(delta, self.initial_attitudes(x, rows).unsqueeze(-2))
        phot = self.renderer(q, gradient=True)
        rho_d = torch.exp(x[:, 6]).unsqueeze(-1) * phot.D
        f = rho_d + phot.S
        m = self.renderer.magnitude(f)
        ok = torch.isfinite(m)
        scale = torch.where(ok, M_PER_LN / (f.clamp_min(1e-300) * self.sigma), 0.0)  # ∂r/∂f · f/… : r = (y − m)/σ
        grad = (torch.exp(x[:, 6])[:, None, None] * phot.dD + phot.dS) * scale.unsqueeze(-1)  # ∂r/∂δ_k (A, K, 3)
        rot = attitude_matrix(delta)  # (A, K, 3, 3)
        j_theta = torch.einsum("aki,akij->akj", grad, rot)
        j_theta = torch.einsum("akj,ajl->akl", j_theta, left_jacobian(x[:, :3]))
        j_omega = torch.einsum("aki,akij->akj", grad, phi)
        j_beta = (rho_d * scale).unsqueeze(-1)
        return self._whitened(m, torch.cat([j_theta, j_omega, j_beta], -1))

    def grid_cost(self, omega: Tensor, q0: Tensor, *, chunk: int = 1 << 18) -> tuple[Tensor, Tensor]:
        """Costs ``½ Σ r²`` ``(R, A)`` and profiled ``β`` ``(R, A)`` of every rate ``omega (R, 3)`` with every initial
        attitude ``q0 (A, 4)``: ``R`` propagations and ``R·A`` light curves (module docstring of :mod:`.forward`)."""
        delta = propagate_rates(omega, inertia=self.inertia, times=self.times)  # (R, K, 4)
        K, A = delta.shape[1], q0.shape[0]
        per = max(1, chunk // (K * A))
        weight = self.sigma ** -2
        costs, betas = [], []
        for part in delta.split(per):
            q = quat_mul(part[:, None], q0[None, :, None])  # (r, A, K, 4)
            phot = self.renderer(q)
            beta = profile_log_rho(phot.D, phot.S, y=self.y, weight=weight, log_r2=self.renderer.log_r2)
            rho_d = torch.exp(beta).unsqueeze(-1) * phot.D
            res = self._whitened(self.renderer.magnitude(rho_d + phot.S))
            costs.append(0.5 * res.square().sum(-1))
            betas.append(beta)
        return torch.cat(costs), torch.cat(betas)

    @property
    def samples(self) -> int:
        return int(self.times.shape[0])
