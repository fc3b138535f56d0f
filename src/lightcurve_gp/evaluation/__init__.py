"""Evaluation: estimators by name, run side by side on a scenario, scored and reported.

* :mod:`.registry` — every estimator's name and how it runs (filters from :mod:`lightcurve_gp.filters`, the batch
  MAP from :mod:`lightcurve_gp.inference`).
* :mod:`.harness` — :func:`~.harness.run_estimators`: the chosen estimators on one scenario, all seeds batched.
* :mod:`.scoring` — per-seed RMSE, NEES, whitened errors and the scores modulo the exact ambiguities.
* :mod:`.reporting` — per-seed rows, case records, the one quantile summary, Markdown and CSV tables.
* :mod:`.suite_summary` — the generalisation suite's rows and grouped summaries.
* :mod:`.plots` — figures.
"""
