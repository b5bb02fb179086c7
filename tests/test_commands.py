"""edge.commands: every command of mqtt.md, and every way a payload can be wrong."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.commands import COMMANDS, MODES, Command, parse_command, request_id_of
from edge.errors import CommandError

PAN = (-159.0, 159.0)
TILT = (-47.0, 31.0)


def parse(name: str, payload: bytes | str | dict, max_bytes: int = 65536) -> Command:
    if isinstance(payload, dict):
        payload = json.dumps(payload)
    if isinstance(payload, str):
        payload = payload.encode("utf-8")
    return parse_command(name, payload, max_bytes=max_bytes, pan_limits=PAN, tilt_limits=TILT)


def refused(name: str, payload: bytes | str | dict, max_bytes: int = 65536) -> str:
    with pytest.raises(CommandError) as info:
        parse(name, payload, max_bytes)
    message = str(info.value)
    assert len(message.splitlines()) == 1, message
    return message


# ---- valid commands ----


def test_mode():
    for mode in MODES:
        command = parse("mode", {"mode": mode})
        assert command == Command("mode", {"mode": mode}, None)
        assert command.args["mode"] == mode


@pytest.mark.parametrize("name", ["sweep", "relearn", "lasers_off"])
def test_argument_less_commands_take_an_empty_object(name):
    assert parse(name, "{}").args == {}
    assert parse(name, {"request_id": "r1"}).request_id == "r1"


def test_point_takes_ints_and_floats_and_the_limits_themselves():
    command = parse("point", {"pan_deg": 159, "tilt_deg": -47.0, "request_id": "abc"})
    assert command.args == {"pan_deg": 159.0, "tilt_deg": -47.0}
    assert isinstance(command.args["pan_deg"], float)
    assert command.request_id == "abc"


def test_calibrate():
    command = parse("calibrate", {"distances_m": [0.25, 1, 2.5, 5.0]})
    assert command.args["distances_m"] == (0.25, 1.0, 2.5, 5.0)


def test_args_are_read_only():
    command = parse("mode", {"mode": "guard"})
    with pytest.raises(TypeError):
        command.args["mode"] = "blindaid"  # type: ignore[index]


# ---- refused ----


def test_size_is_checked_before_decoding():
    # Not UTF-8 and not JSON, but too large: the size is what is reported.
    message = refused("mode", b"\xff" * 300, max_bytes=256)
    assert message == "cmd/mode: payload of 300 bytes exceeds the limit of 256 bytes"
    assert parse("sweep", b" " * 10 + b"{}", max_bytes=12).args == {}


def test_unknown_command_lists_the_known_ones():
    message = refused("explode", {})
    assert message == f"unknown command explode (known: {', '.join(COMMANDS)})"
    assert "calibrate, lasers_off, mode, point, relearn, sweep" in message
    # Odd names are escaped, not echoed raw.
    assert "\n" not in refused("a\nb", {})


def test_not_utf8():
    assert refused("mode", b'{"mode": "\xff"}') == "cmd/mode: payload is not UTF-8 (invalid byte at offset 10)"


@pytest.mark.parametrize("payload, why", [
    ("{", "not valid JSON"),
    ("mode=guard", "not valid JSON"),
    (' {"mode": "guard"} x', "not valid JSON"),
    ('{"pan_deg": NaN, "tilt_deg": 0}', "NaN is not a JSON number"),
    ('{"pan_deg": Infinity, "tilt_deg": 0}', "Infinity is not a JSON number"),
    ('{"mode": "guard", "mode": "blindaid"}', 'duplicate key "mode"'),
    ("[" * 100_000 + "]" * 100_000, "payload is not"),
    ('{"pan_deg": 1' + "0" * 5000 + ', "tilt_deg": 0}', "not usable JSON"),
])
def test_not_json(payload, why):
    name = "point" if "pan_deg" in payload else "mode"
    message = refused(name, payload, max_bytes=1 << 20)
    assert why in message


@pytest.mark.parametrize("name", ["sweep", "relearn", "lasers_off", "mode", "point"])
def test_an_empty_payload_is_no_command(name):
    # Issue 13, item 9: an empty message is how a retained command is cleared; it once stood for
    # {} and so started a sweep.
    assert refused(name, b"") == (f"cmd/{name}: empty payload: a command is a JSON object, at least {{}} "
                                  "(an empty message only clears a retained command)")


@pytest.mark.parametrize("payload, kind", [
    ("[]", "an array"), ('"sweep"', "a string"), ("1", "a number"), ("null", "null"), ("true", "a boolean"),
])
def test_json_that_is_not_an_object(payload, kind):
    assert refused("sweep", payload) == f"cmd/sweep: payload must be a JSON object, got {kind}"


def test_unknown_keys():
    assert refused("sweep", {"zones": 3}) == "cmd/sweep: unknown key \"zones\" (allowed: request_id)"
    message = refused("point", {"pan_deg": 0, "tilt_deg": 0, "pan": 1, "speed": 2})
    assert message == 'cmd/point: unknown keys "pan", "speed" (allowed: pan_deg, tilt_deg, request_id)'


@pytest.mark.parametrize("value", [True, False, "10", None, [10], {"deg": 10}])
def test_wrong_types_bool_is_not_a_number(value):
    message = refused("point", {"pan_deg": value, "tilt_deg": 0})
    assert message.startswith("cmd/point: pan_deg must be a number, got ")
    assert message.endswith(json.dumps(value))


def test_non_finite_numbers():
    message = refused("point", '{"pan_deg": 0, "tilt_deg": 1e999}')
    assert message == "cmd/point: tilt_deg must be a finite number, got Infinity"
    assert "finite" in refused("point", {"pan_deg": 10**400, "tilt_deg": 0})


def test_limits_are_written_with_the_digits_that_make_them_true():
    """A D46-17's pan stops at 179.99994°: 'outside -180..180°' for 180 would be a riddle."""
    limit = 3500 * 185.1428 / 3600  # the emulated unit's 3500 positions
    with pytest.raises(CommandError) as info:
        parse_command("point", b'{"pan_deg": 180, "tilt_deg": 0}', max_bytes=65536,
                      pan_limits=(-limit, limit), tilt_limits=TILT)
    assert str(info.value) == "cmd/point: pan_deg = 180 is outside the pan limits -179.99994..179.99994°"


def test_angles_outside_the_limits():
    assert refused("point", {"pan_deg": 159.5, "tilt_deg": 0}) == \
        "cmd/point: pan_deg = 159.5 is outside the pan limits -159..159°"
    assert refused("point", {"pan_deg": 0, "tilt_deg": -60}) == \
        "cmd/point: tilt_deg = -60 is outside the tilt limits -47..31°"


def test_bad_mode():
    assert refused("mode", {"mode": "party"}) == \
        'cmd/mode: mode must be one of rangefinder, blindaid, guard, got "party"'
    assert refused("mode", {"mode": 1}).endswith("got 1")
    assert refused("mode", {"mode": "Guard"}).endswith('got "Guard"')


@pytest.mark.parametrize("distances, why", [
    ([1.0], "distances_m has 1 entries, 3-20 expected"),
    ([1.0, 2.0], "distances_m has 2 entries, 3-20 expected"),
    ([1.0] * 21, "distances_m has 21 entries, 3-20 expected"),
    ([0.5, 0.6, 0.7],
     "distances_m spans only a factor 1.40 (0.5 to 0.7 m): it must span at least 1.5 (e.g. 0.5 to 2 m)"),
    ([0.5, 0.52, 1.0],
     "distances_m: 0.5 and 0.52 m follow each other but differ by under 10 %: the move cannot be seen"),
    ("1,2,3", "distances_m must be an array of numbers, got a string"),
    ([1.0, 0.2, 2.0], "distances_m[1] = 0.2 m is outside 0.25-5 m"),
    ([5.01, 1.0, 2.0], "distances_m[0] = 5.01 m is outside 0.25-5 m"),
    ([1.0, True, 2.0], "distances_m[1] must be a number, got true"),
    ([1.0, "2", 3.0], 'distances_m[1] must be a number, got "2"'),
])
def test_bad_calibration_distances(distances, why):
    assert refused("calibrate", {"distances_m": distances}) == f"cmd/calibrate: {why}"


def test_request_id_must_be_a_short_string():
    assert refused("sweep", {"request_id": 7}) == "cmd/sweep: request_id must be a string, got a number"
    assert refused("sweep", {"request_id": "x" * 129}) == \
        "cmd/sweep: request_id has 129 characters, at most 128 allowed"
    assert parse("sweep", {"request_id": "x" * 128}).request_id == "x" * 128
    assert "lone surrogate" in refused("sweep", '{"request_id": "\\ud800"}')


def test_long_values_are_shortened_in_messages():
    message = refused("mode", {"mode": "m" * 10_000})
    assert len(message) < 120


# ---- request_id_of ----


def test_request_id_of_a_bad_command_is_still_found():
    assert request_id_of(b'{"request_id": "r-9", "mode": "party"}') == "r-9"
    assert request_id_of(b'{"request_id": "r-9", "pan_deg": true}') == "r-9"


@pytest.mark.parametrize("payload", [
    b"", b"\xff\xfe", b"{", b"[]", b'"request_id"', b'{"request_id": 5}',
    b'{"request_id": "' + b"x" * 129 + b'"}', b'{"request_id": "\\ud800"}', b"[" * 100_000,
])
def test_request_id_of_gives_none_when_there_is_no_usable_one(payload):
    assert request_id_of(payload) is None


# ---- properties ----

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=True, allow_infinity=True) | st.text(),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=12,
)
# Objects made of the keys commands know, so that validation (not just decoding) is exercised.
known_keys = st.sampled_from(["mode", "pan_deg", "tilt_deg", "distances_m", "request_id", "zones"])
command_objects = st.dictionaries(
    known_keys,
    json_values | st.sampled_from(MODES) | st.lists(st.floats(0, 6) | st.integers(0, 6), max_size=22),
    max_size=4,
)
names = st.sampled_from(COMMANDS) | st.text(max_size=12)


def _check(name: str, payload: bytes) -> None:
    try:
        command = parse_command(name, payload, max_bytes=4096, pan_limits=PAN, tilt_limits=TILT)
    except CommandError as exc:
        assert len(str(exc).splitlines()) == 1, str(exc)
        assert str(exc)
    else:
        assert command.name == name and command.name in COMMANDS
        assert command.request_id is None or len(command.request_id) <= 128
        json.dumps(dict(command.args), allow_nan=False)  # what a command carries is plain and finite


@settings(max_examples=400, deadline=None)
@given(names, st.binary(max_size=200))
def test_arbitrary_bytes_raise_nothing_but_command_error(name, payload):
    _check(name, payload)


@settings(max_examples=400, deadline=None)
@given(names, json_values | command_objects)
def test_arbitrary_json_raises_nothing_but_command_error(name, value):
    payload = json.dumps(value).encode("utf-8")  # NaN and Infinity included, as Python writes them
    _check(name, payload)
    rid = request_id_of(payload)
    assert rid is None or isinstance(rid, str)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=200) | json_values.map(lambda v: json.dumps(v).encode()))
def test_request_id_of_never_raises(payload):
    rid = request_id_of(payload)
    assert rid is None or (isinstance(rid, str) and len(rid) <= 128)
