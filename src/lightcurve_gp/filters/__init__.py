"""Filters: the batched unscented quaternion estimator (USQUE) and what is built on it.

* :mod:`.usque` — :class:`~.usque.UsqueParams` and :func:`~.usque.run_usque`, the one filter loop.
* :mod:`.step` (ω known: the prediction as a rotation), :mod:`.rates` (ω in the state), :mod:`.update` (the shared
  measurement update), :mod:`.state` (state layout and history), :mod:`.unscented` (weights, square roots),
  :mod:`.offset` (the magnitude offset of an unknown ρ), :mod:`.compiled` (the step as compiled graphs, opt-in).
* :mod:`.setup` — from a config to ``P0``, ``b0``, ``θ0`` and the filter's parameters, in one place.
* :mod:`.selection` — the innovation log-likelihood; :mod:`.bank` — a bank of filters over SO(3) (MMAE).
"""
