"""The batch MAP with the body rate unknown: the known-rate MAP in the limit of a certain rate, and the truth from
noise-free light curves."""

import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.dynamics import propagate, quaternion_increments
from lightcurve_gp.attitude.metrics import total_angle_deg
from lightcurve_gp.attitude.rotations import euler321_to_quat, quat_mul
from lightcurve_gp.config.load import load_config
from lightcurve_gp.inference.attitude import MapPrior, map_known_rate
from lightcurve_gp.inference.spin import RateDynamics, map_with_rate, neg_log_posterior, rate_map_errors
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario

from helpers import DT, ToyModel

BOXWING = Path(__file__).resolve().parents[1] / "configs" / "boxwing.yaml"
INERTIA = torch.tensor([2.0, 3.0, 4.5], dtype=DT)
OMEGA0 = torch.deg2rad(torch.tensor([1.5, -1.0, 2.5], dtype=DT))


def toy_truth(T: int, omega_error_deg_s, seeds: int = 2, noise: float = 0.0):
    """A torque-free truth (``q (T+1, 4)``, ``ω (T+1, 3)``), toy light curves ``(seeds, T+1)``, the initial attitude
    estimate 10° off and the initial rate estimate off by ``omega_error_deg_s``."""
    q0 = euler321_to_quat(torch.deg2rad(torch.tensor([20.0, -35.0, 50.0], dtype=DT)))
    q_true, omega_true = propagate(q0, OMEGA0, INERTIA, 1.0, T)
    clean = ToyModel()(q=q_true, m_past=torch.zeros(T + 1, dtype=DT))[0]
    g = torch.Generator().manual_seed(2)
    y = clean + noise * torch.randn(seeds, T + 1, generator=g, dtype=DT)
    q_est0 = quat_mul(euler321_to_quat(torch.deg2rad(torch.tensor([-10.0, 5.0, -10.0], dtype=DT))), q0)
    omega_est0 = OMEGA0 + torch.deg2rad(torch.tensor(omega_error_deg_s, dtype=DT))
    return q_true, omega_true, y, q_est0, omega_est0


def test_a_certain_rate_gives_the_known_rate_map():
    _, _, y, q_est0, omega_est0 = toy_truth(50, [0.2, -0.1, 0.1], noise=0.3)
    prior = MapPrior(p0_deg=10.0, measurement_noise=0.09)
    known = map_known_rate(ToyModel(), q_est0=q_est0, observations=y, prior=prior, checkpoints=[25, 50],
                           offset=False, increments=quaternion_increments(omega_est0, INERTIA, 1.0, 50), iterations=30)
    dynamics = RateDynamics(omega_est0=omega_est0, p0_omega_deg_s=1e-9, inertia=INERTIA, dt=1.0)
    rate = map_with_rate(ToyModel(), q_est0=q_est0, dynamics=dynamics, observations=y, prior=prior,
                         checkpoints=[25, 50], offset=False, iterations=30, halvings=0)  # plain steps, as known
    for t in (25, 50):
        assert float((rate[t].x[:, :3] - known[t]).abs().max()) < 1e-10
        assert float(rate[t].x[:, 3:].abs().max()) < 1e-15
        # the rate's posterior std is its prior's when the prior leaves nothing to learn
        std = rate[t].covariance.diagonal(dim1=-2, dim2=-1)[:, 3:].sqrt()
        torch.testing.assert_close(std, torch.full_like(std, math.radians(1e-9)), rtol=1e-6, atol=0)


@pytest.mark.slow  # ~21 s on two loaded cores
@pytest.mark.parametrize("offset", [False, True])
def test_the_map_is_a_minimum_of_its_negative_log_posterior(offset):
    _, _, y, q_est0, omega_est0 = toy_truth(80, [0.2, -0.1, 0.1], noise=0.2)
    y = y + (0.3 if offset else 0.0)
    prior = MapPrior(p0_deg=10.0, measurement_noise=0.04, offset_prior_std=0.5)
    dynamics = RateDynamics(omega_est0=omega_est0, p0_omega_deg_s=0.3, inertia=INERTIA, dt=1.0)
    x = map_with_rate(ToyModel(), q_est0=q_est0, dynamics=dynamics, observations=y, prior=prior, checkpoints=[40, 80],
                      offset=offset, iterations=30)[80].x

    def cost(states):
        return neg_log_posterior(ToyModel(), states, q_est0=q_est0, dynamics=dynamics, observations=y, prior=prior,
                                 t=80)

    at_map = cost(x)
    scale = torch.tensor([1e-3] * 3 + [1e-5] * 3 + [1e-3] * offset, dtype=DT)
    for d in torch.diag(scale):
        assert bool((cost(x + d) > at_map).all()) and bool((cost(x - d) > at_map).all())
    assert bool((cost(torch.zeros_like(x)) > at_map).all())  # the data moved it off the prior mean


@pytest.mark.parametrize("offset", [False, True])
def test_noise_free_light_curves_give_the_true_attitude_and_rate(offset):
    q_true, omega_true, y, q_est0, omega_est0 = toy_truth(120, [0.3, -0.3, 0.3])
    y = y + (0.4 if offset else 0.0)
    dynamics = RateDynamics(omega_est0=omega_est0, p0_omega_deg_s=1e4, inertia=INERTIA, dt=1.0)
    est = map_with_rate(ToyModel(), q_est0=q_est0, dynamics=dynamics, observations=y, offset=offset,
                        prior=MapPrior(p0_deg=1e5, measurement_noise=1e-8, offset_prior_std=1e3),
                        checkpoints=[60, 120], iterations=30)
    att, rate = rate_map_errors(est, q_true=q_true, omega_true=omega_true, q_est0=q_est0, dynamics=dynamics)
    start_att, start_rate = rate_map_errors({120: type(est[120])(torch.zeros_like(est[120].x), est[120].covariance)},
                                            q_true=q_true, omega_true=omega_true, q_est0=q_est0, dynamics=dynamics)
    assert float(start_att.abs().max()) > 20 and float(start_rate.min()) > 0.5  # far off without the data
    assert float(att.abs().max()) < 1e-6 and float(rate.max()) < 1e-8
    torch.testing.assert_close(est[120].x[:, 3:6], (OMEGA0 - omega_est0).expand(2, 3), rtol=0, atol=1e-10)
    if offset:
        torch.testing.assert_close(est[120].x[:, 6], torch.full((2,), 0.4, dtype=DT), rtol=0, atol=1e-8)


@pytest.mark.slow  # ~14 s on two loaded cores
def test_renderer_light_curve_started_off_in_rate_gives_the_truth():
    cfg = load_config(BOXWING, ["scenario.duration_s=300", "evaluation.rmse_window_s=[200, 300]",
                                "scenario.initial_error_deg=[-3, 2, -3]",
                                "scenario.initial_omega_error_deg_s=[0.02, -0.02, 0.02]"])
    scene = Scene.from_config(cfg)
    sc = simulate_scenario(cfg, seeds=[0], scene=scene)
    y = sc.m_clean
    q_true, omega_true, q_est0, omega_est0 = sc.q_true[0], sc.omega_true[0], sc.q_est0[0], sc.omega_est0[0]
    dynamics = RateDynamics(omega_est0=omega_est0, p0_omega_deg_s=100.0, dt=cfg.scenario.dt_s,
                            inertia=torch.tensor(cfg.shape.inertia_kg_m2, dtype=DT))
    est = map_with_rate(Parametric(scene, cfg.scenario.rho_true), q_est0=q_est0, dynamics=dynamics, observations=y,
                        prior=MapPrior(p0_deg=1e5, measurement_noise=1e-4), checkpoints=[60, 120, 180, 240, 300],
                        offset=False, iterations=30)
    att, rate = rate_map_errors(est, q_true=q_true, omega_true=omega_true, q_est0=q_est0, dynamics=dynamics)
    assert float(total_angle_deg(q_true[0], q_est0)) > 4
    assert float(att[:, -1].abs().max()) < 1e-4 and float(rate[:, -1].max()) < 1e-6
    assert float((omega_est0 - omega_true[0]).norm()) > math.radians(0.03)


@pytest.mark.slow  # ~5 s on two loaded cores
def test_the_numbers_of_the_first_rate_map_are_kept():
    # computed by the solver this one replaced (commit 7be9713). It differenced the predictions, the shared core the
    # residuals: on this toy (values near zero) they round apart, and the rate columns' 1e-8 rad/s central step
    # magnifies that to ~1e-9 (on the renderer, whose magnitudes keep y − h exact, they agree bit for bit)
    _, _, y, q_est0, omega_est0 = toy_truth(60, [0.2, -0.1, 0.1], noise=0.2)
    dynamics = RateDynamics(omega_est0=omega_est0, p0_omega_deg_s=0.3, inertia=INERTIA, dt=1.0)
    est = map_with_rate(ToyModel(), q_est0=q_est0, dynamics=dynamics, observations=y + 0.3,
                        prior=MapPrior(10.0, 0.04, 0.5), checkpoints=[30, 60], offset=True)[60]
    x = [[0.0033952171417683504, 0.06955612981090177, 0.03380821066992267, 0.0012946520946624054,
          -0.0010433552818257738, 0.000898977865772054, 0.1950535475825989],
         [-0.038362299248640694, -0.051160525013074554, 0.08755176625342374, -0.001197904546594727,
          0.0006918846507866473, 0.0009374753701219442, 0.32163847454086236]]
    variances = [[0.02656109445244349, 0.016554843500349956, 0.006378368044372794, 2.3769600958606753e-05,
                  2.54962101849561e-05, 7.422264772764595e-06, 0.015163079911575797],
                 [0.027493813947887635, 0.018653205195797138, 0.00639750624043686, 2.4639592133481966e-05,
                  2.5404243743299374e-05, 6.518280807247336e-06, 0.0149774531099394]]
    torch.testing.assert_close(est.x, torch.tensor(x, dtype=DT), rtol=0, atol=1e-8)
    torch.testing.assert_close(est.covariance.diagonal(dim1=-2, dim2=-1), torch.tensor(variances, dtype=DT),
                               rtol=1e-7, atol=0)


@pytest.mark.parametrize("change, message", [
    ({"p0_omega_deg_s": 0.0}, r"filter.p0_omega_deg_s: 0.0 must be > 0"),
    ({"p0_omega_deg_s": float("nan")}, r"filter.p0_omega_deg_s: nan must be > 0"),
    ({"omega_est0": torch.zeros(2, dtype=DT)}, r"omega_est0: shape \(2,\), expected \(3,\)"),
    ({"inertia": torch.tensor([1.0, -1.0, 2.0], dtype=DT)}, r"inertia: \[1.0, -1.0, 2.0\] must be three positive"),
    ({"dt": 0.0}, r"dt: 0.0 must be > 0"),
])
def test_bad_dynamics_are_named(change, message):
    kwargs = dict(omega_est0=OMEGA0, p0_omega_deg_s=0.03, inertia=INERTIA, dt=1.0) | change
    with pytest.raises(ValueError, match=message):
        RateDynamics(**kwargs)


@pytest.mark.parametrize("checkpoints", [[], [0, 5], [5, 3], [5, 11]])
def test_bad_checkpoints_are_named(checkpoints):
    _, _, y, q_est0, omega_est0 = toy_truth(10, [0.0, 0.0, 0.0])
    dynamics = RateDynamics(omega_est0=omega_est0, p0_omega_deg_s=0.03, inertia=INERTIA, dt=1.0)
    with pytest.raises(ValueError, match=r"checkpoints: .* must be increasing step indices in 1 … 10"):
        map_with_rate(ToyModel(), q_est0=q_est0, dynamics=dynamics, observations=y, prior=MapPrior(10.0, 0.1),
                      checkpoints=checkpoints, offset=False)
