"""Peer implementations of one filter for ``benchmarks/compare_peers.py``, written for the benchmark only.

* :func:`numpy_gpukf`: a straightforward numpy GPUKF (paper Sec. 3.3) with the exact GP: per step a Cholesky of
  ``P + Q``, the 7 sigma attitudes, the kernel rows against all ``N`` training inputs (``scipy.spatial.distance.cdist``)
  and one matrix-vector product with ``α = (K + σ²I)⁻¹ (y − μ)`` (the GP's one solve, done once before the run, as
  any GP user caches it), then the scalar update.
* :func:`filterpy_usque`: filterpy's ``UnscentedKalmanFilter`` on the GRP error with the USQUE reset after each
  step, its measurement function calling the library's renderer once per sigma point (filterpy's interface).
* :class:`GPyTorchMean`: an observation model whose mean is GPyTorch's default prediction path
  ``likelihood(model(x)).mean`` on the same training data and hyperparameters, to run inside the library's filter.

Each runner takes one filter's inputs as numpy arrays and returns the estimates ``(T+1, 4)``; all follow the
library's USQUE (:func:`lightcurve_gp.filters.usque.run_usque`: ``Q`` added to the sigma covariance and again to ``P⁻``,
the paper's ``λ = 0`` weights), so their estimates agree with it to round-off (the GPyTorch one to its CG
tolerance).
"""

from __future__ import annotations

import copy
import math

import numpy as np
import torch
from scipy.spatial.distance import cdist

__all__ = ["GPyTorchMean", "UsqueSetup", "filterpy_runner", "filterpy_usque", "numpy_gpukf", "numpy_runner"]


class UsqueSetup:
    """The filter constants as numpy: weights ``wm, wc (7,)``, ``n + λ``, ``Q, R``, GRP ``(a, f)``, ``T`` of the
    running mean, from :class:`lightcurve_gp.filters.usque.UsqueParams`."""

    def __init__(self, params):
        lam, wm, wc = params.weights(3, dtype=torch.float64)
        self.lam, self.wm, self.wc = lam, wm.numpy(), wc.numpy()
        self.scale = 3.0 + lam
        self.Q = float(params.Q) * np.eye(3)
        self.R = float(params.R)
        self.a, self.f = float(params.grp_a), float(params.grp_f)
        self.t_span_past = float(params.t_span_past)


def quat_mul(q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The paper's product ``q ⊗ p`` (Eq. (13)) of ``(..., 4)`` arrays, scalar last."""
    qv, q4, pv, p4 = q[..., :3], q[..., 3:], p[..., :3], p[..., 3:]
    vec = q4 * pv + p4 * qv - np.cross(qv, pv)
    return np.concatenate([vec, q4 * p4 - (qv * pv).sum(-1, keepdims=True)], axis=-1)


def attitude_matrix(q: np.ndarray) -> np.ndarray:
    """``A(q)`` ``(3, 3)`` of one unit quaternion (inertial → body)."""
    x, y, z, w = q
    return np.array([[w * w + x * x - y * y - z * z, 2 * (x * y + w * z), 2 * (x * z - w * y)],
                     [2 * (x * y - w * z), w * w - x * x + y * y - z * z, 2 * (y * z + w * x)],
                     [2 * (x * z + w * y), 2 * (y * z - w * x), w * w - x * x - y * y + z * z]])


def grp_to_quat(p: np.ndarray, a: float, f: float) -> np.ndarray:
    """Quaternions ``(..., 4)`` of GRPs ``(..., 3)`` (Crassidis & Markley 2003, eq. 33)."""
    p2 = (p * p).sum(-1, keepdims=True)
    q4 = (-a * p2 + f * np.sqrt(f * f + (1.0 - a * a) * p2)) / (f * f + p2)
    return np.concatenate([(a + q4) * p / f, q4], axis=-1)


def _propagate(s: UsqueSetup, q: np.ndarray, P: np.ndarray, inc: np.ndarray):
    """USQUE steps 1–5 (the rotation form of :func:`lightcurve_gp.filters.usque.run_usque`): ``(q₀⁻, P⁻, S⁻, χ⁻ (7,
    3))``."""
    d = inc / np.linalg.norm(inc)
    S_m = math.sqrt(s.scale) * attitude_matrix(d) @ np.linalg.cholesky(P + s.Q)
    P_m = S_m @ S_m.T / s.scale + s.Q
    chi = np.vstack([np.zeros((1, 3)), S_m.T, -S_m.T])
    return quat_mul(d, q), P_m, S_m, chi


def _update(s: UsqueSetup, q_m: np.ndarray, P_m: np.ndarray, S_m: np.ndarray, y_sig: np.ndarray, y: float):
    """USQUE steps 6–8 with predictions ``y_sig (7,)``: the reset attitude and ``P⁺``."""
    y_hat = s.wm @ y_sig
    dy = y_sig - y_hat
    P_yy = s.wc @ (dy * dy) + s.R
    P_xy = s.wc[1] * S_m @ (dy[1:4] - dy[4:])
    K = P_xy / P_yy
    dp = K * (y - y_hat)
    q = quat_mul(grp_to_quat(dp, s.a, s.f), q_m)
    return q / np.linalg.norm(q), P_m - P_yy * np.outer(K, K)


def numpy_gpukf(s: UsqueSetup, gp: dict, *, q0: np.ndarray, P0: np.ndarray, obs: np.ndarray,
                increments: np.ndarray) -> np.ndarray:
    """One GPUKF over ``obs (T+1,)`` (mag) with the exact GP ``gp``: ``xs`` (scaled training inputs ``(N, 5)``),
    ``inv_scale (5,)`` (``1/(ℓ√2)``), ``alpha (N,)``, ``theta1``, ``y_mean``. Returns the estimates ``(T+1, 4)``."""
    q, P, m_past = q0.copy(), P0.copy(), float(obs[0])
    out = np.empty((obs.shape[0], 4))
    out[0] = q
    for k in range(1, obs.shape[0]):
        q_m, P_m, S_m, chi = _propagate(s, q, P, increments[k - 1])
        q_sig = quat_mul(grp_to_quat(chi, s.a, s.f), q_m)
        x = np.column_stack([q_sig, np.full(7, m_past)]) * gp["inv_scale"]
        y_sig = gp["theta1"] * np.exp(-cdist(x, gp["xs"], "sqeuclidean")) @ gp["alpha"] + gp["y_mean"]
        q, P = _update(s, q_m, P_m, S_m, y_sig, float(obs[k]))
        P = 0.5 * (P + P.T)
        m_past = (s.t_span_past * m_past + obs[k]) / (s.t_span_past + 1.0)
        out[k] = q
    return out


def filterpy_usque(s: UsqueSetup, render, *, q0: np.ndarray, P0: np.ndarray, obs: np.ndarray,
                   increments: np.ndarray) -> np.ndarray:
    """The conventional UKF (paper Sec. 2.5) with filterpy's ``UnscentedKalmanFilter``: GRP error state, ``fx``
    the rotation ``A(δ) χ``, ``hx`` the renderer ``render(q (4,)) -> mag`` at ``δq(χ) ⊗ q₀⁻``; ``Q`` is added to
    ``P`` before ``predict`` (USQUE), the attitude reset after ``update``. Returns the estimates ``(T+1, 4)``."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    points = MerweScaledSigmaPoints(3, alpha=math.sqrt(s.scale / 3.0), beta=2.0, kappa=0.0)
    points.Wm, points.Wc = s.wm.copy(), s.wc.copy()  # the paper's λ = 0 weights (w0c with α = 1e-4)
    ctx = {"A": np.eye(3), "q_m": q0.copy()}
    ukf = UnscentedKalmanFilter(dim_x=3, dim_z=1, dt=1.0, points=points,
                                fx=lambda x, dt: ctx["A"] @ x,
                                hx=lambda x: np.array([render(quat_mul(grp_to_quat(x, s.a, s.f), ctx["q_m"]))]))
    ukf.x, ukf.P, ukf.Q, ukf.R = np.zeros(3), P0.copy(), s.Q.copy(), np.array([[s.R]])
    q = q0.copy()
    out = np.empty((obs.shape[0], 4))
    out[0] = q
    for k in range(1, obs.shape[0]):
        d = increments[k - 1] / np.linalg.norm(increments[k - 1])
        ctx["A"], ctx["q_m"] = attitude_matrix(d), quat_mul(d, q)
        ukf.P = ukf.P + s.Q
        ukf.predict()
        ukf.update(np.array([obs[k]]))
        q = quat_mul(grp_to_quat(ukf.x, s.a, s.f), ctx["q_m"])
        q /= np.linalg.norm(q)
        ukf.x = np.zeros(3)
        out[k] = q
    return out


def numpy_runner(setup: UsqueSetup, exact, sc, P0: torch.Tensor):
    """``run(n_steps, seed) -> estimates (n_steps + 1, 4)`` of :func:`numpy_gpukf` with the library's ExactGP
    ``exact`` on one filter of scenario ``sc`` (its observations of noise seed ``seed``)."""
    gp = {"xs": exact.xs_train.numpy(), "inv_scale": 1.0 / (exact.lengthscale.numpy() * math.sqrt(2.0)),
          "alpha": exact.alpha.numpy(), "theta1": float(exact.outputscale), "y_mean": float(exact.y_mean)}
    obs, inc, q0, p0 = sc.observations.numpy(), sc.increments[0].numpy(), sc.q_est0[0].numpy(), P0.numpy()
    return lambda n, seed: numpy_gpukf(setup, gp, q0=q0, P0=p0, obs=obs[seed, :n + 1], increments=inc[:n])


def filterpy_runner(setup: UsqueSetup, scene, rho: float, sc, P0: torch.Tensor):
    """``run(n_steps, seed)`` of :func:`filterpy_usque` with the library's renderer ``scene`` at reflectance
    ``rho`` (as :func:`numpy_runner`)."""

    def render(q: np.ndarray) -> float:
        return float(scene.magnitude(torch.from_numpy(q).unsqueeze(0), rho=rho)[0])

    obs, inc, q0, p0 = sc.observations.numpy(), sc.increments[0].numpy(), sc.q_est0[0].numpy(), P0.numpy()
    return lambda n, seed: filterpy_usque(setup, render, q0=q0, P0=p0, obs=obs[seed, :n + 1], increments=inc[:n])


class GPyTorchMean:
    """Observation model (the library's ``model(q=, m_past=, variance=)`` call) predicting the mean through
    GPyTorch's prediction path ``likelihood(model(x)).mean`` with the exact GP's data and hyperparameters.

    ``variance`` must be ``"none"`` (the paper's GPUKF uses the mean). With default settings GPyTorch also computes
    the predictive covariance on every call (a CG solve against all ``N`` points above 800 points, whether or not
    it is read); :meth:`skipping_variances` gives a view of the same model (same caches) that predicts under
    ``gpytorch.settings.skip_posterior_variances``. The mean solve (CG) is computed and cached on the first call.
    """

    uses_m_past = True

    def __init__(self, exact, y_train: torch.Tensor):
        from lightcurve_gp.observation.fitting import gpytorch_exact_model

        self.exact = exact
        self.skip_variances = False
        self.gmodel, self.glik = gpytorch_exact_model(
            exact.x_train, y_train.to(torch.float64) - exact.y_mean, float(exact.outputscale),
            float(exact.lengthscale[0]), float(exact.noise))
        self.gmodel.eval()
        self.glik.eval()

    def skipping_variances(self) -> GPyTorchMean:
        view = copy.copy(self)
        view.skip_variances = True
        return view

    def __call__(self, *, q: torch.Tensor, m_past: torch.Tensor, variance: str = "none"):
        import gpytorch

        if variance != "none":
            raise ValueError("GPyTorchMean predicts the mean only (variance='none')")
        x = self.exact.inputs(q.reshape(-1, 4), m_past.reshape(-1))
        with torch.no_grad(), gpytorch.settings.skip_posterior_variances(self.skip_variances):
            mean = self.glik(self.gmodel(x)).mean
        return (mean + self.exact.y_mean).reshape(q.shape[:-1]), None
