"""Inference over whole arcs: one least-squares core, the batch MAP problems, the bound and the global inversion.

* :mod:`.solver` — batched Gauss–Newton / Levenberg–Marquardt over ``B`` independent problems, Laplace covariance;
  :mod:`.jacobian` — Jacobians of batched residual functions (forward mode, finite differences, or provided).
* :mod:`.attitude` (:func:`~.attitude.map_known_rate`), :mod:`.surface` (:func:`~.surface.map_with_surface`),
  :mod:`.spin` (:func:`~.spin.map_with_rate`) — the batch MAP of the initial attitude with the rate known, with the
  surface (or an offset) unknown, with the rate unknown.
* :mod:`.crb` — the Cramér–Rao bound of a light curve, the reference beside every RMSE.
* :mod:`.periodogram`, :mod:`.forward`, :mod:`.trajectory`, :mod:`.inversion`, :mod:`.families` — the global
  inversion: rate candidates, the fast forward model and its Jacobian, the batched multi-start search, and the
  solutions grouped modulo the exact ambiguity group with their weights.
"""
