"""Range and type checks of settings dataclasses: one ConfigError naming the field, its value and
what is allowed. The caller (helioflow.models.registry.split_settings) puts the config key in front."""

from __future__ import annotations

import math
from dataclasses import fields

from helioflow.errors import ConfigError


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


# annotation (as written, `from __future__ import annotations`) -> (check, what is expected)
_TYPES = {
    "int": (_is_int, "an integer"),
    "float": (_is_number, "a number"),
    "bool": (lambda v: isinstance(v, bool), "true or false"),
    "str": (lambda v: isinstance(v, str), "a string"),
    "float | None": (lambda v: v is None or _is_number(v), "a number or null"),
    "dict": (lambda v: isinstance(v, dict), "a mapping"),
    "dict | None": (lambda v: v is None or isinstance(v, dict), "a mapping or null"),
}


def check_types(settings) -> None:
    """Each field of the dataclass instance `settings` holds a value of its annotated type (tuples:
    a list or tuple of numbers); ConfigError 'field = value: expected ...' otherwise."""
    for f in fields(settings):
        value = getattr(settings, f.name)
        kind = str(f.type)
        if kind.endswith(" | None") and value is None:
            continue
        if kind.startswith("tuple"):
            ok = isinstance(value, (list, tuple)) and all(_is_number(v) for v in value)
            expected = "a list of numbers"
        elif kind in _TYPES:
            check, expected = _TYPES[kind]
            ok = check(value)
        else:
            continue
        if not ok:
            raise ConfigError(f"{f.name} = {value!r}: expected {expected}")


def check_ranges(settings, *, at_least_one=(), counts=(), non_negative=(), positive=(), fraction=(),
                 below_one=(), at_most: dict | None = None) -> None:
    """Integers >= 1 (`at_least_one`) and >= 0 (`counts`), numbers >= 0 (`non_negative`), > 0 (`positive`), in (0, 1]
    (`fraction`) and in [0, 1) (`below_one`) among the fields of `settings`, and sizes within their bound
    (`at_most`: {field: (largest value, why)}); ConfigError 'field = value: expected ...' for the first
    one out of range."""
    rules = (
        (at_least_one, lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
        (counts, lambda v: _is_int(v) and v >= 0, "an integer >= 0"),
        (non_negative, lambda v: _is_number(v) and v >= 0, "a number >= 0"),
        (positive, lambda v: _is_number(v) and v > 0, "a number > 0"),
        (fraction, lambda v: _is_number(v) and 0 < v <= 1, "a number in (0, 1]"),
        (below_one, lambda v: _is_number(v) and 0 <= v < 1, "a number in [0, 1)"),
    )
    for names, ok, expected in rules:
        for name in names:
            value = getattr(settings, name)
            if not ok(value):
                raise ConfigError(f"{name} = {value!r}: expected {expected}")
    for name, (largest, why) in (at_most or {}).items():
        value = getattr(settings, name)
        if value > largest:
            raise ConfigError(f"{name} = {value!r}: expected a value <= {largest} ({why})")
