"""Integrator options, one system for every method.

Each integrator declares its options once, as its ``Config``: a frozen dataclass whose typed fields
are the options, each made by ``option(default, check, allowed, doc)`` (the check, what is allowed
for the error message, the meaning with its unit). ``Config.parse`` overlays a scene's ``[solver]``
table (or ``--set solver.NAME=VALUE``) on the defaults and refuses unknown names and bad values;
``Config.resolve(arch, fast_math, counts)`` is the one place an ``auto`` becomes a concrete choice,
for the integrator's construction and ``memory.estimate`` alike. Every integrator's launch mode is
``base.IntegratorConfig``, the explicit methods' options ``base.ExplicitConfig``, the implicit
solvers' ``implicit/options.py``.
"""

from dataclasses import dataclass, field, fields, replace
from typing import Any, Callable

import numpy as np

from ...errors import UserError


@dataclass(frozen=True)
class Option:
    """What a ``Config`` field declares besides its name and type."""

    default: Any
    check: Callable[[Any], bool]
    allowed: str  # what is allowed, for the error message
    doc: str  # meaning, with its unit


def option(default, check: Callable[[Any], bool], allowed: str, doc: str):
    """A ``Config`` field: its default, ``check(value) -> bool``, what is allowed (for the error
    message) and its meaning with its unit."""
    return field(default=default, metadata={"option": Option(default, check, allowed, doc)})


@dataclass(frozen=True)
class Config:
    """Base of every integrator's options (fields made by ``option``)."""

    @classmethod
    def options(cls) -> dict[str, Option]:
        """The options by name, in declaration order."""
        return {f.name: f.metadata["option"] for f in fields(cls)}

    @classmethod
    def parse(cls, given: dict, owner: str) -> "Config":
        """The defaults overlaid with ``given`` (name -> value); an unknown name or a bad value raises
        ``UserError`` naming the option and what it allows (``owner``: the integrator's name). An
        integer given for a real-valued option becomes a float (TOML writes 1000 for 1000.0)."""
        known = {f.name: f for f in fields(cls)}
        values = {}
        for name, value in given.items():
            if name not in known:
                raise UserError(f"solver.{name}: not an option of {owner}; its options are {', '.join(known)}")
            opt = known[name].metadata["option"]
            if not opt.check(value):
                raise UserError(f"solver.{name} = {value!r}: must be {opt.allowed} ({opt.doc})")
            if known[name].type in (float, "float"):
                value = float(value)
            values[name] = value
        return cls(**values)

    @classmethod
    def accepted(cls, table: dict) -> dict:
        """The entries of a scene's ``[solver]`` table that are options of this config (a scene may
        carry options of other integrators, for ``compare``)."""
        names = cls.options()
        return {k: v for k, v in table.items() if k in names}

    def resolve(self, arch: str, fast_math: bool, counts) -> "Config":
        """This config with every ``auto`` made concrete for backend ``arch`` ("cpu" or a GPU
        backend's name), the ``fast_math`` setting and the scene's ``footprint.Counts``.
        Subclasses with ``auto`` options extend it; resolving a resolved config changes nothing."""
        return self

    def but(self, **changes) -> "Config":
        """A copy with ``changes`` (name -> value), not checked: for ``resolve``."""
        return replace(self, **changes)


def choice(default: str, values: tuple, doc: str):
    """An option that is one of ``values`` (strings)."""
    allowed = ", ".join(values[:-1]) + " or " + values[-1]
    return option(default, lambda v: v in values, allowed, doc)


def flag(default: bool, doc: str):
    """A true/false option."""
    return option(default, is_bool, "true or false", doc)


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
