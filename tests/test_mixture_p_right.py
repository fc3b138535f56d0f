"""The probability that a family's mode is right under the whole posterior mixture: the other families' mass within
its tolerance, against closed forms (modes along one axis, normal spreads), through the group's images, and equal
to ``weight · mass`` where no other family reaches it."""

import math

import pytest
import torch

from lightcurve_gp.attitude.rotations import matrix_to_quat, quat_mul, rotvec_to_quat
from lightcurve_gp.inference.families import MASS_DRAWS, RIGHT_ANGLE_DEG, mixture_p_right, tolerance_mass
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup

F64 = torch.float64
IDENTITY = torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=F64)
ALONE = AmbiguityGroup(body=IDENTITY, inertial=IDENTITY, labels=("identity",), rate_known=False)


def _yaw(deg: list[float]) -> torch.Tensor:
    """Attitudes ``(F, 4)`` turned about z by ``deg``: all commute, the 3-2-1 error of two is their yaw difference."""
    return rotvec_to_quat(torch.tensor([[0.0, 0.0, math.radians(d)] for d in deg], dtype=F64))


def _p(q: torch.Tensor, *, weight: list[float], cov: torch.Tensor, omega: torch.Tensor | None = None,
       group: AmbiguityGroup = ALONE) -> tuple[torch.Tensor, torch.Tensor]:
    n = q.shape[0]
    omega = torch.tensor([[0.0, 0.0, 0.02]], dtype=F64).expand(n, 3) if omega is None else omega
    covariance = cov.expand(n, 7, 7)
    w = torch.tensor(weight, dtype=F64)
    mass = tolerance_mass(q, omega, covariance)
    return mixture_p_right(group, q0=q, omega0=omega, covariance=covariance, weight=w, mass=mass), w * mass


def _sharp() -> torch.Tensor:
    return torch.diag(torch.tensor([1e-10] * 3 + [1e-14] * 3 + [1e-4], dtype=F64))


def test_one_family_is_its_weight_times_its_mass():
    cov = torch.diag(torch.tensor([1e-2] * 3 + [1e-6] * 3 + [1e-2], dtype=F64))
    got, own = _p(_yaw([30.0]), weight=[1.0], cov=cov)
    assert torch.equal(got, own)


def test_a_sharp_neighbour_within_the_tolerance_adds_its_whole_weight_and_a_far_one_nothing():
    got, own = _p(_yaw([0.0, 3.0, 40.0]), weight=[0.5, 0.3, 0.2], cov=_sharp())
    assert own.tolist() == pytest.approx([0.5, 0.3, 0.2])  # sharp: every draw is right about its own mode
    # 0 and 3° reach each other, 40° neither: systematic allocation gives round(w · draws) draws each
    assert got.tolist() == pytest.approx([0.8, 0.8, 0.2], abs=1.0 / MASS_DRAWS)


def test_the_cross_term_of_a_normal_spread_is_the_normal_mass_within_the_angle():
    s, d = math.radians(4.0), 8.0
    cov = torch.zeros(7, 7, dtype=F64)
    cov[2, 2] = s * s  # δθ about z only: a draw of the second family is at yaw d + δ from the first mode
    got, own = _p(_yaw([0.0, d]), weight=[0.5, 0.5], cov=cov)
    a = math.radians(RIGHT_ANGLE_DEG)
    phi = lambda x: 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))  # noqa: E731
    reach = phi((a - math.radians(d)) / s) - phi((-a - math.radians(d)) / s)  # P(|d + δ| < 10°)
    n_other = MASS_DRAWS // 2
    sd = math.sqrt(n_other * reach * (1.0 - reach)) / MASS_DRAWS
    assert float(got[0] - own[0]) == pytest.approx(0.5 * reach, abs=5.0 * sd)
    assert float(got[1] - own[1]) == pytest.approx(0.5 * reach, abs=5.0 * sd)


def test_a_rate_beyond_two_percent_is_no_neighbour():
    q = _yaw([0.0, 0.0, 0.0])
    omega = torch.tensor([[0.0, 0.0, 0.02], [0.0, 0.0, 0.0202], [0.0, 0.0, 0.0208]], dtype=F64)  # +1 %, +4 %
    got, _ = _p(q, weight=[0.4, 0.3, 0.3], cov=_sharp(), omega=omega)
    # the truth's rate sets the 2 %: 0 and 1 reach each other; 2 is 3.8 % of its rate from 0, 2.9 % from 1
    assert got.tolist() == pytest.approx([0.7, 0.7, 0.3], abs=1.0 / MASS_DRAWS)


def test_an_image_of_the_neighbour_counts_and_without_the_group_it_does_not():
    turn = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=F64))  # a body 180° turn about x
    group = AmbiguityGroup(body=torch.cat([IDENTITY, matrix_to_quat(turn)[None]]), inertial=IDENTITY.expand(2, 4),
                           labels=("identity", "body 180° x"), rate_known=False)
    q_f = _yaw([20.0])
    omega_f = torch.tensor([[0.01, 0.005, 0.02]], dtype=F64)
    near = _yaw([24.0])  # 4° from q_f …
    q_g = quat_mul(matrix_to_quat(turn)[None], near)  # … seen through the turn
    omega_g = (turn @ omega_f.T).T
    q, omega = torch.cat([q_f, q_g]), torch.cat([omega_f, omega_g])
    with_group, _ = _p(q, weight=[0.6, 0.4], cov=_sharp(), omega=omega, group=group)
    alone, own = _p(q, weight=[0.6, 0.4], cov=_sharp(), omega=omega)
    assert with_group.tolist() == pytest.approx([1.0, 1.0], abs=1.0 / MASS_DRAWS)
    assert torch.equal(alone, own)
