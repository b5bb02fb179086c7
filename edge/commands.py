"""The commands of ../shared/spec/mqtt.md: strict parsing and validation, no MQTT.

A command arrives as a name (the last level of ``<p>/<id>/cmd/<name>``) and a payload of bytes.
:func:`parse_command` turns them into a :class:`Command` or raises :class:`~edge.errors.CommandError`
with one line saying what is wrong; that line goes back to the sender as the result's ``error``,
so it names the command and the key and never echoes more than a short, escaped excerpt of what
was sent. Nothing is carried out here: a refused command changes nothing.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from edge.calibration.limits import MIN_POINTS, MIN_SPAN
from edge.errors import CommandError
from edge.modes import MODES
from edge.schema import show

MAX_REQUEST_ID_CHARS = 128
CALIBRATION_DISTANCE_M = (0.25, 5.0)
CALIBRATION_COUNT = (MIN_POINTS, 20)
CALIBRATION_MIN_STEP = 1.1  # from one distance to the next
# request_id_of reads at most this much: a best-effort helper must not parse a huge payload.
_REQUEST_ID_SCAN_BYTES = 1 << 20
_SHOW_CHARS = 40


@dataclass(frozen=True)
class Command:
    """A valid command. ``args`` is read-only and holds exactly the keys of the command's schema
    (numbers as float, ``distances_m`` as a tuple of floats); ``request_id`` is echoed in the result."""

    name: str
    args: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}), hash=False)
    request_id: str | None = None


# name → (required keys, optional keys) besides request_id
_SCHEMAS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "calibrate": (("distances_m",), ()),
    "lasers_off": ((), ()),
    "mode": (("mode",), ()),
    "point": (("pan_deg", "tilt_deg"), ()),
    "relearn": ((), ()),
    "sweep": ((), ()),
}
COMMANDS = tuple(sorted(_SCHEMAS))


def parse_command(
    name: str,
    payload: bytes,
    *,
    max_bytes: int,
    pan_limits: tuple[float, float],
    tilt_limits: tuple[float, float],
) -> Command:
    """Validate one command; raise :class:`CommandError` (one line) if anything is wrong.

    A payload is at least ``{}``: an empty message is how MQTT clears a retained message, never a
    command (the link drops those before they get here); the size is checked before anything is
    decoded; angles are checked against the unit's limits (inclusive, degrees)."""
    where = f"cmd/{label(name)}"
    data = bytes(payload)
    if len(data) > max_bytes:
        raise CommandError(f"{where}: payload of {len(data)} bytes exceeds the limit of {max_bytes} bytes")
    if name not in _SCHEMAS:
        raise CommandError(f"unknown command {label(name)} (known: {', '.join(COMMANDS)})")
    obj = _decode_object(where, data)
    request_id = _request_id(where, obj)
    required, optional = _SCHEMAS[name]
    allowed = (*required, *optional, "request_id")
    unknown = sorted(k for k in obj if k not in allowed)
    if unknown:
        keys = ", ".join(_sent(k) for k in unknown[:5]) + (", …" if len(unknown) > 5 else "")
        raise CommandError(f"{where}: unknown key{'s' if len(unknown) > 1 else ''} {keys} "
                           f"(allowed: {', '.join(allowed)})")
    for key in required:
        if key not in obj:
            raise CommandError(f"{where}: missing key {key!r}")
    args = _VALIDATORS[name](where, obj, pan_limits, tilt_limits)
    return Command(name, MappingProxyType(args), request_id)


def request_id_of(payload: bytes) -> str | None:
    """The payload's ``request_id`` if it is a JSON object with a usable one, else None.

    For the error reply of a command that is otherwise bad; never raises."""
    try:
        data = bytes(payload)
        if len(data) > _REQUEST_ID_SCAN_BYTES:
            return None
        obj = json.loads(data.decode("utf-8"))
        rid = obj.get("request_id") if isinstance(obj, dict) else None
        if isinstance(rid, str) and len(rid) <= MAX_REQUEST_ID_CHARS:
            rid.encode("utf-8")  # a lone surrogate could not be sent back
            return rid
    except Exception:  # noqa: BLE001 - best effort by contract: any failure means "no id"
        pass
    return None


# ---- decoding ----


def _decode_object(where: str, data: bytes) -> dict[str, Any]:
    if not data:
        raise CommandError(f"{where}: empty payload: a command is a JSON object, at least {{}} "
                           "(an empty message only clears a retained command)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CommandError(f"{where}: payload is not UTF-8 (invalid byte at offset {exc.start})") from None
    try:
        obj = json.loads(text, object_pairs_hook=_no_duplicates, parse_constant=_no_constants)
    except _Refused as exc:
        raise CommandError(f"{where}: payload is not valid JSON: {exc}") from None
    except json.JSONDecodeError as exc:
        raise CommandError(f"{where}: payload is not valid JSON: {exc.msg} at line {exc.lineno} "
                           f"column {exc.colno}") from None
    except ValueError as exc:  # e.g. an integer beyond Python's digit limit
        raise CommandError(f"{where}: payload is not usable JSON: {_one_line(str(exc))}") from None
    except RecursionError:
        raise CommandError(f"{where}: payload is not usable JSON: nested too deeply") from None
    if not isinstance(obj, dict):
        raise CommandError(f"{where}: payload must be a JSON object, got {_json_type(obj)}")
    return obj


class _Refused(ValueError):
    """JSON that Python's parser accepts but the JSON standard (or we) do not."""


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    # json keeps the last of duplicate keys silently; a command meaning two things is refused.
    obj: dict[str, Any] = {}
    for key, value in pairs:
        if key in obj:
            raise _Refused(f"duplicate key {_sent(key)}")
        obj[key] = value
    return obj


def _no_constants(name: str) -> Any:
    raise _Refused(f"{name} is not a JSON number")


def _request_id(where: str, obj: dict[str, Any]) -> str | None:
    if "request_id" not in obj:
        return None
    rid = obj["request_id"]
    if not isinstance(rid, str):
        raise CommandError(f"{where}: request_id must be a string, got {_json_type(rid)}")
    if len(rid) > MAX_REQUEST_ID_CHARS:
        raise CommandError(f"{where}: request_id has {len(rid)} characters, at most {MAX_REQUEST_ID_CHARS} allowed")
    try:
        rid.encode("utf-8")
    except UnicodeEncodeError:
        raise CommandError(f"{where}: request_id is not valid Unicode (a lone surrogate escape)") from None
    return rid


# ---- per-command validation ----

_Validator = Callable[[str, dict[str, Any], tuple[float, float], tuple[float, float]], dict[str, Any]]


def _no_args(where: str, obj: dict[str, Any], pan: tuple[float, float], tilt: tuple[float, float]) -> dict[str, Any]:
    return {}


def _mode(where: str, obj: dict[str, Any], pan: tuple[float, float], tilt: tuple[float, float]) -> dict[str, Any]:
    mode = obj["mode"]
    if not isinstance(mode, str) or mode not in MODES:
        raise CommandError(f"{where}: mode must be one of {', '.join(MODES)}, got {_sent(mode)}")
    return {"mode": mode}


def _degrees(x: float) -> str:
    """Enough digits that a limit reads true (a D46-17 stops at 179.99994°, which :g calls 180),
    none that say nothing (159, not 159.00000)."""
    return f"{x:.5f}".rstrip("0").rstrip(".")


def _point(where: str, obj: dict[str, Any], pan: tuple[float, float], tilt: tuple[float, float]) -> dict[str, Any]:
    args = {}
    for key, (lo, hi), what in (("pan_deg", pan, "pan"), ("tilt_deg", tilt, "tilt")):
        value = _number(where, key, obj[key])
        if not lo <= value <= hi:
            raise CommandError(f"{where}: {key} = {value:g} is outside the {what} limits "
                               f"{_degrees(lo)}..{_degrees(hi)}°")
        args[key] = value
    return args


def _calibrate(where: str, obj: dict[str, Any], pan: tuple[float, float], tilt: tuple[float, float]) -> dict[str, Any]:
    values = obj["distances_m"]
    lo_n, hi_n = CALIBRATION_COUNT
    lo, hi = CALIBRATION_DISTANCE_M
    if not isinstance(values, list):
        raise CommandError(f"{where}: distances_m must be an array of numbers, got {_json_type(values)}")
    if not lo_n <= len(values) <= hi_n:
        raise CommandError(f"{where}: distances_m has {len(values)} entries, {lo_n}-{hi_n} expected")
    distances = []
    for i, raw in enumerate(values):
        d = _number(where, f"distances_m[{i}]", raw)
        if not lo <= d <= hi:
            raise CommandError(f"{where}: distances_m[{i}] = {d:g} m is outside {lo:g}-{hi:g} m")
        distances.append(d)
    # What a session can take (edge.calibration.session): a span the fit can use, and steps it can see.
    span = max(distances) / min(distances)
    if span < MIN_SPAN:
        raise CommandError(f"{where}: distances_m spans only a factor {span:.2f} ({min(distances):g} to "
                           f"{max(distances):g} m): it must span at least {MIN_SPAN:g} (e.g. 0.5 to 2 m)")
    for a, b in zip(distances, distances[1:]):
        if abs(math.log(b / a)) < math.log(CALIBRATION_MIN_STEP):
            raise CommandError(f"{where}: distances_m: {a:g} and {b:g} m follow each other but differ by under "
                               f"{100 * (CALIBRATION_MIN_STEP - 1):.0f} %: the move cannot be seen")
    return {"distances_m": tuple(distances)}


_VALIDATORS: dict[str, _Validator] = {
    "calibrate": _calibrate,
    "lasers_off": _no_args,
    "mode": _mode,
    "point": _point,
    "relearn": _no_args,
    "sweep": _no_args,
}


def _number(where: str, key: str, value: Any) -> float:
    # bool is an int in Python, but `true` is not a number in JSON.
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CommandError(f"{where}: {key} must be a number, got {_sent(value)}")
    try:
        number = float(value)
    except OverflowError:  # an integer too large for a float
        number = math.inf
    if not math.isfinite(number):
        raise CommandError(f"{where}: {key} must be a finite number, got {_sent(value)}")
    return number


# ---- messages ----


def label(name: str) -> str:
    """A command name as it may appear in a message or a log line: plain if it looks like a name,
    else escaped and cut short (a name can be 65 kB long)."""
    if isinstance(name, str) and 0 < len(name) <= 32 and name.replace("_", "a").isascii() \
            and name.replace("_", "a").isalnum():
        return name
    return _sent(name)


def _sent(value: Any) -> str:
    """A value as the sender wrote it, JSON (so `true`, `"text"`, `[1, 2]`: a string "2" reads
    apart from the number 2), ASCII, shown as every message shows text (:func:`edge.schema.show`)."""
    try:
        text = json.dumps(value, ensure_ascii=True)
    except (ValueError, TypeError, RecursionError):
        text = _json_type(value)
    return show(text, _SHOW_CHARS)


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _json_type(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__
