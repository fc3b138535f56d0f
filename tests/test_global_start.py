"""The global-start bank's attitudes cover SO(3)."""

import torch

from lightcurve_gp.attitudes import random_attitudes
from lightcurve_gp.global_start import bank_attitudes


def nearest_angle_deg(q: torch.Tensor, bank: torch.Tensor) -> torch.Tensor:
    """Rotation angle from each attitude ``q (n, 4)`` to its nearest bank member (sign invariant)."""
    return torch.rad2deg(2 * torch.acos((q @ bank.T).abs().amax(1).clamp(max=1.0)))


def test_a_bank_of_1024_leaves_no_attitude_far_from_a_member():
    bank = bank_attitudes(1024)
    angles = nearest_angle_deg(random_attitudes(2000, seed=11, dtype=torch.float64), bank)
    # a uniform set of N points covers balls of angle r with (r - sin r)/pi = 1/N: r = 15.4 deg for N = 1024
    assert float(angles.quantile(0.95)) < 22.0
    assert float(angles.median()) < 15.4


def test_members_are_distinct_unit_quaternions():
    bank = bank_attitudes(1024)
    assert torch.allclose(bank.norm(dim=-1), torch.ones(1024, dtype=torch.float64), atol=1e-12)
    gram = (bank @ bank.T).abs() - torch.eye(1024, dtype=torch.float64)
    assert float(gram.max()) < 0.9999  # no two members within 1.6 deg of each other
