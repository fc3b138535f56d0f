"""Time of the closed-form torque-free propagation (:func:`lightcurve_gp.attitude.torque_free.torque_free_motion`)
against the fixed-step RK4 that the inversion used before it (``propagate_rates`` on the ``dt`` grid, kept below as
the baseline), for ``R`` rates × ``K`` samples on one thread (median of ``--repeats``; the load average beside
them: on a shared machine the wall time is the CPU time stretched by the other processes).

Rows: 10^4 rates × 600 samples at 1 s (the screening's shape), the same samples spread over ten days (RK4 would
step 864000 times: its time is estimated from the 1 s row's time per step, not run), and the small batches a
Levenberg–Marquardt stage propagates (rows × 4 shifted rates). The last column is the largest rotation angle
between the two on the 1 s grid (RK4's own error). The row "RK4 to 1e-10 rad" runs RK4 with the fewest sub-steps
per second (found on 64 of the rates, doubling) whose largest angle from the closed form is within ``--tolerance``:
the two at the same accuracy.

    python benchmarks/bench_propagation.py --repeats 3
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import torch
from torch import Tensor

from lightcurve_gp.attitude.dynamics import rk4_rate_stages
from lightcurve_gp.attitude.rotations import quat_conj, quat_mul
from lightcurve_gp.attitude.torque_free import torque_free_motion

INERTIA = [55.0, 40.0, 65.0]  # the box-wing's (kg m²)


# --------------------------------------------------------------------------------------------- the RK4 baseline

def _product(a: Tensor, b: Tensor) -> Tensor:
    """``a ⊗ b`` of quaternions stored components first ``(4, ...)``."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return torch.stack([aw * bx + bw * ax - (ay * bz - az * by), aw * by + bw * ay - (az * bx - ax * bz),
                        aw * bz + bw * az - (ax * by - ay * bx), aw * bw - ax * bx - ay * by - az * bz])


def _pure_times(w: Tensor, p: Tensor) -> Tensor:
    """``[w; 0] ⊗ p`` with ``w (3, ...)``, ``p (4, ...)`` components first."""
    wx, wy, wz = w
    px, py, pz, pw = p
    return torch.stack([pw * wx - (wy * pz - wz * py), pw * wy - (wz * px - wx * pz), pw * wz - (wx * py - wy * px),
                        -(wx * px + wy * py + wz * pz)])


def _rk4_step(w: Tensor, c: Tensor, dt: float) -> tuple[Tensor, Tensor]:
    """One RK4 step of the rates ``w (3, ...)`` and its kinematic increment ``δ (4, ...)``."""
    rate = lambda v: c * torch.stack([v[1] * v[2], v[2] * v[0], v[0] * v[1]])  # noqa: E731
    (_, w2, w3, w4), w_next = rk4_rate_stages(w, rate, dt)
    one = torch.zeros_like(w[:1]).expand(4, *w.shape[1:]).clone()
    one[3] = 1.0
    pure1 = torch.cat([w, torch.zeros_like(w[:1])])
    t2 = _pure_times(w2, one + (0.25 * dt) * pure1)
    t3 = _pure_times(w3, one + (0.25 * dt) * t2)
    t4 = _pure_times(w4, one + (0.5 * dt) * t3)
    return one + (dt / 12.0) * (pure1 + 2.0 * t2 + 2.0 * t3 + t4), w_next


def rk4_propagate_rates(omega0: Tensor, *, inertia: Tensor, dt: float, index: Tensor) -> Tensor:
    """The previous ``inference.forward.propagate_rates``: RK4 through every ``dt`` step up to the last sample,
    ``Δ (..., K, 4)`` at the grid steps ``index (K,)``."""
    j = torch.as_tensor(inertia, dtype=omega0.dtype)
    c = ((j.roll(-1) - j.roll(-2)) / j).reshape(3, *([1] * (omega0.ndim - 1)))
    w = omega0.movedim(-1, 0).contiguous()
    q = torch.zeros(4, *omega0.shape[:-1], dtype=omega0.dtype)
    q[3] = 1.0
    out = [q]
    for _ in range(int(index[-1])):
        delta, w = _rk4_step(w, c, dt)
        q = _product(delta, q)
        q = q / torch.sqrt((q * q).sum(0, keepdim=True))
        out.append(q)
    picked = torch.stack([out[i] for i in index.tolist()])
    return picked.movedim(0, -1).movedim(0, -1)


# --------------------------------------------------------------------------------------------- timing

def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def max_angle(a: Tensor, b: Tensor) -> float:
    r = quat_mul(a, quat_conj(b))
    return float((2.0 * torch.atan2(r[..., :3].norm(dim=-1), r[..., 3].abs())).max())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--rate-deg-s", type=float, default=1.0, help="rms body rate per axis of the random rates")
    parser.add_argument("--tolerance", type=float, default=1e-10, help="rad: the same-accuracy row's RK4 error")
    args = parser.parse_args()
    torch.set_num_threads(1)
    inertia = torch.tensor(INERTIA, dtype=torch.float64)
    gen = torch.Generator().manual_seed(0)
    print(f"torch threads {torch.get_num_threads()}, cores {os.cpu_count()}, float64, box-wing inertia {INERTIA}")
    print("| rates × samples | span | closed form s | RK4 s | RK4 / closed form | max angle closed vs RK4 (rad) | "
          "load |")
    print("|---|---|---|---|---|---|---|")
    for rates, samples in ((10_000, 600), (64, 600), (16, 150)):
        omega = torch.deg2rad(args.rate_deg_s * torch.randn(rates, 3, generator=gen, dtype=torch.float64))
        index = torch.arange(samples)
        times = index.to(torch.float64)
        closed = median_time(lambda: torque_free_motion(omega, inertia=inertia, times=times), args.repeats)
        rk4 = median_time(lambda: rk4_propagate_rates(omega, inertia=inertia, dt=1.0, index=index), args.repeats)
        err = max_angle(torque_free_motion(omega, inertia=inertia, times=times)[0],
                        rk4_propagate_rates(omega, inertia=inertia, dt=1.0, index=index))
        print(f"| {rates} × {samples} | {samples - 1} s at 1 s | {closed:.3f} | {rk4:.3f} | {rk4 / closed:.1f} | "
              f"{err:.1e} | {os.getloadavg()[0]:.1f} |")
        if rates == 10_000:
            probe, sub = omega[:64], 1
            exact = torque_free_motion(probe, inertia=inertia, times=times)[0]
            while max_angle(exact, rk4_propagate_rates(probe, inertia=inertia, dt=1.0 / sub, index=index * sub)) \
                    > args.tolerance and sub < 256:
                sub *= 2
            fine = median_time(lambda: rk4_propagate_rates(omega, inertia=inertia, dt=1.0 / sub, index=index * sub),
                               args.repeats)
            err_fine = max_angle(torque_free_motion(omega, inertia=inertia, times=times)[0],
                                 rk4_propagate_rates(omega, inertia=inertia, dt=1.0 / sub, index=index * sub))
            print(f"| {rates} × {samples} | {samples - 1} s at 1 s, RK4 to {args.tolerance:.0e} rad ({sub} steps per "
                  f"s) | {closed:.3f} | {fine:.3f} | {fine / closed:.1f} | {err_fine:.1e} | "
                  f"{os.getloadavg()[0]:.1f} |")
            far = torch.linspace(0.0, 864000.0, samples, dtype=torch.float64)
            closed_far = median_time(lambda: torque_free_motion(omega, inertia=inertia, times=far), args.repeats)
            rk4_far = rk4 * 864000 / (samples - 1)
            print(f"| {rates} × {samples} | 10 days | {closed_far:.3f} | ~{rk4_far:.0f} (estimated: 864000 steps "
                  f"at the 1 s row's time per step) | ~{rk4_far / closed_far:.0f} | — | {os.getloadavg()[0]:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
