"""Helpers shared by the tests: a toy attitude observation model and a constant-rate truth to filter."""

import math

import torch

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.rotations import attitude_matrix, euler321_to_quat, quat_conj, quat_mul, quat_to_rotvec
from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.evaluation.harness import run_estimators
from lightcurve_gp.evaluation.registry import DEFAULT_ESTIMATORS
from lightcurve_gp.inference.families import families
from lightcurve_gp.observation.base import ObservationModule
from lightcurve_gp.simulation.scenario import simulate_scenario

DT = torch.float64


class ToyModel(ObservationModule):
    """Scalar ``h(q) = Σ_j a_j · A(q) b_j`` with two body/inertial vector pairs (no rotational symmetry)."""

    uses_m_past = False

    def __init__(self, variance: float | None = None, m_past_gain: float = 0.0):
        super().__init__()
        a = torch.tensor([[0.6, 0.8, 0.0], [0.0, 0.6, -0.8]], dtype=DT)
        b = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.28, 0.96]], dtype=DT)
        self.register_buffer("a", a)
        self.register_buffer("b", b)
        self.constant_variance = variance
        self.m_past_gain = m_past_gain
        self.calls = 0

    def _predict(self, q, m_past, variance):
        self.calls += 1
        A = attitude_matrix(q / torch.linalg.vector_norm(q, dim=-1, keepdim=True))
        mean = torch.einsum("ji,...ik,jk->...", self.a, A, self.b) + self.m_past_gain * m_past
        var = None
        if variance != "none" and self.constant_variance is not None:
            var = torch.full_like(mean, self.constant_variance)
        return mean, var


def increment(omega: torch.Tensor, dt: float) -> torch.Tensor:
    """Exact kinematic increment for a constant body rate: δ = [sin(|ω|dt/2) ω̂, cos(|ω|dt/2)]."""
    w = torch.linalg.vector_norm(omega, dim=-1, keepdim=True)
    return torch.cat([torch.sin(0.5 * w * dt) * omega / w, torch.cos(0.5 * w * dt)], -1)


def scenario(B=3, T=120, seed=0, noise=0.0):
    """Truth rotating at constant body rates, noisy toy observations, initial estimates 10° off."""
    g = torch.Generator().manual_seed(seed)
    omega = torch.deg2rad(torch.tensor([1.5, -1.0, 2.5], dtype=DT))
    omega = omega * (1 + 0.2 * torch.rand(B, 1, generator=g, dtype=DT))
    delta = increment(omega, 1.0)  # (B, 4)
    q = euler321_to_quat(torch.deg2rad(torch.randn(B, 3, generator=g, dtype=DT) * 40))
    qs = [q]
    for _ in range(T):
        q = quat_mul(delta, q)
        qs.append(q)
    q_true = torch.stack(qs, 1)  # (B, T+1, 4)
    model = ToyModel()
    y = model(q=q_true, m_past=torch.zeros(B, T + 1, dtype=DT))[0]
    y = y + noise * torch.randn(y.shape, generator=g, dtype=DT)
    err0 = euler321_to_quat(torch.deg2rad(torch.tensor([-10.0, 5.0, -10.0], dtype=DT)))
    q_est0 = quat_mul(err0, q_true[:, 0])
    increments = delta[:, None].expand(B, T, 4).contiguous()
    return q_true, y, q_est0, increments


def err_deg(q_true, q_est):
    return torch.rad2deg(torch.linalg.vector_norm(quat_to_rotvec(quat_mul(q_true, quat_conj(q_est))), dim=-1))


def tiny_training(name: str) -> list[str]:
    """Config overrides of a tiny sparse-GP training run named ``name``: 256 random attitudes, 64 inducing points,
    no hyperparameter fit, a 60 s scenario scored over 30–60 s (the CLI tests' model, seconds to train)."""
    return ["data.num_random=256", "model.sparse.num_inducing=64", "model.sparse.iterations=0",
            "data.heldout_size=40", "scenario.duration_s=60", "evaluation.rmse_window_s=[30, 60]", f"name={name}"]


def as_sets(overrides: list[str]) -> list[str]:
    """``["--set", o, …]`` for the command lines."""
    return [a for o in overrides for a in ("--set", o)]


def train_tiny(config: str, out, name: str):
    """Train the tiny model of ``config`` into ``out`` with ``python -m lightcurve_gp.train``; its model file."""
    from lightcurve_gp.commands import train

    assert train.main([config, "--out", str(out), "--no-progress", *as_sets(tiny_training(name))]) == 0
    return out / name / "model.pt"


def simulate_file(config: str, tmp_path, sets: list[str], *extra: str):
    """``python -m lightcurve_gp.simulate`` of ``config`` (noise seed 2) into ``tmp_path/obs.ecsv``; the file."""
    from lightcurve_gp.commands import simulate

    obs = tmp_path / "obs.ecsv"
    assert simulate.main([config, "--out", str(obs), "--seed", "2", "--no-progress", *sets, *extra]) == 0
    return obs


def estimate_scenario(cfg, model=None, *, seeds=None, rho_true=None, estimators=DEFAULT_ESTIMATORS):
    """The config's scenario simulated for ``seeds`` and the estimators run on it (the estimate command's core)."""
    return run_estimators(cfg, simulate_scenario(cfg, seeds=seeds, rho_true=rho_true), estimators=estimators,
                          model=model)


def tumbler_light_curve(scene, inertia, *, seed: int, rate_deg_s: float, samples: int, sigma: float,
                        rho: float | None = None):
    """A random tumbler's noisy light curve at 1 Hz: the initial attitude ``(4,)``, the body rate ``(3,)`` (rad/s,
    ``rate_deg_s`` about a random axis) and the magnitudes ``(samples + 1,)`` (float64); ``rho``: the scene's own
    when ``None``."""
    g = torch.Generator().manual_seed(seed)
    axis = torch.randn(3, generator=g, dtype=torch.float64)
    q0 = random_attitudes(1, seed=seed + 5, dtype=torch.float64)[0]
    w0 = math.radians(rate_deg_s) * axis / torch.linalg.vector_norm(axis)
    q, _ = propagate(q0, w0, inertia, 1.0, samples)
    m = scene.magnitude(q) if rho is None else scene.magnitude(q, rho=rho)
    return q0, w0, m + sigma * torch.randn(samples + 1, generator=g, dtype=torch.float64)


def families_of(group, inv, problem, *, rate_max_deg_s: float = 5.0):
    """The families (:func:`lightcurve_gp.inference.families.families`) of the solutions of ``inv`` (an
    :class:`~lightcurve_gp.inference.inversion.Inversion`) on ``problem``, rates up to ``rate_max_deg_s``."""
    return families(group, q0=inv.q0, omega0=inv.omega0, log_rho=inv.log_rho, cost=inv.cost,
                    covariance=inv.covariance, sigma=problem.sigma, rate_max_rad_s=math.radians(rate_max_deg_s))
