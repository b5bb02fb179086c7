"""The PTU-D46 driver (edge.hw.ptu): the real driver over pyserial against the emulator on a pty.

Nothing of the driver is mocked: every test talks the ASCII protocol through a pseudo-terminal.
Speeds are set high (120 °/s) so that moves take a fraction of a second.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import serial

from edge.errors import HardwareError
from edge.hw import ptu
from edge.hw.ptu import PanTiltUnit, PtuConfig, trapezoid_s
from edge.parts import open_ptu
from edge.sim.ptu_emulator import Emulator

RES = 185.1428  # arc-seconds per position of a D46-17
RES_DEG = RES / 3600.0
FAST = PtuConfig(port="", timeout_s=0.3, speed_deg_s=120.0, accel_deg_s2=1200.0, settle_ms=0.0)


@pytest.fixture
def emu():
    e = Emulator(reset_s=0.3)
    yield e
    e.close()


@pytest.fixture
def unit(emu):
    u = PanTiltUnit.open(dataclasses.replace(FAST, port=emu.port))
    yield u
    u.close()


def warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


# ---- set-up ----

def test_initialise_from_power_up_state(emu):
    ser = serial.serial_for_url(emu.port, 9600, timeout=0.1)
    emu.inject("reset")  # as if just switched on: banner pending, echo on, verbose
    assert emu.echo and emu.verbose
    unit = PanTiltUnit(dataclasses.replace(FAST, port=emu.port), ser)
    with unit:
        unit.initialise()
        assert list(emu.commands)[:2] == ["ED", "FT"]
        assert not emu.echo and not emu.verbose
        assert unit.res_arcsec == (RES, RES)  # a real number, not 185
        assert unit.resolution_deg == pytest.approx((RES_DEG, RES_DEG))
        (pn, px), (tn, tx) = unit.limits_deg
        assert (pn, px) == pytest.approx((-3090 * RES_DEG, 3090 * RES_DEG))
        assert (tn, tx) == pytest.approx((-907 * RES_DEG, 604 * RES_DEG))
        assert emu.pan.speed == emu.tilt.speed == round(120.0 / RES_DEG)
        assert emu.pan.accel == round(1200.0 / RES_DEG)
        assert "PTU-D46" in unit.model
        unit.initialise()  # again, from terse and no echo: still fine
        assert unit.position() == (0.0, 0.0)


@pytest.mark.parametrize("speed", [200.0, 1.0])
def test_speed_outside_the_units_bounds_is_refused_not_clamped(emu, speed):
    with pytest.raises(HardwareError, match=r"ptu\.speed_deg_s = .* \(2\.93–149\.14 °/s\)") as err:
        PanTiltUnit.open(dataclasses.replace(FAST, port=emu.port, speed_deg_s=speed))
    assert "\n" not in str(err.value)
    assert not any(c.startswith(("PS", "TS")) for c in emu.commands)
    assert emu.pan.speed == 1000  # the unit's own, untouched


def test_open_sim_starts_the_emulator_and_close_stops_it():
    unit, emulator = open_ptu(dataclasses.replace(FAST, port="sim://"))
    assert emulator is not None and unit.port == emulator.port
    assert unit.move(3.0, -2.0) == pytest.approx((58 * RES_DEG, -39 * RES_DEG))
    assert emulator.pose() == pytest.approx((58 * RES_DEG, -39 * RES_DEG))
    unit.close()
    assert not emulator._thread.is_alive()


def test_a_port_that_does_not_exist_is_one_line():
    with pytest.raises(HardwareError, match=r"cannot open .*/dev/nonexistent-ptu.*check ptu.port"):
        PanTiltUnit.open(dataclasses.replace(FAST, port="/dev/nonexistent-ptu"))


# ---- degrees and positions ----

def test_degrees_round_to_positions(unit, emu):
    assert unit.to_positions(0.0514, 0.02) == (1, 0)
    assert unit.to_positions(-0.0514, -0.0258) == (-1, -1)
    reached = unit.move(0.0514, 0.02)
    assert emu.positions() == (1, 0)
    assert reached == pytest.approx((RES_DEG, 0.0))
    assert unit.move(10.0, 5.0) == pytest.approx((194 * RES_DEG, 97 * RES_DEG))
    assert unit.position() == pytest.approx((194 * RES_DEG, 97 * RES_DEG))


@pytest.mark.parametrize("pan, tilt, words", [
    (170.0, 0.0, r"pan 170° is outside the pan-tilt unit's limits -158\.91424°…158\.91424°"),
    (0.0, -50.0, r"tilt -50° is outside the pan-tilt unit's limits -46\.6457°…31\.06285°"),
])
def test_targets_outside_the_limits_are_refused_and_nothing_is_sent(unit, emu, pan, tilt, words):
    sent = len(emu.commands)
    with pytest.raises(HardwareError, match=words) as err:
        unit.move(pan, tilt)
    assert "\n" not in str(err.value)
    assert len(emu.commands) == sent


def test_move_time_is_a_trapezoid_of_the_longer_axis(unit):
    v, a = FAST.speed_deg_s, FAST.accel_deg_s2
    assert unit.move_time_s(0, 0, 5, 1) == pytest.approx(2 * math.sqrt(5 / a))  # never at full speed
    assert unit.move_time_s(0, 0, 100, -40) == pytest.approx(100 / v + v / a)
    assert unit.move_time_s(10, 10, 10, 10) == 0.0


def test_await_timeout_grows_with_the_distance_slow_long_move(emu, caplog):
    config = dataclasses.replace(FAST, port=emu.port, speed_deg_s=15.0, accel_deg_s2=60.0)
    with PanTiltUnit.open(config) as unit:
        predicted = unit.move_time_s(0, 0, 40, 10)  # 2.9 s, far beyond any reply timeout
        assert predicted > 5 * config.timeout_s
        started = time.monotonic()
        reached = unit.move(40.0, 10.0)
        elapsed = time.monotonic() - started
    assert reached == pytest.approx((778 * RES_DEG, 194 * RES_DEG))
    assert emu.last_motion_s == pytest.approx(predicted, rel=0.2)
    assert elapsed > 0.5 * predicted  # it waited for the motion (real time: the emulator's clock is)
    assert not warnings(caplog)  # and did not take the long wait for a lost reply: no retries


def test_position_mid_move_is_where_the_head_is(unit, emu):
    worker = threading.Thread(target=unit.move, args=(120.0, 0.0))
    worker.start()
    time.sleep(0.3)
    pan, _ = emu.pose()
    worker.join(timeout=5)
    assert 5.0 < pan < 115.0  # on its way
    assert emu.pose() == pytest.approx((2333 * RES_DEG, 0.0))


# ---- the line ----

def test_async_notice_glued_to_a_reply_is_logged_and_skipped(unit, emu, caplog):
    unit.move(5.0, 0.0)
    emu.inject("notice")
    assert unit.position() == pytest.approx((97 * RES_DEG, 0.0))
    assert any("limit notice !P" in w for w in warnings(caplog))


def test_lone_async_notice_is_logged(unit, emu, caplog):
    emu.emit(b"!T")
    time.sleep(0.05)
    assert unit.position() == (0.0, 0.0)
    assert any("limit notice !T" in w for w in warnings(caplog))


def test_dropped_replies_are_retried(unit, emu, caplog):
    emu.inject("drop", count=2)
    assert unit.move(20.0, 3.0) == pytest.approx((389 * RES_DEG, 58 * RES_DEG))
    assert sum("no reply" in w for w in warnings(caplog)) == 2


def test_three_dropped_replies_are_an_error_then_it_recovers(unit, emu):
    emu.inject("drop", count=3)
    with pytest.raises(HardwareError, match=r"does not answer \(no reply to PP in 3 tries"):
        unit.position()
    assert unit.position() == (0.0, 0.0)


def test_garbled_reply_resynchronises(unit, emu, caplog):
    emu.inject("garble")
    assert unit.position() == (0.0, 0.0)
    assert any("garbled reply" in w for w in warnings(caplog))
    emu.inject("garble", count=3)
    with pytest.raises(HardwareError, match=r"garbled replies to PP .*check ptu.baudrate"):
        unit.position()


def test_silence_shorter_than_the_retry_budget_is_ridden_out(unit, emu):
    emu.inject("silence", seconds=0.5 * unit.retry_budget_s)
    assert unit.move(-8.0, 2.0) == pytest.approx((-156 * RES_DEG, 39 * RES_DEG))


def test_hung_unit_is_an_error_in_bounded_time(unit, emu):
    emu.inject("hang")
    started = time.monotonic()
    with pytest.raises(HardwareError) as err:
        unit.move(1.0, 1.0)
    assert time.monotonic() - started < 5.0
    message = str(err.value)
    assert message.startswith(f"pan-tilt unit on {emu.port} does not answer")
    assert message.endswith("check power and cable") and "\n" not in message
    started = time.monotonic()
    unit.close()  # the move was not seen to end: one halt is tried, briefly
    assert time.monotonic() - started < 1.0
    assert not unit._ser.is_open


def test_reset_between_moves_is_noticed_and_the_unit_set_up_again(unit, emu, caplog):
    unit.move(20.0, 5.0)
    emu.inject("reset")  # power-cycled: echo, verbose, default speed, position 0
    assert emu.pan.speed == 1000
    assert unit.move(-20.0, -5.0) == pytest.approx((-389 * RES_DEG, -97 * RES_DEG))
    assert unit.resets == 1
    assert not emu.echo and not emu.verbose and emu.pan.speed == 2333
    assert any("reset or power-cycled" in w for w in warnings(caplog))


def test_reset_mid_sweep_move_is_recovered_and_the_move_repeated(unit, emu, caplog):
    threading.Timer(0.25, emu.inject, ("reset",)).start()
    reached = unit.move(100.0, 20.0)  # about 0.9 s; the reset hits it on the way
    assert reached == pytest.approx((1944 * RES_DEG, 389 * RES_DEG))
    assert emu.positions() == (1944, 389)
    assert unit.resets == 1
    assert any("reset during a move" in w for w in warnings(caplog))


def test_exchanges_from_two_threads_do_not_mix(unit):
    unit.move(7.0, -3.0)
    results: list[tuple[float, float]] = []

    def ask() -> None:
        for _ in range(15):
            results.append(unit.position())

    threads = [threading.Thread(target=ask) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=10)
    assert results == [pytest.approx((136 * RES_DEG, -58 * RES_DEG))] * 45


def test_error_reply_carries_the_units_words(unit):
    with pytest.raises(HardwareError, match=r"refused PP9999: Illegal Pan position argument"):
        unit._exchange("PP9999")


def test_halt_and_close(unit, emu):
    unit.halt()
    assert list(emu.commands)[-1] == "H"
    unit.close()
    assert not unit._ser.is_open
    unit.close()  # twice is fine


# ---- edge ptu ----

def _wired() -> bool:
    from edge.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return "ptu" in sub.choices


def _edge_ptu(argv: list[str], capsys) -> str:
    if _wired():
        edge = Path(sys.executable).with_name("edge")
        done = subprocess.run([str(edge), "ptu", *argv], capture_output=True, text=True, timeout=30)
        assert done.returncode == 0, done.stderr
        return done.stdout
    parser = argparse.ArgumentParser(prog="edge")
    ptu.add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["ptu", *argv])
    assert args.func(args) == 0
    return capsys.readouterr().out


def test_cli_status_move_home(emu, capsys):
    out = _edge_ptu(["--port", emu.port, "status"], capsys)
    assert "185.1428″" in out and "-158.91424°…+158.91424°" in out and "pan +0.0000°" in out
    out = _edge_ptu(["--port", emu.port, "--set", "ptu.settle_ms=0", "move", "10", "5"], capsys)
    assert "pan +9.9771°, tilt +4.9886°" in out
    assert emu.positions() == (194, 97)
    out = _edge_ptu(["--port", emu.port, "home"], capsys)
    assert "pan +0.0000°, tilt +0.0000°" in out
    assert emu.positions() == (0, 0)


def test_emulator_trapezoid_matches_the_drivers():
    assert trapezoid_s(0, 1000, 2000) == 0.0
    assert trapezoid_s(100, 1000, 2000) == pytest.approx(2 * math.sqrt(100 / 2000))
    assert trapezoid_s(3000, 1000, 2000) == pytest.approx(3.5)
