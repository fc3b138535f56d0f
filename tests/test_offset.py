"""Reflectance as a magnitude offset: renderer identity, normalised targets, A(q) inputs, offset-augmented USQUE."""

import math
import warnings
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.rotations import attitude_matrix, quat_conj, quat_mul
from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.config.load import load_config
from lightcurve_gp.filters.offset import initial_offset, offset_covariance, offset_to_rho, rho_to_offset
from lightcurve_gp.filters.usque import UsqueParams, run_usque
from lightcurve_gp.observation.inputs import INPUT_KINDS, InputMap, attitude_matrix_features
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.training.sets import TrainingSet, model_targets, normalised_targets

from helpers import ToyModel, err_deg, scenario

DT = torch.float64
CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_rho_is_a_pure_magnitude_offset_where_the_curve_is_diffuse():
    cfg = load_config(CONFIGS / "boxwing.yaml")
    scene = Scene.from_config(cfg, dtype=DT)
    q = random_attitudes(300, seed=3, dtype=DT)
    diffuse, specular = scene.flux_parts(q, rho=0.5)
    keep = (diffuse > 0) & (specular < 1e-9 * diffuse)
    assert int(keep.sum()) > 50
    m05 = scene.magnitude(q[keep], rho=0.5)
    for rho in (0.3, 0.7):
        shift = scene.magnitude(q[keep], rho=rho) - m05
        assert torch.allclose(shift, torch.full_like(shift, rho_to_offset(rho, 0.5)), atol=1e-7)
    b = torch.tensor([rho_to_offset(r, 0.5) for r in (0.1, 0.5, 0.9)], dtype=DT)
    assert torch.allclose(offset_to_rho(b, 0.5), torch.tensor([0.1, 0.5, 0.9], dtype=DT), atol=1e-14)
    with pytest.raises(ValueError, match="positive"):
        rho_to_offset(0.0, 0.5)


def test_normalised_targets_collapse_every_rho_onto_the_reference_curve():
    m_ref = torch.tensor([12.0, 13.5, 14.2], dtype=DT)
    rho = torch.tensor([0.1, 0.7, 0.9], dtype=DT)
    y = m_ref + rho_to_offset(rho, 0.5)
    assert torch.allclose(normalised_targets(y, rho, 0.5), m_ref, atol=1e-12)
    ts = TrainingSet(torch.zeros(3, 4, dtype=DT), y - 0.2, y, rho)
    paper = load_config(CONFIGS / "boxwing.yaml")
    robust = load_config(CONFIGS / "boxwing_robust.yaml")
    assert model_targets(ts, paper.model) is ts  # the paper's GP sees raw magnitudes
    norm = model_targets(ts, robust.model)
    assert torch.allclose(norm.y, m_ref, atol=1e-12) and torch.allclose(norm.m_past, m_ref - 0.2, atol=1e-12)
    assert norm.q is ts.q and norm.rho is ts.rho
    with pytest.raises(ValueError, match="rho"):
        normalised_targets(y, torch.tensor([0.1, 0.0, 0.9], dtype=DT), 0.5)


def test_attitude_matrix_inputs_are_sign_invariant_and_measure_the_rotation_angle():
    assert INPUT_KINDS["quaternion"].dim == 5  # the paper's kind is untouched
    q = random_attitudes(50, seed=1, dtype=DT)
    p = random_attitudes(50, seed=2, dtype=DT)
    m = torch.zeros(50, dtype=DT)
    x, xp = attitude_matrix_features(q, m), attitude_matrix_features(p, m)
    assert torch.allclose(x, attitude_matrix_features(-q, m), atol=1e-15)
    assert torch.allclose(attitude_matrix_features(3.0 * q, m), x, atol=1e-14)  # normalised inside
    theta = 2 * torch.acos(quat_mul(q, quat_conj(p))[:, 3].abs().clamp(max=1.0))
    assert torch.allclose(((x - xp) ** 2).sum(-1), 4 * (1 - torch.cos(theta)), atol=1e-12)
    # the body-frame Sun direction A(q) s is a linear function of the features
    s = torch.tensor([0.3, -0.5, 0.81], dtype=DT)
    assert torch.allclose(x.view(50, 3, 3) @ s, attitude_matrix(q) @ s, atol=1e-14)
    assert InputMap("attitude_matrix").dim == 9


@pytest.mark.slow  # ~3 s on two loaded cores
def test_known_offset_reduces_to_usque_with_matching_sigma_spread():
    """With b known (variance → 0), n = 4 and λ = 0 spread and weigh the attitude sigma points exactly like
    USQUE with n = 3 and λ = 1 (the two b sigma points coincide with the centre): same estimates."""
    q_true, y, q_est0, inc = scenario(B=3, T=60, noise=0.01)
    b_true = 0.8
    base = dict(Q=1e-8, R=1e-4, variance="none")
    h3 = run_usque(model=ToyModel(), q_est0=q_est0, P0=1e-2 * torch.eye(3, dtype=DT), observations=y, m_past0=y[:, 0],
                   increments=inc, params=UsqueParams(lam=1.0, **base))
    P0 = offset_covariance(math.degrees(0.1), 1e-7, dtype=DT)
    h4 = run_usque(model=ToyModel(), q_est0=q_est0, P0=P0, offset0=torch.tensor(b_true, dtype=DT),
                   observations=y + b_true, m_past0=y[:, 0], increments=inc, params=UsqueParams(lam=0.0, **base))
    assert torch.allclose(h4.q_est, h3.q_est, atol=1e-6)
    assert torch.allclose(h4.y_pred[:, 1:] - b_true, h3.y_pred[:, 1:], atol=1e-6)
    assert torch.allclose(h4.offset, torch.full_like(h4.offset, b_true), atol=1e-6)


def test_unknown_offset_is_learned_and_a_blind_filter_is_not():
    """Attitude known to 0.1°: the offset must converge to the truth within its own uncertainty, while plain
    USQUE, blind to the offset, absorbs it into a wrong attitude."""
    q_true, y, _, inc = scenario(B=4, T=150, noise=0.01, seed=5)
    b_true = torch.tensor([-0.6, 0.0, 0.4, 1.1], dtype=DT)
    obs = y + b_true[:, None]
    model = ToyModel()
    q_est0 = q_true[:, 0]
    b0 = initial_offset(model, q_est0, obs[:, 0], obs[:, 0])
    assert torch.allclose(b0, b_true, atol=0.05)  # ỹ_0 − h(q̂_0): only the noise separates them
    P0 = offset_covariance(0.1, 1.0, dtype=DT)
    params = UsqueParams(Q=1e-10, R=1e-4, variance="none")
    h = run_usque(model=model, q_est0=q_est0, P0=P0, offset0=torch.zeros(4, dtype=DT), observations=obs,
                  m_past0=obs[:, 0], increments=inc, params=params)
    err_b = (h.offset[:, -1] - b_true).abs()
    assert bool((err_b < 4 * h.offset_var[:, -1].sqrt()).all()) and float(err_b.max()) < 0.01
    assert float(err_deg(q_true[:, -1], h.q_est[:, -1]).max()) < 0.5
    assert h.P.shape == (4, 151, 3, 3) and torch.equal(h.P, h.P_full[..., :3, :3])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        blind = run_usque(model=model, q_est0=q_est0, P0=P0[:3, :3], observations=obs, m_past0=obs[:, 0],
                          increments=inc, params=params)
    assert float(err_deg(q_true[-1:, -1], blind.q_est[-1:, -1]).max()) > 5.0


def test_bad_inputs_name_the_argument():
    q_true, y, q_est0, inc = scenario(B=2, T=5)
    with pytest.raises(ValueError, match="P0"):
        run_usque(model=ToyModel(), q_est0=q_est0, P0=torch.eye(3, dtype=DT), offset0=torch.zeros(2, dtype=DT),
                  observations=y, m_past0=y[:, 0], increments=inc)
    with pytest.raises(ValueError, match="offset0"):
        run_usque(model=ToyModel(), q_est0=q_est0, P0=torch.eye(4, dtype=DT), offset0=torch.zeros(3, dtype=DT),
                  observations=y, m_past0=y[:, 0], increments=inc)
    with pytest.raises(ValueError, match="^offset_process_noise must be >= 0, got -1.0$"):
        UsqueParams(offset_process_noise=-1.0)


def test_paper_config_keeps_the_paper_behaviour_and_robust_config_enables_the_offset():
    paper = load_config(CONFIGS / "boxwing.yaml")
    assert (paper.model.inputs, paper.model.target, paper.filter.estimate_offset) == ("quaternion", "magnitude", False)
    robust = load_config(CONFIGS / "boxwing_robust.yaml")
    assert robust.filter.estimate_offset and robust.model.inputs == "attitude_matrix"
    assert robust.model.rho_reference in robust.data.rho_grid
