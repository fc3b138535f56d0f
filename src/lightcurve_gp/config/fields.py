"""A config field with its validation rule and its hash rule (:mod:`lightcurve_gp.config.schema`'s module docstring
says what each rule means): what every section's dataclass is declared with."""

from __future__ import annotations

import dataclasses
from dataclasses import field
from typing import Any

__all__ = ["spec", "hash_rule"]


def spec(default: Any = dataclasses.MISSING, *, lo: float | None = None, hi: float | None = None,
          lo_open: bool = False, choices: tuple | None = None, length: int | None = None,
          min_length: int | None = None, doc: str = "", omit_default: bool = False, omit_when: dict | None = None,
          omit_unless: dict | None = None) -> Any:
    """A dataclass field with its validation rule and its hash rule stored in ``metadata``.

    ``lo``/``hi`` bound numbers (and every element of number lists); ``lo_open`` makes the lower bound
    strict; ``choices`` lists allowed strings; ``length``/``min_length`` constrain lists. ``omit_default``,
    ``omit_when`` and ``omit_unless`` are the hash rule (module docstring).
    """
    meta = dict(lo=lo, hi=hi, lo_open=lo_open, choices=choices, length=length, min_length=min_length, doc=doc,
                **hash_rule(omit_default=omit_default, omit_when=omit_when, omit_unless=omit_unless))
    if isinstance(default, list):
        return field(default_factory=lambda d=tuple(default): list(d), metadata=meta)
    return field(default=default, metadata=meta)


def hash_rule(*, omit_default: bool = False, omit_when: dict | None = None,
               omit_unless: dict | None = None) -> dict[str, Any]:
    """The metadata of a hash rule (module docstring): only the rules given."""
    rule = {"omit_default": omit_default, "omit_when": omit_when, "omit_unless": omit_unless}
    return {k: v for k, v in rule.items() if v}
