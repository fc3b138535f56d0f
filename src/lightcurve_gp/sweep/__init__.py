"""``python -m lightcurve_gp.sweep CONFIG --grid KEY=V1,V2,... --seeds N``: resumable parameter sweeps.

A sweep is the cartesian product of its grid axes (any config key, values parsed as YAML; :mod:`.grid`). Each grid
point is a *case*: one validated config, run with every seed batched in one filter per estimator
(:func:`~lightcurve_gp.evaluation.harness.run_estimators`; :mod:`.runner`). Storage (the command's ``--out``
``OUT`` gives ``out = OUT/sweeps`` and ``store = OUT/models``, :mod:`lightcurve_gp.commands.layout`):

* ``<store>/<model-key>/model.pt`` (+ ``metrics.json``): the model store (:mod:`lightcurve_gp.training.store`,
  default ``<out>/models``), one GP per distinct ``geometry``, ``shape``, ``surface``, ``data``, ``model`` setting
  (and dtype), trained once — by ``train`` or a sweep — and reused by every case, sweep and rerun that needs it
  (:mod:`.models`);
* ``<out>/<name>/cases/<case-id>.json``: one atomic file per finished case
  (:class:`~lightcurve_gp.evaluation.reporting.CaseRecord`), content-addressed — the case id hashes the whole
  config, the seeds and the estimators — so identical cases are shared between sweeps and a rerun skips them
  (:mod:`.store`). It holds the per-(seed, estimator) rows, the estimators' summary and the seed-0 traces for
  figures. A case that raised is stored with ``status = "failed"`` and its error; a rerun retries it.
* ``<out>/<name>/sweep/<sweep-id>/``: ``sweep.json`` (the definition), ``results.csv`` (one row per case × seed ×
  estimator, :data:`~lightcurve_gp.evaluation.reporting.RESULT_COLUMNS` after the grid columns), ``summary.csv`` and
  ``summary.json`` (median and IQR per case and estimator; :mod:`.tables`).

Where the trainings and the cases run is the sweep's *executor* (:mod:`.executors`): this process, a local pool of
spawned processes, or a ``dask.distributed`` cluster (the optional ``cluster`` extra). Whichever it is, the models
are trained first, one task per distinct model, then the cases run and each record is stored by this process the
moment it arrives, so the store is the same, and resumable, whichever executor wrote it.

Config errors (unknown key, bad value) stop the sweep before any work and name the key; a run-time failure of one
case is recorded and the others go on; a case whose worker process died is run again (a bounded number of times).
Ctrl-C keeps every finished case.

The package face imports nothing (torch loads only with a submodule), so ``python -m lightcurve_gp.sweep`` can turn a
Ctrl-C during its imports into one line: import the names from their modules (``.runner``, ``.executors``, ``.cli``,
…).
"""
