"""Config values checked against their type annotation and range: the one checker behind every task
config (:meth:`.config.TaskConfig.validate`) and every algorithm key (:mod:`dexmots_rl.algorithms.validation`).

A field's type annotation says what kind of value it takes (``int``, ``float``, ``bool``, ``str``,
``Optional[...]``, ``tuple[float, float]``, ``tuple[int, ...]``, a nested dataclass); its range comes from
:func:`rule` (dataclass field metadata): ``gt`` / ``ge`` / ``le`` / ``lt`` bounds, ``choices`` for strings,
``ordered`` for ``(low, high)`` pairs. A field without a rule gets its type's default: numbers finite and
> 0, pairs ``0 <= low <= high``, strings non-empty. Numbers are always finite. Every failure is one
``ValueError`` naming the field (``task.joint_noise must be a finite number >= 0, got 'abc'``).

Example:
    >>> import dataclasses
    >>> @dataclasses.dataclass
    ... class Example:
    ...     steps: int = 10
    ...     noise: float = dataclasses.field(default=0.1, metadata=rule(ge=0))
    >>> try:
    ...     validate_fields(Example(noise=float("nan")), "task")
    ... except ValueError as e:
    ...     print(e)
    task.noise must be a finite number >= 0, got nan
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import types
import typing
from typing import Any, Mapping

__all__ = ["check_value", "field_rules", "rule", "validate_fields"]

_NO_RULE: Mapping[str, Any] = types.MappingProxyType({})


def rule(*, gt: float | None = None, ge: float | None = None, lt: float | None = None, le: float | None = None,
         choices: tuple[str, ...] | str | None = None, ordered: bool = False, empty: bool = False,
         objects: bool = False) -> dict:
    """Field metadata for :func:`validate_fields`: bounds on a number (or on each element of a tuple),
    the allowed strings (``choices``: a tuple, or the name of a class attribute holding one), ``ordered``:
    a pair is ``(low, high)`` with ``low <= high``; ``empty``: a tuple may be empty; ``objects``: from Python the
    field may also hold a non-empty list of objects (e.g. plans in memory instead of a plan file), checked where
    they are used."""
    return {"check": {"gt": gt, "ge": ge, "lt": lt, "le": le, "choices": choices, "ordered": ordered,
                      "empty": empty, "objects": objects}}


def _bounds_text(r: Mapping[str, Any]) -> str:
    parts = [f"{op} {r[key]:g}" for key, op in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="))
             if r.get(key) is not None]
    return " and ".join(parts)


def _default_rule(annotation) -> Mapping[str, Any]:
    if annotation in (int, float) or typing.get_origin(annotation) is tuple:
        return {"gt": 0} if annotation in (int, float) else {"ge": 0}
    return _NO_RULE


def _is_optional(annotation) -> tuple[bool, Any]:
    args = typing.get_args(annotation)
    if typing.get_origin(annotation) in (typing.Union, types.UnionType) and type(None) in args:
        rest = [a for a in args if a is not type(None)]
        return True, rest[0] if len(rest) == 1 else typing.Union[tuple(rest)]
    return False, annotation


def _number(name: str, value, kind, r: Mapping[str, Any]) -> float | int:
    whole = kind is int
    ok_type = isinstance(value, numbers.Integral if whole else numbers.Real) and not isinstance(value, bool)
    if whole and isinstance(value, float) and value.is_integer():  # 1e3 from a YAML file
        value, ok_type = int(value), True
    bounds = _bounds_text(r)
    what = ("an integer" if whole else "a finite number") + (f" {bounds}" if bounds else "")
    if not ok_type or not math.isfinite(value):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    for key, holds in (("gt", lambda b: value > b), ("ge", lambda b: value >= b), ("lt", lambda b: value < b),
                       ("le", lambda b: value <= b)):
        if r.get(key) is not None and not holds(r[key]):
            raise ValueError(f"{name} must be {what}, got {value!r}")
    return int(value) if whole else float(value)


def check_value(name: str, value, annotation, r: Mapping[str, Any] | None = None, owner=None):
    """``value`` checked against ``annotation`` and rule ``r`` (``None``: the type's default), normalised
    (lists become tuples, ints in float fields floats); a ``ValueError`` naming ``name`` otherwise.
    ``owner``: the object whose attribute a ``choices`` string names."""
    optional, annotation = _is_optional(annotation)
    if value is None and optional:
        return None
    r = _default_rule(annotation) if r is None else r.get("check", r)  # a rule() or its inner dict
    if annotation is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{name} must be true or false, got {value!r}")
        return value
    if annotation in (int, float):
        return _number(name, value, annotation, r)
    if annotation is str:
        if r.get("objects") and isinstance(value, (list, tuple)) and len(value) > 0:
            return value
        choices = r.get("choices")
        if isinstance(choices, str):
            choices = getattr(owner, choices)
        if not isinstance(value, str) or (choices is not None and value not in choices) or not value:
            what = f"one of {', '.join(choices)}" if choices is not None else "a non-empty string"
            raise ValueError(f"{name} must be {what}, got {value!r}")
        return value
    if typing.get_origin(annotation) is tuple:
        return _sequence(name, value, annotation, r)
    if dataclasses.is_dataclass(annotation):
        return _nested(name, value, annotation)
    raise TypeError(f"{name}: no check for annotation {annotation!r}")  # a programming error, not bad input


def _sequence(name: str, value, annotation, r: Mapping[str, Any]) -> tuple:
    args = typing.get_args(annotation)
    variadic = len(args) == 2 and args[1] is Ellipsis
    kind = args[0] if variadic else args
    bounds = _bounds_text(r)
    if variadic:
        size = "a non-empty list" if not r.get("empty") else "a list"
    else:
        size = "a pair" if len(args) == 2 else f"a list of {len(args)}"
    integers = kind is int if variadic else all(k is int for k in args)
    what = f"{size} of {'integers' if integers else 'finite numbers'}"
    what += f" {bounds}" if bounds else ""
    what += " (low, high) with low <= high" if r.get("ordered") else ""
    if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    if (variadic and not value and not r.get("empty")) or (not variadic and len(value) != len(args)):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    kinds = [kind] * len(value) if variadic else list(args)
    try:
        out = tuple(_number(name, v, k, r) for v, k in zip(value, kinds))
    except ValueError:
        raise ValueError(f"{name} must be {what}, got {value!r}") from None
    if r.get("ordered") and not all(a <= b for a, b in zip(out, out[1:])):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return out


def _nested(name: str, value, cls):
    if isinstance(value, cls):
        values = {f.name: getattr(value, f.name) for f in dataclasses.fields(cls)}
    elif isinstance(value, Mapping):
        values = dict(value)
    else:
        names = ", ".join(f.name for f in dataclasses.fields(cls))
        raise ValueError(f"{name} must be a mapping with keys among {names}, got {value!r}")
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = [k for k in values if k not in known]
    if unknown:
        raise ValueError(f"{name} has no key {unknown[0]!r}; its keys are: {', '.join(sorted(known))}")
    rules = field_rules(cls)
    checked = {k: check_value(f"{name}.{k}", v, *rules[k]) for k, v in values.items()}
    return dataclasses.replace(value, **checked) if isinstance(value, cls) else cls(**checked)


@functools.lru_cache(maxsize=None)
def field_rules(cls) -> dict[str, tuple[Any, Mapping[str, Any] | None]]:
    """Field name -> (type annotation, rule) of dataclass ``cls``. A subclass that only changes a field's
    default keeps the rule of the class that declared it with one (the nearest in the MRO)."""
    hints = typing.get_type_hints(cls)
    out = {}
    for f in dataclasses.fields(cls):
        found = None
        for klass in cls.__mro__:
            declared = getattr(klass, "__dataclass_fields__", {}).get(f.name)
            if declared is not None and "check" in declared.metadata:
                found = declared.metadata["check"]
                break
        out[f.name] = (hints[f.name], found)
    return out


def validate_fields(obj, prefix: str):
    """Check every field of dataclass instance ``obj`` (``ValueError`` naming ``<prefix>.<field>``, the first
    bad one) and store the normalised values; returns ``obj``."""
    for name, (annotation, r) in field_rules(type(obj)).items():
        value = check_value(f"{prefix}.{name}", getattr(obj, name), annotation, r, owner=obj)
        object.__setattr__(obj, name, value)
    return obj
