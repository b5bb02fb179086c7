"""The PTU-D46 emulator (edge.sim.ptu_emulator) seen from the serial line, byte by byte."""

from __future__ import annotations

import time

import pytest
import serial

from edge.sim.ptu_emulator import Emulator


@pytest.fixture
def line():
    emu = Emulator(reset_s=0.2)
    ser = serial.serial_for_url(emu.port, 9600, timeout=1.0)
    yield emu, ser
    ser.close()
    emu.close()


def ask(ser: serial.Serial, cmd: str) -> str:
    ser.write(cmd.encode() + b" ")
    return ser.read_until(b"\n").decode("latin-1")


def test_power_up_echo_and_verbose_then_terse(line):
    emu, ser = line
    assert ask(ser, "PP") == "PP * Current Pan position is 0\r\n"
    assert ask(ser, "PR") == "PR * 185.1428 seconds arc per Pan position\r\n"
    assert ask(ser, "ED") == "ED *\r\n"  # the echo of ED itself still comes back
    assert ask(ser, "FT") == "*\r\n"
    assert ask(ser, "TN") == "* -907\r\n"
    assert ask(ser, "PU") == "* 2900\r\n"


def test_motion_is_trapezoidal_and_await_answers_when_it_ended(line):
    emu, ser = line
    ask(ser, "ED"), ask(ser, "FT")
    assert ask(ser, "PS2000") == "*\r\n" and ask(ser, "PA20000") == "*\r\n"
    assert ask(ser, "PP2000") == "*\r\n"  # 1.1 s
    time.sleep(0.3)
    mid = int(ask(ser, "PP")[1:])
    assert 100 < mid < 1900  # a query mid-move says where the axis is now
    assert emu.moving
    started = time.monotonic()
    assert ask(ser, "A") == "*\r\n"
    assert time.monotonic() - started > 0.3
    assert not emu.moving and ask(ser, "PP") == "* 2000\r\n"
    assert emu.last_motion_s == pytest.approx(2000 / 2000 + 2000 / 20000)


def test_errors_and_bounds(line):
    emu, ser = line
    ask(ser, "ED"), ask(ser, "FT")
    assert ask(ser, "PP3091").startswith("! Illegal Pan position argument")
    assert ask(ser, "TP-908").startswith("! Illegal Tilt position argument")
    assert ask(ser, "PS3000").startswith("! Illegal Pan speed argument")
    assert ask(ser, "PS56").startswith("! Illegal Pan speed argument")
    assert ask(ser, "XYZ") == "! Illegal command\r\n"
    assert emu.positions() == (0, 0) and emu.pan.speed == 1000


def test_halt_and_reset(line):
    emu, ser = line
    ask(ser, "ED"), ask(ser, "FT")
    ask(ser, "PP3000")
    time.sleep(0.2)
    assert ask(ser, "H") == "*\r\n"
    stopped = emu.positions()[0]
    assert 0 < stopped < 3000 and not emu.moving
    ser.write(b"R ")
    assert ser.read_until(b"\n") == b"*\r\n"  # only once recalibrated
    assert emu.positions() == (0, 0) and emu.echo and emu.verbose


def test_faults(line):
    emu, ser = line
    ask(ser, "ED"), ask(ser, "FT")
    emu.inject("notice")
    assert ask(ser, "PP") == "!P* 0\r\n"
    emu.inject("garble")
    garbled = ask(ser, "PP")
    assert garbled.endswith("\r\n") and garbled[0] not in "*!"
    emu.inject("drop")
    ser.write(b"PP ")
    assert ser.read_until(b"\n") == b""  # nothing within the timeout
    assert ask(ser, "PP") == "* 0\r\n"
    emu.inject("reset")
    assert ser.read_until(b"\n").startswith(b"Pan-Tilt Controller")  # the power-up banner
    ser.reset_input_buffer()
    emu.inject("hang")
    ser.write(b"PP ")
    assert ser.read_until(b"\n") == b""
    with pytest.raises(ValueError):
        emu.inject("smoke")
