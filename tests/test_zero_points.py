"""Zero points profiled out of whitened residuals: the closed form against a direct solve, its Jacobian against
finite differences."""

import torch

from lightcurve_gp.inference.zero_points import profile_zero_points

F64 = torch.float64


def test_profiled_residuals_equal_the_least_squares_solve_with_the_offsets_free():
    g = torch.Generator().manual_seed(0)
    K = 12
    y_minus_m = torch.randn(2, K, generator=g, dtype=F64)
    w = torch.rand(K, generator=g, dtype=F64) + 0.5
    w[3] = 0.0  # a sample left out takes no part
    curve = torch.tensor([0, 0, 1, 1, 1, 0, 2, 2, 1, 0, 2, 2])
    z = torch.stack([(curve == c) for c in (1, 2)], -1).to(F64)  # curves 1 and 2 relative, 0 absolute
    r, offsets, _ = profile_zero_points(w * y_minus_m, w, z)
    for a in range(2):  # the offsets minimise Σ w² (y − m − Z b)² (lstsq on the weighted design)
        b = torch.linalg.lstsq((w[:, None] * z), (w * y_minus_m[a])[:, None]).solution[:, 0]
        assert torch.allclose(offsets[a], b, atol=1e-12)
        assert torch.allclose(r[a], w * (y_minus_m[a] - z @ b), atol=1e-12)
    assert torch.equal(r[:, curve == 0], (w * y_minus_m)[:, curve == 0])


def test_the_projected_jacobian_is_the_derivative_of_the_profiled_residuals():
    g = torch.Generator().manual_seed(1)
    K, n = 9, 3
    A = torch.randn(K, n, generator=g, dtype=F64)
    y = torch.randn(K, generator=g, dtype=F64)
    w = torch.rand(K, generator=g, dtype=F64) + 0.5
    z = (torch.arange(K) % 3 == 1).to(F64)[:, None]

    def residual(x):
        m = torch.sin(A @ x)  # a nonlinear prediction
        return w * (y - m)

    x = torch.randn(n, generator=g, dtype=F64)
    J = torch.autograd.functional.jacobian(residual, x)
    _, _, projected = profile_zero_points(residual(x), w, z, jacobian=J)
    numeric = torch.autograd.functional.jacobian(lambda v: profile_zero_points(residual(v), w, z)[0], x)
    assert torch.allclose(projected, numeric, atol=1e-10)
