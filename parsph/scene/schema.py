"""Declarative validation of plain data (parsed TOML) into frozen dataclasses.

A section of a scene is a frozen dataclass whose fields carry their constraints in
``metadata`` (see :func:`spec`). :func:`build` walks a dict against such a class: it
refuses unknown keys, missing required keys, wrong types, NaN/inf and out-of-range
values, each with a :class:`~parsph.errors.SceneError` naming the dotted key and the file.
"""
from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import MISSING, field

from parsph.errors import SceneError


def spec(default=MISSING, *, doc: str = "", gt=None, ge=None, lt=None, le=None,
         choices=None, min_len=None, max_len=None, inf=False):
    """A dataclass field with validation metadata.

    Parameters
    ----------
    default
        Default value (omit for a required key). Lists are stored as tuples.
    doc
        One line shown in error messages and docs.
    gt, ge, lt, le
        Bounds for numbers (applied to every element of a vector).
    choices
        Allowed values for strings.
    min_len, max_len
        Bounds on the length of a list.
    inf
        A number may be ``inf`` (TOML's ``inf``): a limit the key switches off at.
    """
    meta = dict(doc=doc, gt=gt, ge=ge, lt=lt, le=le, choices=choices,
                min_len=min_len, max_len=max_len, inf=inf)
    if default is MISSING:
        return field(metadata=meta)
    return field(default=default, metadata=meta)


def _where(path: str, source: str) -> str:
    return f"{source}: key '{path}'" if source else f"key '{path}'"


def _fail(path, source, message):
    raise SceneError(f"{_where(path, source)}: {message}")


def _check_number(value, path, source, meta, integer=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        kind = "a whole number" if integer else "a number"
        _fail(path, source, f"expected {kind}, got {value!r}")
    if integer and not isinstance(value, int):
        _fail(path, source, f"expected a whole number, got {value!r}")
    if not integer and not math.isfinite(value) and not (meta.get("inf") and value == math.inf):
        _fail(path, source, f"must be finite, got {value!r}")
    for name, op, text in (("gt", lambda a, b: a > b, ">"), ("ge", lambda a, b: a >= b, ">="),
                           ("lt", lambda a, b: a < b, "<"), ("le", lambda a, b: a <= b, "<=")):
        bound = meta.get(name)
        if bound is not None and not op(value, bound):
            _fail(path, source, f"must be {text} {bound}, got {value!r}")
    return int(value) if integer else float(value)


def _convert(tp, value, path, source, meta):
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is typing.Union:
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _convert(inner[0], value, path, source, meta)
    if tp is float:
        return _check_number(value, path, source, meta)
    if tp is int:
        return _check_number(value, path, source, meta, integer=True)
    if tp is bool:
        if not isinstance(value, bool):
            _fail(path, source, f"expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            _fail(path, source, f"expected a string, got {value!r}")
        choices = meta.get("choices")
        if choices is not None and value not in choices:
            _fail(path, source, f"must be one of {', '.join(map(repr, choices))}; got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            _fail(path, source, f"expected a list, got {value!r}")
        lo, hi = meta.get("min_len"), meta.get("max_len")
        if lo is not None and len(value) < lo:
            _fail(path, source, f"needs at least {lo} entries, got {len(value)}")
        if hi is not None and len(value) > hi:
            _fail(path, source, f"takes at most {hi} entries, got {len(value)}")
        elem = args[0]
        sub = {k: v for k, v in meta.items() if k not in ("min_len", "max_len")}
        return tuple(_convert(elem, v, f"{path}[{i}]", source, sub) for i, v in enumerate(value))
    if origin is dict:
        if not isinstance(value, dict):
            _fail(path, source, f"expected a table, got {value!r}")
        return {k: _convert(args[1], v, f"{path}.{k}", source, {}) for k, v in value.items()}
    if dataclasses.is_dataclass(tp):
        return build(tp, value, path, source)
    raise TypeError(f"schema: unsupported annotation {tp!r} at {path}")  # a bug in a schema class


def build(cls, data, path: str = "", source: str = ""):
    """Validate ``data`` (a dict from TOML) into the frozen dataclass ``cls``.

    Raises
    ------
    SceneError
        On an unknown or missing key, a wrong type or a value out of range; the message
        names the dotted key and the file.
    """
    if not isinstance(data, dict):
        _fail(path or "(top level)", source, f"expected a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - names)
    if unknown:
        prefix = f"{path}." if path else ""
        allowed = ", ".join(sorted(names))
        _fail(prefix + unknown[0], source, f"unknown key; allowed here: {allowed}")
    kwargs = {}
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        key = f"{path}.{f.name}" if path else f.name
        if f.name in data:
            kwargs[f.name] = _convert(hints[f.name], data[f.name], key, source, dict(f.metadata))
        elif f.default is MISSING and f.default_factory is MISSING:
            doc = f.metadata.get("doc", "")
            _fail(key, source, "missing" + (f" ({doc})" if doc else ""))
    try:
        return cls(**kwargs)
    except SceneError as exc:
        raise SceneError(f"{source + ': ' if source else ''}{exc}") from None


def describe(cls, prefix: str = "") -> list[tuple[str, str, str]]:
    """(dotted key, type/default, doc) rows for documentation of a schema class."""
    rows = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        key = prefix + f.name
        tp = hints[f.name]
        if dataclasses.is_dataclass(tp):
            rows.extend(describe(tp, key + "."))
            continue
        default = "required" if f.default is MISSING else repr(f.default)
        rows.append((key, default, f.metadata.get("doc", "")))
    return rows
