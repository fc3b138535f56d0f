"""Writing an astropy table in any of the light-curve formats (ECSV, CSV, FITS): CSV metadata as ``# key: value``
comment lines, FITS metadata as HIERARCH cards. Not atomic by itself: callers write to a temporary path and rename
(:class:`~lightcurve_gp.files.RunFolder`, :func:`~lightcurve_gp.observed.lightcurve_file.write_light_curve`)."""

from __future__ import annotations

import warnings
from pathlib import Path

import yaml
from astropy.table import Table

__all__ = ["write_table"]


def write_table(table: Table, path: str | Path, *, fmt: str) -> None:
    """Write a table in the astropy format ``fmt`` (not atomic: give it a temporary path); CSV metadata becomes
    ``# key: value`` comment lines."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # FITS: long metadata keys become HIERARCH cards, as intended
        if fmt == "ascii.csv":
            table = table.copy(copy_data=False)
            table.meta = {"comments": [f"{k}: {yaml.safe_dump(v, default_flow_style=True).strip()}"
                                       .removesuffix("\n...") for k, v in table.meta.items()]}
            table.write(path, format=fmt, comment="# ", overwrite=True)
        else:
            table.write(path, format=fmt, overwrite=True)
