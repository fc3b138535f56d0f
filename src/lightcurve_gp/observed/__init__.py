"""Observed: light curves from a telescope — the file format and the runs on a file.

* :mod:`.lightcurve_file` and :mod:`.times` — reading and writing light-curve files (ECSV, CSV, FITS), every bad
  file one line naming the file, the line or the column.
* :mod:`.run` — the filter on a file (from an initial attitude or the bank), its history and innovation statistics.
* :mod:`.verdict` — whether the bank's posterior is unique or ambiguous.
* :mod:`.solutions` — the inversion's solutions file.
* :mod:`.plots` — the figures of a run on a file.
"""
