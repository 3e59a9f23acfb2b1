"""Integrator options, one system for every method: each is an ``Option`` (default, check, what is
allowed, meaning with unit). A class's ``OPTIONS`` maps names to them; ``Integrator.parse_options``
overlays a scene's ``[solver]`` table (or ``--set solver.NAME=VALUE``) on the defaults and refuses
unknown names and bad values. The implicit solvers' options are in ``implicit/options.py``.
"""

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np


@dataclass(frozen=True)
class Option:
    default: Any
    check: Callable[[Any], bool]
    allowed: str  # what is allowed, for the error message
    doc: str  # meaning, with its unit


def int_at_least(lo):
    return lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= lo


def number_in(lo, hi, lo_open=False):
    def check(v):
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v):
            return False
        return (v > lo if lo_open else v >= lo) and v <= hi
    return check


def is_bool(v):
    return isinstance(v, bool)


def one_of(*values):
    return lambda v: v in values
