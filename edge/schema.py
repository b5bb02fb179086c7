"""Typed, strict loading of TOML/JSON tables into frozen dataclasses: the one reader of documents.

Configuration, scenes, recordings (``sweep.json``) and calibration files are plain tables on disk;
inside the program they are frozen dataclasses. This module walks a dataclass's fields and type
hints, converts and checks each value, and reports the first problem as one line that names the
file and the key, e.g.::

    config/sim.toml: rig.lasers[1].direction: expected 3 values, got 2
    rec/sweep.json: zone 3, frame frames/z003-1-on.png: t_start_ns: expected a whole number, got number 1.5

Dataclasses validate their own values in ``__post_init__`` by raising :class:`FieldError`; the
loader adds the file and the key path. Supported field types: bool, int, float, str, ``Literal``,
nested dataclasses, ``tuple[float, ...]``/fixed-length tuples, ``tuple[Dataclass, ...]``,
``dict[str, X]``, ``X | None``, ``Any`` and ``Annotated[X, check, ...]`` where each `check` takes the
converted value and returns its problem (or None). A null (JSON; TOML has none) on a key with a
default stands for the absent key.

A dataclass kept in a list may say how messages name it by one of its keys instead of by its place
(``zone 3`` rather than ``zones[2]``) with a ``LABEL: ClassVar[Label]``; its keys then follow a
colon (``zone 3: pan_deg``) and its own tables' items a comma (``zone 3, frames[1]``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import types
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, NoReturn, TypeVar

from edge.errors import ConfigError, EdgeError
from edge.fsutil import SMALL_LIMIT, read_small

T = TypeVar("T")

Check = Callable[[Any], "str | None"]  # a converted value's problem, or None


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


@dataclasses.dataclass(frozen=True)
class Label:
    """How messages name a table by one of its keys: ``Label("index", "zone {}")``."""

    key: str
    text: str

    def name(self, value: Any) -> str:
        return self.text.format(show(str(value)))


def build(
    cls: type[T],
    data: Any,
    source: str,
    path: str = "",
    error: type[EdgeError] = ConfigError,
    *,
    unknown_keys: Literal["refuse", "ignore"] = "refuse",
    table: str = "a table",
) -> T:
    """Convert the table `data` into an instance of the dataclass `cls`.

    `source` names the file for messages; `path` is the key of `data` within it. Raises `error`
    (an :class:`EdgeError` subclass) with a one-line message on the first problem. Unknown keys
    are refused, or ignored (formats that may grow); `table` is how messages call a mapping
    (TOML says a table, JSON an object)."""
    start: tuple[_Segment, ...] = (_Key(path),) if path else ()
    return _Loader(source, error, unknown_keys == "ignore", table).table(cls, data, start)


def fail(error: type[EdgeError], source: str, where: str, message: str) -> NoReturn:
    """Raise `error` with the one-line message ``source: where: message`` (`where` may be empty)."""
    head = f"{show(source)}: {where}" if where else show(source)
    raise error(f"{head}: {message}")


# No document of ours nests deeper than a few levels (sweep.json: zones[i].frames[j].truth.lasers…).
MAX_DEPTH = 32


def read_json(path: str | Path, error: type[EdgeError], missing: str = "no such file",
              limit: int = SMALL_LIMIT) -> Any:
    """The JSON document in file `path`; `error` naming the file when it cannot be read or parsed
    (`missing`: what to say when there is no such file). The file must be a regular file of at
    most `limit` bytes (:func:`edge.fsutil.read_small`) nesting at most MAX_DEPTH levels."""
    source = str(path)
    try:
        doc = json.loads(read_small(path, limit))
    except FileNotFoundError:
        fail(error, source, "", missing)
    except OSError as exc:
        fail(error, source, "", f"cannot be read ({exc.strerror or exc})")
    except json.JSONDecodeError as exc:
        fail(error, source, "", f"not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})")
    except UnicodeDecodeError:
        fail(error, source, "", "not valid JSON (not UTF-8 text)")
    except RecursionError:
        fail(error, source, "", "not usable JSON (nested too deeply)")
    except ValueError as exc:  # a whole number of more digits than Python converts
        fail(error, source, "", f"not usable JSON ({str(exc).splitlines()[0]})")
    if depth(doc) > MAX_DEPTH:
        fail(error, source, "", f"not usable JSON (nested more than {MAX_DEPTH} levels deep)")
    return doc


def depth(doc: Any) -> int:
    """How deeply lists and tables nest in `doc` (a scalar: 0), without recursion."""
    deepest, todo = 0, [(doc, 1)]
    while todo:
        node, level = todo.pop()
        children = node.values() if isinstance(node, Mapping) else node if isinstance(node, list) else None
        if children is not None:
            deepest = max(deepest, level)
            todo.extend((child, level + 1) for child in children)
    return deepest


def show(text: str, limit: int | None = None) -> str:
    """`text` (a file, a key, a name, a value as it was sent: anything quoted in a message) fit for
    a one-line message: as it is when every character is printable, else as a literal with escapes,
    so that a line break or a control character in it can neither break the message in two nor
    hide; cut to `limit` characters (ending in …) when given, for text from untrusted senders."""
    shown = text if text.isprintable() else repr(text)
    return shown if limit is None or len(shown) <= limit else shown[: limit - 1] + "…"


# A path into a document: keys (already shown), list indices, and the names of labelled tables.
@dataclasses.dataclass(frozen=True)
class _Key:
    text: str


@dataclasses.dataclass(frozen=True)
class _Name:
    text: str


_Segment = _Key | _Name | int


def _render(path: tuple[_Segment, ...]) -> str:
    out, after_name = "", False
    for seg in path:
        if isinstance(seg, int):
            out += f"[{seg}]"
        else:
            out += (": " if isinstance(seg, _Key) else ", ") if after_name else ("." if out else "")
            out += seg.text
        after_name = isinstance(seg, _Name)
    return out


def _named(path: tuple[_Segment, ...]) -> tuple[_Segment, ...]:
    """`path` with everything after its last name turned into one name, as it reads."""
    cut = max((i + 1 for i, seg in enumerate(path) if isinstance(seg, _Name)), default=0)
    return (*path[:cut], _Name(_render(path[cut:])))


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
    def __init__(self, source: str, error: type[EdgeError], ignore_unknown: bool, table: str):
        self.source = source
        self.error = error
        self.ignore_unknown = ignore_unknown
        self.table_word = table

    def fail(self, path: tuple[_Segment, ...], message: str) -> NoReturn:
        fail(self.error, self.source, _render(path), message)

    def describe(self, value: Any) -> str:
        return describe(value, self.table_word)

    def table(self, cls: type[T], data: Any, path: tuple[_Segment, ...]) -> T:
        if not isinstance(data, Mapping):
            self.fail(path, f"expected {self.table_word}, got {self.describe(data)}")
        label: Label | None = getattr(cls, "LABEL", None)
        if label is not None:
            path = _named(path)
        hints = typing.get_type_hints(cls, include_extras=True)
        fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
        unknown = [k for k in data if k not in fields]
        if unknown and not self.ignore_unknown:
            self.fail(
                (*path, _Key(show(str(unknown[0])))),
                f"unknown key (expected one of: {', '.join(sorted(fields))})",
            )
        values: dict[str, Any] = {}
        for name, field in fields.items():
            key = (*path, _Key(name))
            has_default = (field.default is not dataclasses.MISSING
                           or field.default_factory is not dataclasses.MISSING)
            if name in data and not (data[name] is None and has_default):
                values[name] = self.value(hints[name], data[name], key)
                if label is not None and name == label.key:
                    path = (*path[:-1], _Name(label.name(values[name])))
            elif not has_default:
                self.fail(key, "missing required key")
        try:
            return cls(**values)
        except FieldError as exc:
            self.fail((*path, _Key(exc.key)), exc.message)

    def value(self, tp: Any, value: Any, path: tuple[_Segment, ...]) -> Any:
        origin = typing.get_origin(tp)
        args = typing.get_args(tp)
        if origin is Annotated:
            converted = self.value(args[0], value, path)
            for check in tp.__metadata__:
                problem = check(converted)
                if problem is not None:
                    self.fail(path, problem)
            return converted
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
                expected = choices if len(args) == 1 else f"one of {choices}"
                self.fail(path, f"expected {expected}, got {value!r}")
            return value
        if origin is tuple:
            if not isinstance(value, (list, tuple)):
                self.fail(path, f"expected a list, got {self.describe(value)}")
            if len(args) == 2 and args[1] is Ellipsis:
                return tuple(self.value(args[0], item, (*path, i)) for i, item in enumerate(value))
            if len(value) != len(args):
                self.fail(path, f"expected {len(args)} values, got {len(value)}")
            return tuple(self.value(a, item, (*path, i)) for i, (a, item) in enumerate(zip(args, value)))
        if origin is dict:
            if not isinstance(value, Mapping):
                self.fail(path, f"expected {self.table_word}, got {self.describe(value)}")
            return {k: self.value(args[1], v, (*path, _Key(show(str(k))))) for k, v in value.items()}
        if dataclasses.is_dataclass(tp):
            return self.table(tp, value, path)  # type: ignore[arg-type]
        if tp is bool:
            if not isinstance(value, bool):
                self.fail(path, f"expected true or false, got {self.describe(value)}")
            return value
        if tp is int:
            if isinstance(value, bool) or not isinstance(value, int):
                self.fail(path, f"expected a whole number, got {self.describe(value)}")
            return value
        if tp is float:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                self.fail(path, f"expected a number, got {self.describe(value)}")
            if isinstance(value, int) and abs(value) > sys.float_info.max:
                self.fail(path, "expected a finite number, got a whole number too large for one")
            if not math.isfinite(value):
                self.fail(path, f"expected a finite number, got {value}")
            return float(value)
        if tp is str:
            if not isinstance(value, str):
                self.fail(path, f"expected a string, got {self.describe(value)}")
            if "\0" in value:  # no path, host, name or text of ours can hold one; the OS refuses it
                self.fail(path, "must not contain a NUL character")
            return value
        if tp is Any:
            return value
        raise TypeError(f"schema: unsupported field type {tp!r} at {_render(path)}")  # a bug, not input


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
