"""Increments between irregular sample times from the known spin (lightcurve_gp.attitude.timeline)."""

import time

import pytest
import torch

from lightcurve_gp.attitude.dynamics import propagate, quaternion_increments
from lightcurve_gp.attitude.rotations import quat_conj, quat_mul, quat_normalize
from lightcurve_gp.attitude.timeline import spin_increments
from lightcurve_gp.attitude.torque_free import torque_free_motion

DT = torch.float64
OMEGA0 = torch.deg2rad(torch.tensor([0.1, -0.1, -0.25], dtype=DT)) * 20  # 20x the paper's rate: RK4 errors show
INERTIA = [55.0, 40.0, 65.0]
Q0 = quat_normalize(torch.tensor([0.1, -0.3, 0.2, 0.9], dtype=DT))


def apply(q0, increments):
    qs = [q0]
    for d in increments:
        qs.append(quat_normalize(quat_mul(d, qs[-1])))
    return torch.stack(qs)


def angle(a, b):
    r = quat_mul(a, quat_conj(b))
    return float((2.0 * torch.atan2(r[..., :3].norm(dim=-1), r[..., 3].abs())).max())


def test_a_regular_grid_agrees_with_the_scenarios_rk4_increments_to_rk4s_error():
    t = torch.arange(31, dtype=DT) * 1.0
    closed = spin_increments(t, omega0=OMEGA0, inertia=INERTIA)
    rk4 = quat_normalize(quaternion_increments(OMEGA0, INERTIA, 1.0, 30))
    assert 1e-10 < angle(closed, rk4) < 1e-8
    # RK4's local error shrinks as h^5: ten 0.1 s sub-steps compose an increment ~1e4 times closer
    sub = quaternion_increments(OMEGA0, INERTIA, 0.1, 10)
    composed = sub[0]
    for d in sub[1:]:
        composed = quat_mul(d, composed)
    assert angle(closed[0], quat_normalize(composed)) < angle(closed[0], rk4[0]) / 3e3


def test_gaps_land_on_the_regularly_propagated_attitudes():
    t_all = torch.arange(41, dtype=DT)
    keep = torch.tensor([0, 1, 2, 7, 8, 20, 21, 22, 40])
    q_regular, _ = propagate(Q0, OMEGA0, INERTIA, 0.01, 4000)  # RK4 at 10 ms
    q_gaps = apply(Q0, spin_increments(t_all[keep], omega0=OMEGA0, inertia=INERTIA))
    assert angle(q_gaps, q_regular[keep * 100]) < 1e-11


@pytest.mark.slow
def test_irregular_times_compose_to_the_closed_form_motion():
    t = torch.tensor([5.0, 5.3, 6.1, 9.0, 9.05, 14.7, 20.0], dtype=DT)  # the first sample at 5 s
    increments = spin_increments(t, omega0=OMEGA0, inertia=INERTIA)
    delta, _ = torque_free_motion(OMEGA0, inertia=INERTIA, times=t - 5.0)
    assert angle(apply(Q0, increments), quat_mul(delta, Q0)) < 1e-14
    assert float((increments[:, 3]).min()) > 0  # short steps: increments near the identity, not their negatives
    reference, _ = propagate(Q0, OMEGA0, INERTIA, 0.001, 15000)  # RK4 at 1 ms
    assert angle(apply(Q0, increments), reference[((t - 5.0) * 1000).round().long()]) < 1e-11


def test_a_ten_day_file_takes_no_steps_through_its_gaps():
    g = torch.Generator().manual_seed(0)
    t = torch.cat([torch.arange(300, dtype=DT), 864000.0 - torch.arange(300, 0, -1, dtype=DT),
                   torch.rand(100, generator=g, dtype=DT) * 8e5 + 400.0]).sort().values
    start = time.perf_counter()
    increments = spin_increments(t, omega0=OMEGA0, inertia=INERTIA)
    assert time.perf_counter() - start < 5.0  # 864000 RK4 steps took 10-40 minutes
    assert increments.shape == (699, 4) and bool(torch.isfinite(increments).all())
    delta, _ = torque_free_motion(OMEGA0, inertia=INERTIA, times=t[-1:] - t[0])
    assert angle(apply(Q0, increments)[-1], quat_mul(delta[0], Q0)) < 1e-10


def test_times_must_increase_strictly():
    with pytest.raises(ValueError, match="sample times must increase strictly"):
        spin_increments(torch.tensor([0.0, 1.0, 1.0], dtype=DT), omega0=OMEGA0, inertia=INERTIA)


def test_a_float32_run_gets_float64_accurate_increments_of_a_long_file():
    t = torch.tensor([0.0, 1.0, 2.0, 86400.0 * 3, 86400.0 * 3 + 1.0], dtype=DT)
    single = spin_increments(t, omega0=OMEGA0.float(), inertia=INERTIA)
    assert single.dtype == torch.float32
    double = spin_increments(t, omega0=OMEGA0.float().double(), inertia=INERTIA)  # the same rate, in float64
    assert angle(single.double(), double) < 1e-6  # float32 times at 3 days alone are 0.03 s apart: 3e-4 rad here
