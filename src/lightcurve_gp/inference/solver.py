"""Batched nonlinear least squares: Gauss–Newton and Levenberg–Marquardt over ``B`` independent problems at once.

Problem ``b`` has the state ``x_b (n,)``, residuals ``r_b(x_b) (m,)`` of variance ``v_b`` and optionally a Gaussian
prior ``x_b ~ N(μ_b, Λ_b⁻¹)``. The solver minimises, per problem,

    cost(x) = ½ Σ_k r_k(x)² / v + ½ (x − μ)ᵀ Λ (x − μ)

(the negative log posterior up to a constant). For a measurement ``y`` with standard deviation ``σ`` and a
prediction ``h(x)`` either ``r = (y − h(x)) / σ`` with ``v = 1`` (whitened; per-sample ``σ`` allowed) or
``r = y − h(x)`` with ``v = σ²`` (one noise level per problem). A non-finite residual (a missing sample, NaN) is left
out: of the cost, and of the normal equations together with its Jacobian row. ``invalid_residual`` instead charges
every non-finite residual as that value in the cost, so a step into a region where the model fails is rejected.

Each iteration linearises the active problems (:func:`~lightcurve_gp.inference.jacobian.jacobian`) and solves the
normal equations ``(JᵀJ/v + Λ) dx = −(Jᵀr/v + Λ(x − μ))``:

* ``"gauss_newton"`` takes the step; with ``halvings > 0`` it backtracks, taking the longest ``dx / 2^k``
  (``k ≤ halvings``) that does not raise the cost (no step if none);
* ``"levenberg_marquardt"`` solves with Marquardt's scaled damping ``H + λ diag(H)``, ``H = JᵀJ/v + Λ``, takes the
  step when it lowers the cost (then ``λ ← λ / damping_down``), else keeps the state (``λ ← λ · damping_up``);
  ``λ`` is per problem.

A problem stops (and costs nothing more) once every component of its proposed step is within ``tolerance``
(a number or one per coordinate, in the units of ``x``; ``inf`` ignores a coordinate), or, with Levenberg–Marquardt,
once its damping reaches ``damping_max`` (no step lowers the cost any more); both count as converged. A failed solve
(a singular matrix) stops a Gauss–Newton problem unconverged and counts as a rejected Levenberg–Marquardt step. The
Laplace approximation of the posterior covariance is ``H⁻¹`` at the solution (NaN where ``H`` is singular).

Three options exist to reproduce the first batch MAP solvers bit for bit (:mod:`.attitude`, :mod:`.spin`):
``stop_together`` (all problems iterate until all stop), ``first_column`` (residual columns computed but dropped
after differencing) and ``covariance="last_linearization"``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

from lightcurve_gp.inference.jacobian import JacobianMethod, ResidualFunction, jacobian

__all__ = ["GaussianPrior", "LeastSquaresOptions", "LeastSquaresResult", "batch_least_squares", "least_squares_cost"]


@dataclass(frozen=True)
class GaussianPrior:
    """``x ~ N(mean, precision⁻¹)`` for every problem.

    Attributes:
        mean: ``(B, n)`` per problem or ``(n,)`` shared (units of ``x``).
        precision: the information matrix ``Λ``, ``(B, n, n)`` per problem or ``(n, n)`` shared (inverse units²).
        diagonal: ``Λ``'s diagonal, shaped like ``mean``, when ``Λ`` is diagonal (:meth:`independent`): the prior's
            terms are then formed elementwise.
    """

    mean: Tensor
    precision: Tensor
    diagonal: Tensor | None = None

    def __post_init__(self) -> None:
        n = self.mean.shape[-1]
        if self.mean.ndim not in (1, 2) or self.precision.ndim != self.mean.ndim + 1 \
                or self.precision.shape[-2:] != (n, n):
            raise ValueError(f"prior: mean {tuple(self.mean.shape)} and precision {tuple(self.precision.shape)} must "
                             "be (n,) and (n, n), or (B, n) and (B, n, n)")

    @classmethod
    def independent(cls, mean: Tensor, precision: Tensor) -> "GaussianPrior":
        """Independent coordinates: ``precision`` the diagonal of ``Λ``, ``(B, n)`` or ``(n,)`` (broadcast against
        ``mean``)."""
        diagonal = precision.expand_as(mean)
        return cls(mean, torch.diag_embed(diagonal), diagonal)

    @classmethod
    def from_sqrt_information(cls, mean: Tensor, root: Tensor) -> "GaussianPrior":
        """``Λ = RᵀR`` from a square root ``R`` ``(B, n, n)`` or ``(n, n)`` (e.g. the upper Cholesky factor): the
        prior's whitened residual is ``R (x − mean)``."""
        return cls(mean, root.mT @ root)

    def _rows(self, value: Tensor, rows: Tensor, per_problem_ndim: int) -> Tensor:
        if value.ndim == per_problem_ndim:
            return value[rows]
        return value.expand(rows.shape[0], *value.shape)

    def information(self, rows: Tensor) -> Tensor:
        """``Λ`` of the problems ``rows (A,)``: ``(A, n, n)``."""
        return self._rows(self.precision, rows, 3)

    def gradient(self, x: Tensor, rows: Tensor) -> Tensor:
        """``Λ (x − μ)`` ``(A, n)`` of states ``x (A, n)`` of the problems ``rows``."""
        delta = x - self._rows(self.mean, rows, 2)
        if self.diagonal is not None:
            return delta * self._rows(self.diagonal, rows, 2)
        return (self.information(rows) @ delta.unsqueeze(-1)).squeeze(-1)

    def quadratic(self, x: Tensor, rows: Tensor) -> Tensor:
        """``(x − μ)ᵀ Λ (x − μ)`` ``(A,)`` of states ``x (A, n)`` of the problems ``rows``."""
        delta = x - self._rows(self.mean, rows, 2)
        if self.diagonal is not None:
            return (delta.pow(2) * self._rows(self.diagonal, rows, 2)).sum(-1)
        return (delta * (self.information(rows) @ delta.unsqueeze(-1)).squeeze(-1)).sum(-1)


@dataclass(frozen=True)
class LeastSquaresOptions:
    """How :func:`batch_least_squares` iterates (module docstring).

    Attributes:
        method: ``"gauss_newton"`` or ``"levenberg_marquardt"``.
        iterations: linearisations per problem at most.
        tolerance: a problem stops once every ``|dx_i| ≤ tolerance_i``: a number or ``(n,)`` (units of ``x``).
        jacobian: ``"forward_mode"``, ``"central"`` or ``"forward_difference"``
            (:mod:`~lightcurve_gp.inference.jacobian`); ``step``: the finite-difference step, a number or ``(n,)``.
        halvings: Gauss–Newton backtracking: step halvings per iteration at most (0: the plain step).
        damping: Levenberg–Marquardt's initial ``λ``; ``damping_down``, ``damping_up`` its factors after an accepted
            and a rejected step; ``damping_max`` where a problem stops.
        invalid_residual: what a non-finite residual counts in the cost (whitened units); ``None``: left out.
        covariance: ``"solution"``: ``(JᵀJ/v + Λ)⁻¹`` linearised at the returned state (one more Jacobian);
            ``"last_linearization"``: at the state of each problem's last iteration (before its last step, no extra
            evaluation); ``"none"``.
        stop_together: every problem iterates until all stop in the same iteration (one batched solve without the
            active mask, as the first batch MAP did); the default stops each problem on its own.
        first_column: residual columns before this one are computed but are not data (e.g. the prediction of a
            sample that sets a prior only); they are dropped after differencing. With finite differences the
            products then see the memory layout the first batch MAP had, which reproduces its numbers bit for bit.
        chunk: at most this many problems per residual call (``None``: all at once); bounds the memory of a large
            batch (a finite-difference Jacobian evaluates ``(2n + 1) · chunk`` or ``(n + 1) · chunk`` rows).
    """

    method: Literal["gauss_newton", "levenberg_marquardt"] = "levenberg_marquardt"
    iterations: int = 20
    tolerance: float | Tensor = 1e-9
    jacobian: JacobianMethod = "central"
    step: float | Tensor = 1e-6
    halvings: int = 0
    damping: float = 1e-3
    damping_down: float = 3.0
    damping_up: float = 4.0
    damping_max: float = 1e6
    invalid_residual: float | None = None
    covariance: Literal["solution", "last_linearization", "none"] = "solution"
    stop_together: bool = False
    first_column: int = 0
    chunk: int | None = None

    def __post_init__(self) -> None:
        if self.method not in ("gauss_newton", "levenberg_marquardt"):
            raise ValueError(f"method: {self.method!r} is not 'gauss_newton' or 'levenberg_marquardt'")
        if self.covariance not in ("solution", "last_linearization", "none"):
            raise ValueError(f"covariance: {self.covariance!r} is not 'solution', 'last_linearization' or 'none'")
        if self.iterations < 0 or self.halvings < 0:
            raise ValueError(f"iterations: {self.iterations}, halvings: {self.halvings} must be >= 0")
        if self.chunk is not None and self.chunk < 1:
            raise ValueError(f"chunk: {self.chunk} must be >= 1 (or None)")


@dataclass(frozen=True)
class LeastSquaresResult:
    """What :func:`batch_least_squares` returns for ``B`` problems of ``n`` states.

    Attributes:
        x: the states ``(B, n)``.
        cost: ``½ |r|²/v + ½ (x − μ)ᵀ Λ (x − μ)`` at ``x`` ``(B,)``.
        iterations: linearisations each problem took ``(B,)`` (int64).
        converged: whether it stopped before the iteration limit ``(B,)`` (bool).
        information: ``JᵀJ/v + Λ`` ``(B, n, n)`` where the covariance was taken (``None`` with
            ``covariance="none"``).
        covariance: its inverse, the Laplace approximation of the posterior covariance ``(B, n, n)`` (units of
            ``x`` squared; NaN where singular), or ``None``.
    """

    x: Tensor
    cost: Tensor
    iterations: Tensor
    converged: Tensor
    information: Tensor | None
    covariance: Tensor | None


def _per_row(variance: float | Tensor, rows: Tensor) -> float | Tensor:
    """The residual variance of the problems ``rows``: a number as given, ``(B,)`` → ``(A, 1)``."""
    return variance[rows].unsqueeze(-1) if isinstance(variance, Tensor) else variance


def least_squares_cost(r: Tensor, x: Tensor, rows: Tensor, *, prior: GaussianPrior | None = None,
                       variance: float | Tensor = 1.0, invalid_residual: float | None = None) -> Tensor:
    """``½ (Σ r² / v + (x − μ)ᵀ Λ (x − μ))`` ``(A,)`` of residuals ``r (A, m)`` at states ``x (A, n)`` of the
    problems ``rows (A,)``; ``v`` the residual variance (:func:`batch_least_squares`), non-finite residuals as the
    module docstring says."""
    fill = 0.0 if invalid_residual is None else float(invalid_residual)
    r = torch.where(torch.isfinite(r), r, torch.full_like(r, fill))
    total = ((r * r) / _per_row(variance, rows)).sum(-1) if isinstance(variance, Tensor) else \
        (r * r).sum(-1) / variance
    if prior is not None:
        total = total + prior.quadratic(x, rows)
    return 0.5 * total


def _normal_equations(r: Tensor, J: Tensor, x: Tensor, rows: Tensor, prior: GaussianPrior | None,
                      variance: float | Tensor, first: int = 0) -> tuple[Tensor, Tensor]:
    """``JᵀJ / v + Λ`` ``(A, n, n)`` and ``−(Jᵀr / v + Λ(x − μ))`` ``(A, n)`` from residual columns ``first …``,
    non-finite residual rows left out."""
    ok = torch.isfinite(r) & torch.isfinite(J).all(-1)
    r, J = torch.where(ok, r, 0.0)[:, first:], torch.where(ok.unsqueeze(-1), J, 0.0)[:, first:]
    v = _per_row(variance, rows)
    H = J.mT @ J / (v.unsqueeze(-1) if isinstance(v, Tensor) else v)
    g = (J.mT @ r.unsqueeze(-1)).squeeze(-1) / v
    if prior is None:
        return H, -g
    return H + prior.information(rows), -g - prior.gradient(x, rows)


class _Iteration:
    """The fixed parts of one solve: the residual, the prior, the options and the per-coordinate tolerance."""

    def __init__(self, residual: ResidualFunction, prior: GaussianPrior | None, variance: float | Tensor,
                 options: LeastSquaresOptions, like: Tensor) -> None:
        self.residual, self.prior, self.variance, self.options = residual, prior, variance, options
        self.tolerance = torch.as_tensor(options.tolerance, dtype=like.dtype, device=like.device).expand(like.shape[-1])

    def chunks(self, x: Tensor, rows: Tensor) -> zip:
        """``(x, rows)`` in pieces of at most ``options.chunk`` problems."""
        size = self.options.chunk or max(1, rows.shape[0])
        return zip(x.split(size), rows.split(size))

    def evaluate(self, x: Tensor, rows: Tensor) -> Tensor:
        """Residuals ``(A, m)`` of states ``x (A, n)`` of problems ``rows``, chunk by chunk."""
        return torch.cat([self.residual(xc, rc) for xc, rc in self.chunks(x, rows)])

    def cost(self, x: Tensor, rows: Tensor, r: Tensor | None = None) -> Tensor:
        """Cost ``(A,)`` of states ``x (A, n)`` of problems ``rows`` (``r``: their residuals, if known)."""
        r = self.evaluate(x, rows) if r is None else r
        return least_squares_cost(r[:, self.options.first_column:], x, rows, prior=self.prior, variance=self.variance,
                                  invalid_residual=self.options.invalid_residual)

    def linearize(self, x: Tensor, rows: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Residuals ``(A, m)``, ``JᵀJ/v + Λ`` ``(A, n, n)`` and the right-hand side ``(A, n)`` at ``x (A, n)``."""
        o = self.options
        parts = [jacobian(self.residual, xc, rc, method=o.jacobian, step=o.step) for xc, rc in self.chunks(x, rows)]
        r, J = (parts[0] if len(parts) == 1 else (torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])))
        H, g = _normal_equations(r, J, x, rows, self.prior, self.variance, self.options.first_column)
        return r, H, g

    def small(self, dx: Tensor) -> Tensor:
        """Whether every component of the steps ``dx (A, n)`` is within the tolerance ``(A,)``."""
        return (dx.abs() <= self.tolerance).all(-1)

    def backtrack(self, x: Tensor, dx: Tensor, rows: Tensor, cost_now: Tensor) -> Tensor:
        """Per problem the longest ``dx / 2^k`` (``k ≤ halvings``) that does not raise the cost; zero if none."""
        out, pending = torch.zeros_like(dx), torch.ones(x.shape[0], dtype=torch.bool, device=x.device)
        for k in range(self.options.halvings + 1):
            idx = pending.nonzero().squeeze(-1)
            trial = dx[idx] / 2 ** k
            ok = self.cost(x[idx] + trial, rows[idx]) <= cost_now[idx]
            out[idx[ok]], pending[idx[ok]] = trial[ok], False
            if not bool(pending.any()):
                break
        return out


def _gauss_newton(it: _Iteration, x: Tensor, rows: Tensor, r: Tensor, H: Tensor, g: Tensor
                  ) -> tuple[Tensor, Tensor, Tensor]:
    """One Gauss–Newton step of the problems ``rows``: their new states ``(A, n)``, stop and converged flags."""
    dx, info = torch.linalg.solve_ex(H, g)
    failed = info != 0
    dx = torch.where(failed.unsqueeze(-1), torch.zeros_like(dx), dx)
    if it.options.halvings:
        dx = it.backtrack(x, dx, rows, it.cost(x, rows, r))
    converged = it.small(dx) & ~failed
    return x + dx, converged | failed, converged


def _levenberg_marquardt(it: _Iteration, x: Tensor, rows: Tensor, H: Tensor, g: Tensor, cost: Tensor,
                         damping: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """One Levenberg–Marquardt trial of the problems ``rows``: new states, costs, dampings and stop flags (a stop
    is a convergence: the step is small or no step lowers the cost)."""
    o = it.options
    scaled = H + torch.diag_embed(damping.unsqueeze(-1) * torch.diagonal(H, dim1=-2, dim2=-1))
    dx, info = torch.linalg.solve_ex(scaled, g)
    failed = info != 0
    dx = torch.where(failed.unsqueeze(-1), torch.zeros_like(dx), dx)
    trial = it.cost(x + dx, rows)
    better = (trial < cost) & ~failed
    x = torch.where(better.unsqueeze(-1), x + dx, x)
    cost = torch.where(better, trial, cost)
    damping = torch.where(better, damping / o.damping_down, damping * o.damping_up)
    stop = (it.small(dx) & ~failed) | (damping >= o.damping_max)
    return x, cost, damping, stop


def batch_least_squares(residual: ResidualFunction, x0: Tensor, *, prior: GaussianPrior | None = None,
                        variance: float | Tensor = 1.0,
                        options: LeastSquaresOptions = LeastSquaresOptions()) -> LeastSquaresResult:
    """Minimise ``½ |r(x)|²/v + ½ (x − μ)ᵀ Λ (x − μ)`` for ``B`` problems at once (module docstring).

    Args:
        residual: ``residual(x (A, n), rows (A,)) → (A, m)`` residuals of the problems ``rows`` (see
            :mod:`~lightcurve_gp.inference.jacobian`); NaN marks a left-out sample.
        x0: starting states ``(B, n)`` (not modified).
        prior: the Gaussian prior, or ``None`` (the data alone).
        variance: the residuals' variance ``v``, a number or one per problem ``(B,)``: the data term is
            ``½ Σ r² / v``. 1 (the default) for whitened residuals; the measurement variance (e.g. mag²) for
            residuals ``y − h(x)`` that share one noise level, which keeps the differences of ``h`` unscaled.
        options: the method, stopping rule, Jacobian and covariance (:class:`LeastSquaresOptions`).

    Returns:
        :class:`LeastSquaresResult`.
    """
    B, n = x0.shape
    it, x = _Iteration(residual, prior, variance, options, x0), x0.clone()
    every = torch.arange(B, device=x0.device)
    active = torch.ones(B, dtype=torch.bool, device=x0.device)
    iterations = torch.zeros(B, dtype=torch.int64, device=x0.device)
    converged = torch.zeros_like(active)
    information = torch.full((B, n, n), torch.nan, dtype=x0.dtype, device=x0.device)
    lm = options.method == "levenberg_marquardt"
    cost = it.cost(x, every) if lm else None
    damping = torch.full((B,), options.damping, dtype=x0.dtype, device=x0.device)
    # Levenberg–Marquardt keeps a problem's normal equations while its trials fail (its state has not moved):
    # only the damping changes, so they are not linearised again
    gradient = torch.zeros(B, n, dtype=x0.dtype, device=x0.device)
    stale = torch.ones(B, dtype=torch.bool, device=x0.device)
    for _ in range(options.iterations):
        rows = active.nonzero().squeeze(-1)
        if rows.numel() == 0:
            break
        if lm:
            fresh = rows[stale[rows]]
            if fresh.numel():
                _, information[fresh], gradient[fresh] = it.linearize(x[fresh], fresh)
            H, g = information[rows], gradient[rows]
            iterations[rows] += 1
            before = cost[rows]
            x[rows], cost[rows], damping[rows], stop = _levenberg_marquardt(it, x[rows], rows, H, g, before,
                                                                           damping[rows])
            stale[rows] = cost[rows] < before
            done = stop
        else:
            r, H, g = it.linearize(x[rows], rows)
            information[rows], iterations[rows] = H, iterations[rows] + 1
            x[rows], stop, done = _gauss_newton(it, x[rows], rows, r, H, g)
        active[rows], converged[rows] = ~stop, done
        if options.stop_together and bool(active.any()):
            active[:] = True
    return _finish(it, x, every, iterations, converged, information)


def _finish(it: _Iteration, x: Tensor, every: Tensor, iterations: Tensor, converged: Tensor,
            information: Tensor) -> LeastSquaresResult:
    """The result: the cost at ``x`` and the Laplace covariance where the options ask for it."""
    how = it.options.covariance
    if how == "solution" or (how == "last_linearization" and bool((iterations == 0).any())):
        r, H, _ = it.linearize(x, every)
        information = H if how == "solution" else torch.where((iterations == 0)[:, None, None], H, information)
    else:
        r = it.evaluate(x, every)
    cost = it.cost(x, every, r)
    if how == "none":
        return LeastSquaresResult(x, cost, iterations, converged, None, None)
    covariance, info = torch.linalg.inv_ex(information)
    covariance = torch.where((info != 0)[:, None, None], torch.nan, covariance)
    return LeastSquaresResult(x, cost, iterations, converged, information, covariance)
