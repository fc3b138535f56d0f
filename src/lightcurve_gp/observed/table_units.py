"""Units on every column of every table the package writes (light-curve files, truth sidecars, attitude histories,
bank members, solutions).

Each writer names the unit of each of its numeric columns (astropy unit strings: ``"deg"``, ``"deg / s"``,
``"mag"``, ``"km"``, ``"s"``, ``""`` for a dimensionless one) and a description of each text column (e.g. ISO UTC
times); :func:`set_units` sets them and refuses a column left without one, so a column added later cannot be
written without its unit. ECSV and FITS store the units (a dimensionless column as ``unit: ''``); CSV has no place
for them.
"""

from __future__ import annotations

from typing import Mapping

import astropy.units as u
from astropy.table import Table

__all__ = ["ISO_UTC", "QUATERNION", "set_units"]

#: the description of a time column written as ISO 8601 UTC strings
ISO_UTC = "ISO 8601 UTC"
#: the unit of a quaternion component (scalar last, inertial -> body)
QUATERNION = ""


def set_units(table: Table, units: Mapping[str, str], descriptions: Mapping[str, str] | None = None) -> Table:
    """Set each numeric column's unit from ``units`` and each text column's description from ``descriptions``;
    returns ``table`` (changed in place).

    Raises:
        ValueError: a column of ``table`` that ``units`` (numeric) or ``descriptions`` (text) does not name; the
            message names the column (a writer's mistake, never the user's).
    """
    descriptions = descriptions or {}
    for name in table.colnames:
        column = table[name]
        if column.dtype.kind in "USO":
            if name not in descriptions:
                raise ValueError(f"column {name}: a text column written without a description")
            column.description = descriptions[name]
        elif name not in units:
            raise ValueError(f"column {name}: written without a unit (say '' for a dimensionless one)")
        else:
            column.unit = u.Unit(units[name]) if units[name] else u.dimensionless_unscaled
            if name in descriptions:
                column.description = descriptions[name]
    return table
