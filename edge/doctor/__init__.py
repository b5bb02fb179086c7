"""`edge doctor`: every part tried the way the service will use it, one line each.

The first person to build a rig meets every problem at once — a laser wired backwards, a camera
that auto-exposes, a unit at another baud rate, a broker that refuses the device. The doctor tries
each thing in turn and says, per line, ``ok`` and what it found, or what is wrong and what to do:

- the computer (:mod:`edge.doctor.system`): Python, the packages and their versions, gpiozero's pin
  factory, the user's groups and the device nodes the real parts need, the state folder, the clock;
- the rig (:mod:`edge.doctor.rig`): the calibration, the pan-tilt unit (answers, firmware, limits,
  resolution, reaches two positions), the camera (frames at the configured rate, with the exposure
  and gain fixed), each laser switched alone (its spot where the rig says, and none when off:
  :mod:`edge.doctor.spots`), its frames (what kind, and what ranging makes of them: JPEG or not,
  the channel read, a Bayer filter's red pixels, the noise: :mod:`edge.doctor.frames`), the
  camera's tone curve against the one ranging undoes (:mod:`edge.doctor.tone`);
- the broker (:mod:`edge.doctor.broker`): credentials, TLS, publishing to the device's own topics.

On the simulator the same checks run against the virtual rig, whose fault switches
(``[[sim.camera_faults]]``, ``[[sim.laser_faults]]``, ``[[sim.ptu_faults]]``, ``[sim.rig_error]``)
each make their own line fail. The checks that need numpy say so, and the others still run, when
numpy cannot be imported: this module and those it imports at start are light.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from edge.doctor.checklist import Checklist, NotRun
from edge.doctor.settings import Settings, from_config, from_table, table_of
from edge.doctor.system import (
    check_clock,
    check_devices,
    check_packages,
    check_pin_factory,
    check_python,
    check_state_dir,
    import_problem,
)

if TYPE_CHECKING:
    from edge.config import Config


@dataclass
class Examination:
    checks: Checklist
    settings: Settings
    elapsed_s: float

    def json(self) -> str:
        return self.checks.json(config=self.settings.source, simulated=self.settings.all_simulated,
                                elapsed_s=round(self.elapsed_s, 2))


def examine(path: str | None = None, overrides: list[str] | tuple[str, ...] = ()) -> Examination:
    """Run every check on the configuration at `path` (default config/sim.toml) with `overrides`.
    A configuration that cannot be read is a ConfigError (bad input), as for every command."""
    started = time.monotonic()
    data, source = table_of(path, list(overrides))
    missing = import_problem("numpy")
    config: Config | None = None
    if missing is None:
        from edge.config import load_config

        config = load_config(path, list(overrides))
        settings = from_config(config)
    else:
        settings = from_table(data, source)  # the light parts' settings only
    checks = Checklist()
    checks.run("python", check_python)
    checks.run("packages", lambda: check_packages(settings))
    checks.run("pin factory", lambda: check_pin_factory(settings))
    checks.run("groups & devices", lambda: check_devices(settings))
    checks.run("state folder", lambda: check_state_dir(settings))
    checks.run("clock", lambda: check_clock(settings))
    from edge.doctor.rig import RigChecks, unseen_lasers

    with contextlib.ExitStack() as stack:
        rig = RigChecks(config, settings, stack, missing)
        checks.run("calibration", rig.calibration)
        checks.run("pan-tilt unit", rig.ptu)
        checks.run("camera", rig.camera_check)
        for index, wire in enumerate(settings.wiring):
            checks.run(f"laser {wire.name}", lambda name=wire.name, i=index: rig.laser(name, i))  # type: ignore[misc]
        checks.lines[:] = unseen_lasers(checks.lines, [f"laser {wire.name}" for wire in settings.wiring])
        # (After the lasers, whose frames it would otherwise shift in the simulator's noise; before
        # the tone curve, which leaves the camera at other settings.)
        checks.run("frames", rig.frames_check)
        checks.run("tone curve", rig.tone_curve)
    checks.run("broker", lambda: _broker(config, missing))
    return Examination(checks, settings, time.monotonic() - started)


def _broker(config: Config | None, missing: str | None) -> str:
    if config is None:
        raise NotRun("needs numpy (to read [mqtt] as the service does), which cannot be imported (see packages)")
    from edge.doctor.broker import check_broker

    return check_broker(config)
