"""A light-curve text file's lines as a spreadsheet saves them, made the same file as one written by hand.

Spreadsheets save CSV with a UTF-8 byte-order mark, CRLF line ends and, in locales whose decimal mark is a comma,
``;`` between the columns and ``5,1`` for 5.1. :func:`text_lines` decodes the file with the mark dropped and splits
it on any line end (``\\n``, ``\\r\\n``, ``\\r``), one entry per line of the file, so line ``N`` of a message is line
``N`` of the file. :func:`csv_dialect` tells a ``;``-separated table from a comma-separated one by its column-name
line (``;`` in it, no ``,``), and :func:`decimal_points` rewrites, in a ``;``-separated table only, every data field
that is a number with a decimal comma (``5,1``, ``-0,25``, ``1,5e-3``) with a point; a field with a comma that is
not such a number (a time, text) is left as it is and named by the column's own check. A comma-separated table
with decimal commas cannot be told from one with more columns; its fields are whatever the quoting says.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

__all__ = ["CsvDialect", "text_lines", "data_line_numbers", "csv_dialect", "decimal_points"]

#: a number written with a decimal comma (and no point), optionally with an exponent
DECIMAL_COMMA = re.compile(r"^\s*[+-]?(\d+,\d*|,\d+)([eE][+-]?\d+)?\s*$")


@dataclass(frozen=True)
class CsvDialect:
    """How a CSV file separates its columns: ``delimiter`` (``","`` or ``";"``) and ``decimal`` (``"."``, or
    ``","`` for a ``;``-separated file)."""

    delimiter: str = ","
    decimal: str = "."


def text_lines(path: Path) -> list[str]:
    """The lines of the text file ``path`` without line ends, decoded as UTF-8 with a leading byte-order mark
    dropped (bytes that are not UTF-8 become U+FFFD and are named by the column that holds them)."""
    return path.read_bytes().decode("utf-8-sig", errors="replace").splitlines()


def _is_data(text: str) -> bool:
    return bool(text.strip()) and not text.lstrip().startswith("#")


def data_line_numbers(lines: list[str]) -> list[int]:
    """The 1-based numbers of the lines that are neither blank nor comments (the column names, then the rows)."""
    return [i for i, text in enumerate(lines, 1) if _is_data(text)]


def csv_dialect(lines: list[str]) -> CsvDialect:
    """The dialect of a CSV file's ``lines``: ``;``-separated with decimal commas when its column-name line has a
    ``;`` and no ``,``, else comma-separated."""
    header = next((text for text in lines if _is_data(text)), "")
    return CsvDialect(";", ",") if ";" in header and "," not in header else CsvDialect()


def decimal_points(lines: list[str], dialect: CsvDialect) -> list[str]:
    """``lines`` with every decimal-comma number of a data row written with a point (only when ``dialect.decimal``
    is ``","``); comments, blank lines and the column names unchanged."""
    if dialect.decimal != ",":
        return lines
    out, header_seen = [], False
    for text in lines:
        if _is_data(text) and header_seen:
            text = dialect.delimiter.join(field.replace(",", ".") if DECIMAL_COMMA.match(field) else field
                                          for field in text.split(dialect.delimiter))
        header_seen = header_seen or _is_data(text)
        out.append(text)
    return out
