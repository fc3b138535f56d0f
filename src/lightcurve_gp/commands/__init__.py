"""Commands: the command-line programs, thin over the library (``python -m lightcurve_gp.<command>``).

* :mod:`.common` — options, the thread policy, progress, one-line errors, interrupts, provenance.
* :mod:`.layout` — where every command writes under ``--out`` (training runs, the model store, estimates, sweeps).
* :mod:`.train`, :mod:`.estimate` (+ :mod:`.estimate_file` for ``--light-curve``), :mod:`.simulate`,
  :mod:`.invert` — one module per command; ``lightcurve-gp COMMAND`` dispatches to them (``lightcurve_gp.__main__``).

A command checks every input before any computation and only writes what the library returns.
"""
