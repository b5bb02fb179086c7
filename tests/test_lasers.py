"""The lasers on gpiozero's mock pins: off unless asked, off on every way out, never on too long,
and the simulated wires that tell the simulated camera what the lasers did."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import time
from dataclasses import replace

import numpy as np
import pytest
from gpiozero.pins.mock import MockFactory

from edge.config import LaserConfig, load_config
from edge.errors import HardwareError
from edge.hw.lasers import Lasers, LasersConfig, LaserWiring, force_all_off
from edge.parts import open_lasers
from edge.schema import FieldError
from edge.sim.gpio import LaserPin, Wires, laser_factory
from edge.sim.light import LaserLight

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# Two lasers switched high, one by an active-low driver (its pin is high when it is off).
LASERS = (
    LaserConfig("center", (0.035, 0.0, 0.0), (0.0, 0.0, 1.0), pin=17, reference=True),
    LaserConfig("parallel", (0.035, -0.04, 0.0), (0.0, 0.0, 1.0), pin=27),
    LaserConfig("sloped", (0.035, 0.0, 0.0), (0.0, 0.0, 1.0), pin=22, active_high=False),
)
WIRING = (LaserWiring("center", 17), LaserWiring("parallel", 27), LaserWiring("sloped", 22, active_high=False))
OFF_LEVEL = {17: False, 27: False, 22: True}


def _config(**lasers_changes):
    config = load_config(None)
    return replace(
        config,
        rig=replace(config.rig, lasers=LASERS),
        lasers=replace(config.lasers, **lasers_changes),
    )


def _levels(factory) -> dict[int, bool]:
    return {pin: bool(factory.pin(pin).state) for pin in OFF_LEVEL}


def _assert_all_off(factory) -> None:
    assert _levels(factory) == OFF_LEVEL


@pytest.fixture
def factory():
    return laser_factory()


def test_all_off_after_construction_and_outputs(factory):
    with Lasers(WIRING, LasersConfig(), factory) as lasers:
        _assert_all_off(factory)
        assert all(factory.pin(p).function == "output" for p in OFF_LEVEL)
        assert lasers.lit == frozenset()
        assert lasers.names == ("center", "parallel", "sloped")


def test_set_switches_exactly_the_named_lasers(factory):
    with Lasers(WIRING, LasersConfig(settle_ms=2.0), factory) as lasers:
        before = time.monotonic_ns()
        effective = lasers.set(["center", "sloped"])
        assert lasers.lit == {"center", "sloped"}
        assert _levels(factory) == {17: True, 27: False, 22: False}  # sloped is active-low: on = low
        assert before <= lasers.last_switch_ns <= time.monotonic_ns()
        assert effective == lasers.last_switch_ns + 2_000_000
        lasers.set(["parallel"])
        assert _levels(factory) == {17: False, 27: True, 22: True}
        # No change: the previous switch stands (a frame after it is already clean).
        switched = lasers.last_switch_ns
        assert lasers.set(["parallel"]) == switched + 2_000_000
        lasers.off()
        _assert_all_off(factory)


def test_unknown_laser_is_an_error_and_changes_nothing(factory):
    with Lasers(WIRING, LasersConfig(), factory) as lasers:
        lasers.set(["center"])
        with pytest.raises(ValueError, match="'nosuch'"):
            lasers.set(["center", "nosuch"])
        assert lasers.lit == {"center"}


def test_off_after_close_and_close_is_idempotent(factory):
    lasers = Lasers(WIRING, LasersConfig(), factory)
    lasers.set(lasers.names)
    lasers.close()
    _assert_all_off(factory)
    assert all(factory.pin(p).function == "input" for p in OFF_LEVEL)  # released
    lasers.close()
    with pytest.raises(HardwareError):
        lasers.set(["center"])
    # The pins are free again for the next owner.
    Lasers(WIRING, LasersConfig(), factory).close()


def test_off_after_an_exception_inside_with(factory):
    with pytest.raises(RuntimeError):
        with Lasers(WIRING, LasersConfig(), factory) as lasers:
            lasers.set(lasers.names)
            raise RuntimeError("sweep failed")
    _assert_all_off(factory)


def test_watchdog_switches_off_a_laser_on_too_long(factory, caplog):
    with Lasers(WIRING, LasersConfig(max_on_s=0.2), factory) as lasers:
        with caplog.at_level(logging.WARNING, logger="edge.hw.lasers"):
            lasers.set(["center"])
            start = time.monotonic()
            # Asking again does not extend the on-time: the limit is on continuous light.
            while time.monotonic() - start < 0.15:
                lasers.set(["center"])
                time.sleep(0.02)
            deadline = time.monotonic() + 2.0
            while lasers.lit and time.monotonic() < deadline:
                time.sleep(0.01)
        assert lasers.lit == frozenset() and lasers.watchdog_trips == 1
        _assert_all_off(factory)
        assert "max_on_s" in caplog.text
        on = [t for t, level in factory.pin(17).log if level is True]
        off = [t for t, level in factory.pin(17).log if level is False and t > on[0]]
        assert 0.19 <= (off[0] - on[0]) / 1e9 < 0.5
        # Set again, it lights again (and is watched again).
        lasers.set(["center"])
        assert lasers.lit == {"center"}


def test_force_all_off_drives_every_pin_to_its_off_level(factory):
    config = _config()
    lasers = open_lasers(config, factory)
    lasers.set(lasers.names)
    driven = force_all_off(config.rig.wiring(), factory)
    assert driven == [("center", 17, False), ("parallel", 27, False), ("sloped", 22, True)]
    _assert_all_off(factory)
    lasers.close()
    _assert_all_off(factory)


def test_force_all_off_on_pins_nobody_set_up():
    factory = MockFactory()  # a fresh process: pins are floating inputs
    force_all_off(_config().rig.wiring(), factory)
    _assert_all_off(factory)  # the active-low laser's pin reads high
    assert all(factory.pin(p).function == "output" for p in OFF_LEVEL)


def test_force_all_off_in_a_fresh_process():
    env = {**os.environ, "GPIOZERO_PIN_FACTORY": "mock"}
    result = subprocess.run(
        [sys.executable, "-m", "edge", "lasers", "off", "--set", "lasers.backend=\"gpio\""],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert "GPIO17 driven low" in result.stdout and "GPIO22 driven low" in result.stdout


def test_a_pin_must_be_a_bcm_number():
    with pytest.raises(FieldError, match="pin: must be a BCM GPIO number 0-27, got 99"):
        LaserWiring("center", 99)


def test_missing_pin_is_a_hardware_error(factory):
    with pytest.raises(HardwareError, match="center"):
        Lasers((replace(WIRING[0], pin=None),), LasersConfig(), factory)


# --- the simulated wires ------------------------------------------------------------------------


def test_wiring_reads_what_the_pins_did(factory):
    settle = 1_000_000
    with Lasers(WIRING, LasersConfig(), factory) as lasers:
        wiring = LaserLight(WIRING, factory, settle_ns=settle)
        assert isinstance(factory.pin(17), LaserPin)
        # Claiming an active-low pin as an output drives it low for a few microseconds before
        # gpiozero writes the off level (lgpio's gpio_claim_output does the same on a Pi): let that
        # blip's light pass before the window measured below.
        time.sleep(2 * settle / 1e9)
        lasers.set(["center", "sloped"])
        t_on = factory.pin(17).log[-1][0]  # the GPIO write, as the pin saw it
        s_on = factory.pin(22).log[-1][0]
        time.sleep(0.02)
        lasers.off()
        t_off = factory.pin(17).log[-1][0]
        s_off = factory.pin(22).log[-1][0]
        time.sleep(0.005)
        # Light follows the wire `settle` later; an active-low laser is lit while its pin is low.
        f = wiring.fractions(t_on, t_off + settle)
        assert f["parallel"] == 0.0
        assert f["center"] == pytest.approx((t_off - t_on) / (t_off + settle - t_on), abs=1e-9)
        # Each laser's light follows its own wire: under load the two writes may be far apart.
        window = t_off + settle - t_on
        lit = min(s_off + settle, t_off + settle) - max(s_on + settle, t_on)
        assert f["sloped"] == pytest.approx(max(lit, 0) / window, abs=1e-9)
        assert wiring.lit_at(max(t_on, s_on) + settle + 1) == {"center", "sloped"}
        assert "center" in wiring.lit_at(t_on + settle)
        assert wiring.lit_at(min(t_on, s_on) + settle - 100_000) == frozenset()
        # Per row, vectorised: rows exposed before, across and after the switch-off.
        exposure = 4_000_000
        rows = np.array([t_on - exposure - 10, t_off + settle - exposure // 2, t_off + settle + 1])
        got = wiring.row_fractions(rows, exposure)["center"]
        np.testing.assert_allclose(got, [0.0, 0.5, 0.0], atol=1e-6)
        lasers.set(["center"])
    # A closed (input) pin is dark, whatever level it floats at.
    t_close, level = factory.pin(17).log[-1]
    assert level is None
    time.sleep(0.002)
    assert wiring.lit_at(time.monotonic_ns()) == frozenset()
    assert wiring.fractions(t_close + settle + 10, time.monotonic_ns())["center"] == 0.0


# --- wires that outlive a process ---------------------------------------------------------------


def test_wires_keep_a_killed_process_levels_for_the_next_one(tmp_path):
    """Two factories on one wires file stand for a process that dies with a laser on and the
    fresh one (systemd's ExecStopPost) that finds it so and switches it off."""
    wires = tmp_path / "wires"
    dying = laser_factory(wires)
    lasers = Lasers(WIRING, LasersConfig(), dying)
    lasers.set(["center", "sloped"])  # ...and the process is killed here: no close()
    fresh = laser_factory(wires)
    assert LaserLight(WIRING, fresh).lit_at(time.monotonic_ns()) == {"center", "sloped"}
    assert fresh.pin(17).function == "output" and fresh.pin(17).state  # driven, as the wire was left
    assert fresh.pin(22).function == "output" and not fresh.pin(22).state  # active low: lit while low
    force_all_off(_config().rig.wiring(), fresh)
    _assert_all_off(fresh)
    assert Wires(wires).levels() == OFF_LEVEL
    assert LaserLight(WIRING, laser_factory(wires)).lit_at(time.monotonic_ns()) == frozenset()
    lasers.close()  # a closed device leaves its wire undriven: dark, whatever it floats to
    assert Wires(wires).levels() == {}


def test_a_file_that_is_not_a_wires_file_is_a_hardware_error_naming_it(tmp_path):
    bad = tmp_path / "notes.txt"
    bad.write_text("hello")
    with pytest.raises(HardwareError, match=r"lasers.sim_wires: .*notes.txt is not a wires file \(5 bytes"):
        laser_factory(bad)
    bad.write_bytes(bytes([7] * Wires.SIZE))
    with pytest.raises(HardwareError, match="not a wires file"):
        laser_factory(bad)
    with pytest.raises(HardwareError, match="lasers.sim_wires: cannot open"):
        laser_factory(tmp_path / "no" / "such" / "dir" / "wires")


def test_edge_lasers_off_sets_the_simulated_wires(tmp_path):
    wires = tmp_path / "wires"
    lasers = Lasers(_config().rig.wiring(), LasersConfig(), laser_factory(wires))
    lasers.set(["center", "parallel", "sloped"])
    result = subprocess.run(
        [sys.executable, "-m", "edge", "lasers", "off", "--set", f"lasers.sim_wires={json.dumps(str(wires))}"],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert f"only the simulated wires in {wires}" in result.stdout
    assert Wires(wires).levels() == {17: False, 27: False, 22: False}  # config/sim.toml: all active high
    lasers.close()
