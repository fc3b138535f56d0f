"""Attitude: the bottom layer of the estimation physics — rotations, dynamics and how errors are measured.

* :mod:`.rotations` — scalar-last quaternions, the paper's product, ``A(q)`` (inertial → body), Euler 3-2-1, GRP.
* :mod:`.dynamics` — torque-free Euler equations and quaternion kinematics, fixed-step RK4, per-step increments.
* :mod:`.timeline` — increments between irregular sample times from a known spin.
* :mod:`.sampling` — attitudes on SO(3): the paper's icosphere grid, random and Sobol' draws.
* :mod:`.metrics` — attitude errors, windowed RMSE, NEES / NIS and their χ² bands.

It imports nothing of the package above it.
"""
