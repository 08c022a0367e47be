"""The schema machinery of the config: a key's kind, default, allowed range and doc
(:class:`Field`), how a section class declares its keys (:func:`key`, :func:`section`),
the sizes a run can hold, and the check of one given value against its field
(:func:`check_value`).  This module imports no JAX."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, replace
from typing import Any

from jaxform.errors import ConfigError

# Sizes a run can hold: beyond them a scene overflows the step schedule or the machine's
# memory, so it is refused up front with the keys that set it.
MAX_STEPS = 100_000  # load steps of one run (time to the end / time.dt_s)
MAX_ELEMENTS = 250_000  # mesh.nr x mesh.nz (e.g. 500 x 500)
# Every length (key ending in _mm) and speed (_mm_s) is at most this: a 1 km scene is
# already far outside forging, and 1e300 mm overflows the contact scale and the plots.
MAX_LENGTH_MM = 1e6
# the largest load resultant (N per mm of depth): stresses, energies and their squares stay
# far inside float64 (a resultant of 1e300 N overflows to inf in the strain energy)
MAX_FORCE_N = 1e12


@dataclass(frozen=True)
class Field:
    """One config key: kind, default (None = required), allowed range or choices, doc."""

    # "float" | "int" | "str" | "bool" | "floats" | "strs" (lists) | "points" (list of [a, b])
    kind: str
    default: Any = None
    low: float | None = None
    high: float | None = None
    low_inclusive: bool = True
    high_inclusive: bool = True
    choices: tuple[str, ...] | None = None
    doc: str = ""

    @property
    def numeric(self) -> bool:
        """A single number (float or int): what a study may vary."""
        return self.kind in ("float", "int")

    @property
    def integer(self) -> bool:
        return self.kind == "int"

    def allowed(self) -> str:
        """Human-readable allowed values: an interval, a choice list or the kind."""
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.kind in ("float", "int") and (self.low is not None or self.high is not None):
            lo = "-inf" if self.low is None else _num(self.low)
            hi = "inf" if self.high is None else _num(self.high)
            left = "[" if self.low is not None and self.low_inclusive else "("
            right = "]" if self.high is not None and self.high_inclusive else ")"
            return f"{left}{lo}, {hi}{right}"
        return f"any {self.kind}"


def _num(x: float) -> str:
    """Format a bound compactly (``0``, ``1``, ``2000``, ``0.5``)."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else repr(float(x))


# ----------------------------------------------------------------------------------
# A section class is one frozen dataclass per [section], one annotated attribute per
# key.  ``key(...)`` records the key's default (none: required), its allowed range or
# choices and its doc; :func:`schema_of` reads them back as Fields (lists become tuples
# in the typed sections).

KINDS = {
    "float": "float",
    "float | None": "float",
    "int": "int",
    "str": "str",
    "str | None": "str",
    "bool": "bool",
    "tuple[float, ...]": "floats",
    "tuple[str, ...]": "strs",
    "tuple[tuple[float, float], ...]": "points",
}


def key(
    default: Any = None,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    choices: tuple[str, ...] | None = None,
    doc: str = "",
):
    """A config key of a section class (default None: required)."""
    spec = dict(default=default, low=low, high=high, low_inclusive=not low_open,
                high_inclusive=not high_open, choices=choices, doc=doc)  # fmt: skip
    return dataclasses.field(metadata={"key": spec})


def section(name: str):
    """Name a section class after its TOML table (``cls.section_name``); the document
    (:mod:`jaxform.config.document`) lists the classes in their order."""

    def register(cls: type) -> type:
        cls.section_name = name
        return cls

    return register


def schema_of(cls: type) -> dict[str, Field]:
    """The Fields of a section class's keys, in their order."""
    return {f.name: Field(KINDS[f.type], **f.metadata["key"]) for f in dataclasses.fields(cls)}


def bound_lengths(schema: dict[str, dict[str, Field]]) -> dict[str, dict[str, Field]]:
    """The schema with every unbounded length or speed key capped at MAX_LENGTH_MM."""

    def capped(key: str, f: Field) -> Field:
        is_length = key.endswith("_mm") or key.endswith("_mm_s")
        if f.kind == "float" and is_length and f.low is not None and f.high is None:
            return replace(f, high=MAX_LENGTH_MM, high_inclusive=True)
        return f

    return {s: {k: capped(k, f) for k, f in t.items()} for s, t in schema.items()}


def check_value(name: str, f: Field, value: Any) -> Any:
    """Return ``value`` converted to the field's kind, or raise ConfigError."""
    if f.kind in ("floats", "strs", "points"):
        return _check_list(name, f, value)
    if f.kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{name} = {value!r}: must be a bool (true or false)")
        return value
    if f.kind == "str":
        if not isinstance(value, str):
            raise ConfigError(f"{name} = {value!r}: must be a string, {f.allowed()}")
        if f.choices is not None and value not in f.choices:
            raise ConfigError(f"{name} = {value!r}: must be {f.allowed()}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(
            f"{name} = {value!r}: must be a{'n' if f.kind == 'int' else ''} "
            f"{f.kind} in {f.allowed()}"
        )
    if f.kind == "int" and not isinstance(value, int):
        raise ConfigError(f"{name} = {value!r}: must be an int in {f.allowed()}")
    value = int(value) if f.kind == "int" else float(value)
    if not math.isfinite(value):
        raise ConfigError(f"{name} = {value!r}: must be a finite number in {f.allowed()}")
    ok = True
    if f.low is not None:
        ok = ok and (value >= f.low if f.low_inclusive else value > f.low)
    if f.high is not None:
        ok = ok and (value <= f.high if f.high_inclusive else value < f.high)
    if not ok:
        raise ConfigError(f"{name} = {value!r}: must lie in {f.allowed()}")
    return value


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check_list(name: str, f: Field, value: Any) -> list:
    if not isinstance(value, list):
        raise ConfigError(f"{name} = {value!r}: must be a list ({f.doc})")
    if f.kind == "floats":
        if not all(_is_num(v) for v in value):
            raise ConfigError(f"{name} = {value!r}: must be a list of finite numbers")
        _check_lengths(name, value)
        for v in value:  # each entry within the field's range, where it has one
            if f.low is not None or f.high is not None:
                check_value(f"{name}: entry", replace(f, kind="float"), v)
        return [float(v) for v in value]
    if f.kind == "strs":
        if not all(isinstance(v, str) for v in value):
            raise ConfigError(f"{name} = {value!r}: must be a list of strings")
        bad = [v for v in value if f.choices is not None and v not in f.choices]
        if bad:
            raise ConfigError(
                f"{name} = {value!r}: {bad[0]!r} is not allowed; each entry must be {f.allowed()}"
            )
        return list(value)
    if not all(isinstance(p, list) and len(p) == 2 and all(_is_num(v) for v in p) for p in value):
        raise ConfigError(
            f"{name} = {value!r}: must be a list of [r_mm, z_mm] pairs of finite numbers"
        )
    _check_lengths(name, [v for p in value for v in p])
    return [[float(a), float(b)] for a, b in value]


def _check_lengths(name: str, values: list) -> None:
    """Entries of a list of lengths (key ending in _mm) lie within +-MAX_LENGTH_MM."""
    big = [v for v in values if abs(v) > MAX_LENGTH_MM]
    if name.endswith("_mm") and big:
        raise ConfigError(
            f"{name}: entry {big[0]!r} mm: every entry must lie in "
            f"[-{_num(MAX_LENGTH_MM)}, {_num(MAX_LENGTH_MM)}] mm"
        )
