"""Batch maximum-a-posteriori estimation over whole arcs: one least-squares core, three MAP problems on it.

* :mod:`.solver` — batched Gauss–Newton / Levenberg–Marquardt over ``B`` independent problems, Laplace covariance;
* :mod:`.jacobian` — Jacobians of batched residual functions (forward mode, central or forward differences);
* :mod:`.attitude` — :func:`~.attitude.map_known_rate`: the initial attitude (± offset) along known increments, any
  observation model;
* :mod:`.surface` — :func:`~.surface.map_with_surface`: the renderer's attitude with the surface (or offset) unknown,
  per-seed dynamics, with its Laplace covariance at every checkpoint;
* :mod:`.spin` — :func:`~.spin.map_with_rate`: the initial attitude and body rate (± offset), each evaluation
  propagating its own torque-free trajectory.
"""
