"""Increments between irregular sample times from the known spin (lightcurve_gp.attitude.timeline)."""

import pytest
import torch

from lightcurve_gp.attitude.dynamics import propagate, quaternion_increments
from lightcurve_gp.attitude.rotations import quat_mul, quat_normalize
from lightcurve_gp.attitude.timeline import spin_increments, sub_steps

DT = torch.float64
OMEGA0 = torch.deg2rad(torch.tensor([0.1, -0.1, -0.25], dtype=DT)) * 20  # 20x the paper's rate: RK4 errors show
INERTIA = [55.0, 40.0, 65.0]
Q0 = quat_normalize(torch.tensor([0.1, -0.3, 0.2, 0.9], dtype=DT))


def apply(q0, increments):
    qs = [q0]
    for d in increments:
        qs.append(quat_normalize(quat_mul(d, qs[-1])))
    return torch.stack(qs)


def test_a_regular_grid_gives_the_scenarios_increments_bitwise():
    t = torch.arange(31, dtype=DT) * 1.0
    expected = quaternion_increments(OMEGA0, INERTIA, 1.0, 30)
    assert torch.equal(spin_increments(t, omega0=OMEGA0, inertia=INERTIA, max_step=1.0), expected)


def test_gaps_on_the_grid_land_on_the_regularly_propagated_attitudes():
    t_all = torch.arange(41, dtype=DT)
    keep = torch.tensor([0, 1, 2, 7, 8, 20, 21, 22, 40])
    q_regular, _ = propagate(Q0, OMEGA0, INERTIA, 1.0, 40)
    q_gaps = apply(Q0, spin_increments(t_all[keep], omega0=OMEGA0, inertia=INERTIA, max_step=1.0))
    assert torch.allclose(q_gaps, q_regular[keep], atol=1e-13)


@pytest.mark.slow  # ~6 s on two loaded cores
def test_irregular_steps_converge_to_the_true_motion():
    t = torch.tensor([0.0, 0.3, 1.1, 4.0, 4.05, 9.7, 15.0], dtype=DT)
    reference, _ = propagate(Q0, OMEGA0, INERTIA, 0.001, 15000)  # RK4 at 1 ms
    exact = reference[(t * 1000).round().long()]
    coarse = apply(Q0, spin_increments(t, omega0=OMEGA0, inertia=INERTIA, max_step=1.0))
    fine = apply(Q0, spin_increments(t, omega0=OMEGA0, inertia=INERTIA, max_step=0.1))
    err_coarse = float((coarse - exact).abs().max())
    err_fine = float((fine - exact).abs().max())
    assert err_coarse < 1e-6
    assert err_fine < err_coarse / 1000  # fourth order: 10x shorter sub-steps, ~1e4x smaller error


def test_sub_steps_are_no_longer_than_the_maximum():
    count, h = sub_steps(torch.tensor([0.0, 1.0, 3.5, 3.6], dtype=DT), 1.0)
    assert count.tolist() == [1, 3, 1]
    assert torch.allclose(h, torch.tensor([1.0, 2.5 / 3, 0.1], dtype=DT))
    with pytest.raises(ValueError, match="sample times must increase strictly"):
        sub_steps(torch.tensor([0.0, 1.0, 1.0], dtype=DT), 1.0)
