"""Typed loading of TOML/JSON tables into frozen dataclasses.

Configuration, scenes and recordings are plain tables on disk; inside the program they are frozen
dataclasses. This module walks a dataclass's fields and type hints, converts and checks each value,
and reports the first problem as one line that names the file and the dotted key, e.g.::

    config/sim.toml: rig.lasers[1].direction: expected 3 numbers, got 2

Dataclasses validate their own values in ``__post_init__`` by raising :class:`FieldError`; the
loader adds the file and the key path. Supported field types: bool, int, float, str, ``Literal``,
nested dataclasses, ``tuple[float, ...]``/fixed-length tuples, ``tuple[Dataclass, ...]`` and
``X | None`` (``None`` only as a default: TOML has no null).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import types
import typing
from collections.abc import Mapping
from typing import Any, Literal, TypeVar

from edge.errors import ConfigError, EdgeError

T = TypeVar("T")


class FieldError(ValueError):
    """Raised by a dataclass's validation: `key` is the field (or a dotted sub-path) at fault."""

    def __init__(self, key: str, message: str):
        super().__init__(f"{key}: {message}")
        self.key = key
        self.message = message


def require(condition: bool, key: str, message: str) -> None:
    """Validation helper for ``__post_init__``: raise :class:`FieldError` unless `condition`."""
    if not condition:
        raise FieldError(key, message)


def build(
    cls: type[T],
    data: Any,
    source: str,
    path: str = "",
    error: type[EdgeError] = ConfigError,
) -> T:
    """Convert the table `data` into an instance of the dataclass `cls`.

    `source` names the file for messages; `path` is the dotted key of `data` within it.
    Raises `error` (a :class:`EdgeError` subclass) with a one-line message on the first problem.
    """
    return _Loader(source, error).table(cls, data, path)


def _join(path: str, key: str) -> str:
    key = show(key)
    return f"{path}.{key}" if path else key


def show(text: str) -> str:
    """`text` fit for a one-line message: as it is when printable, else quoted with escapes (a
    key or a path with a line break in it must not break the message in two)."""
    return repr(text) if any(c in text for c in _LINE_BREAKS) else text


# What str.splitlines breaks at: a message must stay one line.
_LINE_BREAKS = "\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029"


def _type_name(tp: Any) -> str:
    if tp is float:
        return "a number"
    if tp is int:
        return "a whole number"
    if tp is bool:
        return "true or false"
    if tp is str:
        return "a string"
    if dataclasses.is_dataclass(tp):
        return "a table"
    return str(tp)


class _Loader:
    def __init__(self, source: str, error: type[EdgeError]):
        self.source = source
        self.error = error

    def fail(self, path: str, message: str) -> typing.NoReturn:
        where = f"{show(self.source)}: {path}" if path else show(self.source)
        raise self.error(f"{where}: {message}")

    def table(self, cls: type[T], data: Any, path: str) -> T:
        if not isinstance(data, Mapping):
            self.fail(path, f"expected a table, got {describe(data)}")
        hints = typing.get_type_hints(cls)
        fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
        unknown = [k for k in data if k not in fields]
        if unknown:
            self.fail(
                _join(path, str(unknown[0])),
                f"unknown key (expected one of: {', '.join(sorted(fields))})",
            )
        values: dict[str, Any] = {}
        for name, field in fields.items():
            key = _join(path, name)
            if name in data:
                values[name] = self.value(hints[name], data[name], key)
            elif (
                field.default is dataclasses.MISSING
                and field.default_factory is dataclasses.MISSING
            ):
                self.fail(key, "missing required key")
        try:
            return cls(**values)
        except FieldError as exc:
            self.fail(_join(path, exc.key), exc.message)

    def value(self, tp: Any, value: Any, path: str) -> Any:
        origin = typing.get_origin(tp)
        args = typing.get_args(tp)
        if origin in (typing.Union, types.UnionType):
            inner = [a for a in args if a is not type(None)]
            if value is None and len(inner) < len(args):
                return None
            if len(inner) == 1:
                return self.value(inner[0], value, path)
            for candidate in inner:
                try:
                    return self.value(candidate, value, path)
                except EdgeError:
                    continue
            self.fail(path, f"expected one of {', '.join(_type_name(a) for a in inner)}")
        if origin is Literal:
            # 8.0 == 8 and True == 1: a choice must also have the type it is written with.
            if not any(value == a and type(value) is type(a) for a in args):
                choices = ", ".join(repr(a) for a in args)
                self.fail(path, f"expected one of {choices}, got {value!r}")
            return value
        if origin is tuple:
            if not isinstance(value, (list, tuple)):
                self.fail(path, f"expected a list, got {describe(value)}")
            if len(args) == 2 and args[1] is Ellipsis:
                return tuple(
                    self.value(args[0], item, f"{path}[{i}]") for i, item in enumerate(value)
                )
            if len(value) != len(args):
                self.fail(path, f"expected {len(args)} values, got {len(value)}")
            return tuple(self.value(a, item, f"{path}[{i}]") for i, (a, item) in enumerate(zip(args, value)))
        if dataclasses.is_dataclass(tp):
            return self.table(tp, value, path)
        if tp is bool:
            if not isinstance(value, bool):
                self.fail(path, f"expected true or false, got {describe(value)}")
            return value
        if tp is int:
            if isinstance(value, bool) or not isinstance(value, int):
                self.fail(path, f"expected a whole number, got {describe(value)}")
            return value
        if tp is float:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                self.fail(path, f"expected a number, got {describe(value)}")
            if isinstance(value, int) and abs(value) > sys.float_info.max:
                self.fail(path, "expected a finite number, got a whole number too large for one")
            if not math.isfinite(value):
                self.fail(path, f"expected a finite number, got {value}")
            return float(value)
        if tp is str:
            if not isinstance(value, str):
                self.fail(path, f"expected a string, got {describe(value)}")
            if "\0" in value:  # no path, host, name or text of ours can hold one; the OS refuses it
                self.fail(path, "must not contain a NUL character")
            return value
        if tp is Any:
            return value
        raise TypeError(f"schema: unsupported field type {tp!r} at {path}")  # a bug, not input


def describe(value: Any, table: str = "a table") -> str:
    """How a message names a wrong value: `number 3`, `string 'x'`, `a list of 2`, …; `table` is
    the word for a mapping (TOML says table, JSON says object)."""
    if isinstance(value, bool):
        return f"boolean {str(value).lower()}"
    if isinstance(value, (int, float)):
        text = str(value) if not isinstance(value, int) or abs(value) < 10**30 else f"of {len(str(abs(value)))} digits"
        return f"number {text}"
    if isinstance(value, str):
        shown = value if len(value) <= 40 else value[:37] + "..."
        return f"string {shown!r}"
    if isinstance(value, Mapping):
        return table
    if isinstance(value, (list, tuple)):
        return f"a list of {len(value)}"
    if value is None:
        return "null"
    return type(value).__name__
