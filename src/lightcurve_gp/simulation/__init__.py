"""Simulation: truths and their noisy light curves.

* :mod:`.scenario` — :class:`~.scenario.Scenario`, ``S`` truths with a seed dimension (the paper's case, random
  truths, a pass), and their observations.
* :mod:`.truths` — the random draws of the generalisation suite and the paper's case in the same form.
"""
