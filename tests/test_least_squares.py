"""The batched least-squares core: Jacobians against closed forms, the exact posterior of a linear-Gaussian problem
in one Gauss–Newton step, descent on nonlinear toys, the Laplace covariance against a numerical Hessian."""

import dataclasses

import numpy as np
import pytest
import torch

from lightcurve_gp.inference.jacobian import jacobian
from lightcurve_gp.inference.solver import (
    GaussianPrior,
    LeastSquaresOptions,
    LeastSquaresResult,
    batch_least_squares,
    least_squares_cost,
)

DT = torch.float64


def curved(params: torch.Tensor):
    """``r_k(x) = p_k0 sin(x_0) + p_k1 x_1² − p_k2 x_0 x_1`` of problem ``rows`` with parameters ``params (B, m, 3)``,
    and its closed-form Jacobian."""

    def residual(x, rows):
        p = params[rows]
        return p[..., 0] * torch.sin(x[:, :1]) + p[..., 1] * x[:, 1:2] ** 2 - p[..., 2] * x[:, :1] * x[:, 1:2]

    def exact(x):
        p = params
        d0 = p[..., 0] * torch.cos(x[:, :1]) - p[..., 2] * x[:, 1:2]
        d1 = 2 * p[..., 1] * x[:, 1:2] - p[..., 2] * x[:, :1]
        return torch.stack([d0, d1], -1)

    return residual, exact


@pytest.mark.parametrize("method, atol", [("forward_mode", 1e-13), ("central", 1e-8), ("forward_difference", 1e-5)])
def test_jacobian_equals_the_closed_form(method, atol):
    g = torch.Generator().manual_seed(0)
    params = torch.randn(5, 7, 3, generator=g, dtype=DT)
    residual, exact = curved(params)
    x = torch.randn(5, 2, generator=g, dtype=DT)
    r, J = jacobian(residual, x, torch.arange(5), method=method, step=1e-6)
    torch.testing.assert_close(r, residual(x, torch.arange(5)), rtol=0, atol=0)
    assert J.shape == (5, 7, 2)
    torch.testing.assert_close(J, exact(x), rtol=0, atol=atol)


def test_forward_mode_agrees_with_central_differences_on_rows_of_repeated_problems():
    g = torch.Generator().manual_seed(1)
    params = torch.randn(3, 4, 3, generator=g, dtype=DT)
    residual, _ = curved(params)
    rows = torch.tensor([2, 0, 2, 1])  # a problem may appear twice, at different states
    x = torch.randn(4, 2, generator=g, dtype=DT)
    _, forward = jacobian(residual, x, rows, method="forward_mode")
    _, central = jacobian(residual, x, rows, method="central", step=torch.tensor([1e-5, 2e-5], dtype=DT))
    torch.testing.assert_close(forward, central, rtol=0, atol=1e-8)
    assert not torch.allclose(forward[0], forward[2])


def test_jacobian_refuses_a_bad_method_and_step():
    residual, _ = curved(torch.ones(1, 2, 3, dtype=DT))
    with pytest.raises(ValueError, match="jacobian method: 'backward' is not one of forward_mode, central"):
        jacobian(residual, torch.zeros(1, 2, dtype=DT), torch.arange(1), method="backward")
    with pytest.raises(ValueError, match=r"jacobian step: \[0.0, 0.0\] must be > 0"):
        jacobian(residual, torch.zeros(1, 2, dtype=DT), torch.arange(1), method="central", step=0.0)


def linear_gaussian(B=4, m=9, n=3, seed=0):
    """``y = A x + σ ε`` per problem with a full-covariance Gaussian prior; the exact posterior from numpy."""
    rng = np.random.default_rng(seed)
    A, y = rng.normal(size=(B, m, n)), rng.normal(size=(B, m))
    sigma = 0.3
    mu = rng.normal(size=(B, n))
    L = rng.normal(size=(B, n, n)) + 2 * np.eye(n)
    precision = L @ L.transpose(0, 2, 1)
    cov = np.linalg.inv(precision + A.transpose(0, 2, 1) @ A / sigma**2)
    mean = (cov @ (precision @ mu[..., None] + A.transpose(0, 2, 1) @ y[..., None] / sigma**2))[..., 0]
    At, yt = torch.tensor(A), torch.tensor(y)

    def residual(x, rows):
        return (yt[rows] - (At[rows] @ x.unsqueeze(-1)).squeeze(-1)) / sigma

    prior = GaussianPrior(torch.tensor(mu), torch.tensor(precision))
    return residual, prior, mean, cov, torch.tensor(np.linalg.cholesky(precision).transpose(0, 2, 1))


@pytest.mark.parametrize("jac", ["forward_mode", "central"])
def test_one_gauss_newton_step_is_the_exact_linear_gaussian_posterior(jac):
    residual, prior, mean, cov, _ = linear_gaussian()
    x0 = torch.full((4, 3), 5.0, dtype=DT)  # far from the answer: a linear problem does not care
    result = batch_least_squares(residual, x0, prior=prior, options=LeastSquaresOptions(
        method="gauss_newton", iterations=1, jacobian=jac, step=1e-3))
    np.testing.assert_allclose(result.x.numpy(), mean, rtol=0, atol=1e-10)
    np.testing.assert_allclose(result.covariance.numpy(), cov, rtol=1e-10, atol=1e-14)
    assert result.iterations.tolist() == [1] * 4 and not bool(result.converged.any())
    assert float(x0.max()) == 5.0  # the start is not modified
    again = batch_least_squares(residual, x0, prior=prior, options=LeastSquaresOptions(method="gauss_newton",
                                                                                       jacobian=jac, step=1e-3))
    assert again.iterations.tolist() == [2] * 4 and bool(again.converged.all())  # the second step is ~0


def test_levenberg_marquardt_and_the_square_root_prior_reach_the_same_posterior():
    residual, prior, mean, cov, root = linear_gaussian(seed=3)
    result = batch_least_squares(residual, torch.zeros(4, 3, dtype=DT),
                                 prior=GaussianPrior.from_sqrt_information(prior.mean, root),
                                 options=LeastSquaresOptions(jacobian="forward_mode", tolerance=1e-12, iterations=50))
    np.testing.assert_allclose(result.x.numpy(), mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(result.covariance.numpy(), cov, rtol=1e-9, atol=1e-14)
    assert bool(result.converged.all())
    expected = least_squares_cost(residual(result.x, torch.arange(4)), result.x, torch.arange(4), prior=prior)
    torch.testing.assert_close(result.cost, expected, rtol=1e-12, atol=0)


def test_a_residual_variance_per_problem_equals_whitened_residuals():
    residual, prior, mean, cov, _ = linear_gaussian(seed=7)
    variance = torch.tensor([0.09, 0.5, 2.0, 0.01], dtype=DT)

    def raw(x, rows):  # the same data term: r_raw² / v = (r √0.09)² / v, i.e. r² when v = 0.09
        return residual(x, rows) * 0.3 * (variance[rows] / 0.09).sqrt().unsqueeze(-1)

    options = LeastSquaresOptions(method="gauss_newton", iterations=1, jacobian="forward_mode")
    scaled = batch_least_squares(raw, torch.zeros(4, 3, dtype=DT), prior=prior, variance=variance, options=options)
    np.testing.assert_allclose(scaled.x.numpy(), mean, rtol=0, atol=1e-10)
    np.testing.assert_allclose(scaled.covariance.numpy(), cov, rtol=1e-10, atol=1e-14)
    shared = batch_least_squares(lambda x, rows: residual(x, rows) * 0.3, torch.zeros(4, 3, dtype=DT), prior=prior,
                                 variance=0.09, options=options)
    np.testing.assert_allclose(shared.x.numpy(), mean, rtol=0, atol=1e-10)


def test_stopping_together_iterates_every_problem_until_all_have_stopped():
    a = torch.tensor([1.0, 1.0], dtype=DT)
    x0 = torch.tensor([[1.0, 1.0], [-1.2, 1.0]], dtype=DT)  # the first starts at its minimum
    options = LeastSquaresOptions(method="gauss_newton", halvings=30, tolerance=1e-10, iterations=100)
    alone = batch_least_squares(rosenbrock(a), x0, options=options)
    together = batch_least_squares(rosenbrock(a), x0, options=dataclasses.replace(options, stop_together=True))
    assert alone.iterations[0] == 1 and together.iterations[0] == together.iterations[1] == alone.iterations[1]
    torch.testing.assert_close(together.x, alone.x, rtol=0, atol=1e-12)
    assert bool(together.converged.all())


def rosenbrock(a: torch.Tensor):
    """``r = (10 (x_1 − x_0²), a − x_0)`` per problem (minimum 0 at ``(a, a²)``)."""

    def residual(x, rows):
        return torch.stack([10 * (x[:, 1] - x[:, 0] ** 2), a[rows] - x[:, 0]], -1)

    return residual


def test_levenberg_marquardt_lowers_the_cost_at_every_step_and_finds_the_minimum():
    a = torch.tensor([1.0, -0.5, 2.0, 0.3], dtype=DT)
    residual = rosenbrock(a)
    x0 = torch.tensor([[-1.2, 1.0], [2.0, -1.0], [0.0, 0.0], [1.5, 2.5]], dtype=DT)
    # the state after k iterations, k = 0 … 30: every accepted step lowers the cost, a rejected one keeps it
    costs = torch.stack([batch_least_squares(residual, x0, options=LeastSquaresOptions(
        iterations=k, tolerance=0.0, covariance="none")).cost for k in range(31)])
    assert bool((costs[1:] <= costs[:-1]).all()) and bool((costs[1:] < costs[:-1]).any(0).all())
    assert bool((costs[-1] < 1e-3 * costs[0]).all())
    result = batch_least_squares(residual, x0, options=LeastSquaresOptions(tolerance=1e-12, iterations=100))
    torch.testing.assert_close(result.x, torch.stack([a, a**2], -1), rtol=0, atol=1e-9)
    assert bool(result.converged.all()) and float(result.cost.max()) < 1e-20


def test_levenberg_marquardt_linearises_each_state_once(monkeypatch):
    """A rejected trial leaves the state where it was, so its normal equations are reused with more damping: no
    problem is linearised twice at the same state, never more often than it iterates, and the minimum is the same."""
    import lightcurve_gp.inference.solver as solver

    a = torch.tensor([1.0, -0.5, 2.0], dtype=DT)
    x0 = torch.tensor([[-1.2, 1.0], [2.0, -1.0], [1.5, 2.5]], dtype=DT)
    seen: list[tuple[int, tuple[float, ...]]] = []

    def recording(residual, x, rows, **kwargs):
        seen.extend((int(r), tuple(v.tolist())) for r, v in zip(rows, x))
        return jacobian(residual, x, rows, **kwargs)

    monkeypatch.setattr(solver, "jacobian", recording)
    result = batch_least_squares(rosenbrock(a), x0, options=LeastSquaresOptions(tolerance=1e-12, iterations=100,
                                                                                 covariance="none"))
    assert len(seen) == len(set(seen))
    linearised = torch.bincount(torch.tensor([r for r, _ in seen]), minlength=3)
    assert bool((linearised <= result.iterations).all())
    assert linearised[0] < result.iterations[0]  # the classic start (−1.2, 1) has rejected trials (20 of 29)
    torch.testing.assert_close(result.x, torch.stack([a, a**2], -1), rtol=0, atol=1e-9)


def test_gauss_newton_with_halvings_never_raises_the_cost():
    a = torch.tensor([1.0, 2.0], dtype=DT)
    residual = rosenbrock(a)
    x0 = torch.tensor([[-1.2, 1.0], [3.0, -2.0]], dtype=DT)
    start = least_squares_cost(residual(x0, torch.arange(2)), x0, torch.arange(2))
    plain = batch_least_squares(residual, x0, options=LeastSquaresOptions(method="gauss_newton", iterations=1))
    halved = batch_least_squares(residual, x0, options=LeastSquaresOptions(method="gauss_newton", iterations=1,
                                                                           halvings=20))
    assert bool((plain.cost > start).any())  # the full step overshoots on this curved valley
    assert bool((halved.cost <= start).all())


def test_laplace_covariance_is_the_inverse_of_the_numerical_hessian_at_a_zero_residual_solution():
    # exact data and the prior centred on the truth: the solution is the truth, the residuals vanish there and the
    # Gauss–Newton information is the cost's full Hessian
    g = torch.Generator().manual_seed(4)
    params = torch.randn(3, 6, 3, generator=g, dtype=DT)
    truth = torch.randn(3, 2, generator=g, dtype=DT)
    model, _ = curved(params)
    y = model(truth, torch.arange(3))

    def residual(x, rows):
        return (y[rows] - model(x, rows)) / 0.1

    prior = GaussianPrior.independent(truth, torch.tensor([2.0, 0.5], dtype=DT))
    result = batch_least_squares(residual, truth + 0.05, prior=prior,
                                 options=LeastSquaresOptions(jacobian="forward_mode", tolerance=1e-13,
                                                             iterations=60))
    torch.testing.assert_close(result.x, truth, rtol=0, atol=1e-10)
    h = 1e-4
    for b in range(3):
        def cost(x):
            xb = x.unsqueeze(0)
            return float(least_squares_cost(residual(xb, torch.tensor([b])), xb, torch.tensor([b]), prior=prior))

        E = torch.eye(2, dtype=DT) * h
        hess = torch.tensor([[(cost(result.x[b] + E[i] + E[j]) - cost(result.x[b] + E[i] - E[j])
                               - cost(result.x[b] - E[i] + E[j]) + cost(result.x[b] - E[i] - E[j])) / (4 * h * h)
                              for j in range(2)] for i in range(2)], dtype=DT)
        torch.testing.assert_close(result.covariance[b], torch.linalg.inv(hess), rtol=1e-5, atol=0)


def test_missing_samples_are_left_out_and_each_problem_is_solved_as_if_alone():
    residual, prior, _, _, _ = linear_gaussian(B=3, m=6, seed=5)
    full = residual(torch.zeros(3, 3, dtype=DT), torch.arange(3))

    def gapped(x, rows):
        r = residual(x, rows)
        return torch.where((rows == 1)[:, None] & (torch.arange(6) == 2), torch.nan, r)

    def dropped(x, rows):  # problem 1 alone (as problem 0) without its sample 2
        return residual(x, rows + 1)[:, [0, 1, 3, 4, 5]]

    options = LeastSquaresOptions(method="gauss_newton", jacobian="forward_mode")
    with_gap = batch_least_squares(gapped, torch.zeros(3, 3, dtype=DT), prior=prior, options=options)
    alone = batch_least_squares(dropped, torch.zeros(1, 3, dtype=DT), options=options,
                                prior=GaussianPrior(prior.mean[1], prior.precision[1]))
    torch.testing.assert_close(with_gap.x[1], alone.x[0], rtol=0, atol=1e-12)
    torch.testing.assert_close(with_gap.covariance[1], alone.covariance[0], rtol=1e-12, atol=0)
    torch.testing.assert_close(with_gap.cost[1], alone.cost[0], rtol=1e-12, atol=0)
    assert bool(torch.isfinite(full).all())


def test_an_invalid_residual_penalty_keeps_steps_out_of_where_the_model_fails():
    def residual(x, rows):  # the model fails (NaN) beyond x = 2.5; the data want x = 3
        r = torch.cat([x - 3.0, 2 * (x - 3.0)], -1)
        return torch.where(x < 2.5, r, torch.nan)

    x0 = torch.zeros(1, 1, dtype=DT)
    options = LeastSquaresOptions(damping=1e-6, iterations=1, covariance="none")
    left_out = batch_least_squares(residual, x0, options=options)
    assert float(left_out.x) == pytest.approx(3.0, abs=1e-5) and float(left_out.cost) == 0.0  # all samples lost
    guarded = batch_least_squares(residual, x0, options=dataclasses.replace(options, invalid_residual=1e3,
                                                                            iterations=30))
    assert 0.0 < float(guarded.x) < 2.5
    assert float(guarded.cost) < float(least_squares_cost(residual(x0, torch.arange(1)), x0, torch.arange(1)))


def test_converged_problems_stop_costing():
    a = torch.tensor([1.0, 1.0], dtype=DT)
    residual, seen = rosenbrock(a), []

    def counting(x, rows):
        seen.append(rows.clone())
        return residual(x, rows)

    x0 = torch.tensor([[1.0, 1.0], [-1.2, 1.0]], dtype=DT)  # the first starts at its minimum
    result = batch_least_squares(counting, x0, options=LeastSquaresOptions(tolerance=1e-10, iterations=100,
                                                                           covariance="none"))
    assert result.iterations[0] == 1 and result.iterations[1] > 5 and bool(result.converged.all())
    late = seen[3:-1]  # after the first iteration, before the final evaluation of every problem
    assert late and all(bool((rows == 1).all()) for rows in late)


def test_chunks_of_problems_give_the_same_solution():
    a = torch.linspace(-1.0, 2.0, 7, dtype=DT)
    x0 = torch.stack([torch.full_like(a, -1.2), torch.ones_like(a)], -1)
    whole = batch_least_squares(rosenbrock(a), x0, options=LeastSquaresOptions(tolerance=1e-12, iterations=100))
    sizes = []

    def counting(x, rows):
        sizes.append(rows.shape[0])
        return rosenbrock(a)(x, rows)

    pieces = batch_least_squares(counting, x0, options=LeastSquaresOptions(tolerance=1e-12, iterations=100, chunk=3))
    torch.testing.assert_close(pieces.x, whole.x, rtol=0, atol=1e-14)
    torch.testing.assert_close(pieces.covariance, whole.covariance, rtol=1e-12, atol=0)
    assert max(sizes) == 3 * 5  # three problems, each at five points of the central differences


def test_a_singular_information_gives_a_nan_covariance_not_an_error():
    def residual(x, rows):  # x_1 never enters: no information on it and no prior
        return torch.stack([x[:, 0] - 1.0, 2 * x[:, 0]], -1)

    result = batch_least_squares(residual, torch.zeros(2, 2, dtype=DT),
                                 options=LeastSquaresOptions(method="gauss_newton", iterations=3))
    assert isinstance(result, LeastSquaresResult)
    assert bool(torch.isnan(result.covariance).all()) and result.iterations.tolist() == [1, 1]
    assert not bool(result.converged.any())


@pytest.mark.parametrize("kwargs, message", [
    ({"method": "newton"}, "method: 'newton' is not 'gauss_newton' or 'levenberg_marquardt'"),
    ({"covariance": "full"}, "covariance: 'full' is not 'solution', 'last_linearization' or 'none'"),
    ({"iterations": -1}, "iterations: -1, halvings: 0 must be >= 0"),
    ({"chunk": 0}, r"chunk: 0 must be >= 1 \(or None\)"),
])
def test_bad_options_are_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        LeastSquaresOptions(**kwargs)


def test_bad_prior_shapes_are_named():
    with pytest.raises(ValueError, match=r"prior: mean \(2, 3\) and precision \(3, 3\) must be"):
        GaussianPrior(torch.zeros(2, 3, dtype=DT), torch.eye(3, dtype=DT))
