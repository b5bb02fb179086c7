"""The rig as a whole, on the service's code paths: one zone, one sweep, the range finder for 10 s,
and the lasers off after a SIGKILL once systemd's ExecStopPost has run.

Aim the unit (``[rangefinder]`` pan_deg, tilt_deg) at a matte wall 1-3 m away and keep the room as
it is while they run. What a failure means: the zone's, that the lasers' spots are not where the
rig says (calibrate) or the wall is out of range; the sweep's, a part that fails within the unit's
limits (the zone's `detail` names it); the range finder's, frames dropped (fewer ranges than frames)
or the wall not ranged; the kill's, a laser left on by a killed service: never run the service
until it passes."""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from edge.config import Config

pytestmark = pytest.mark.hardware

REPO = Path(__file__).resolve().parents[2]
UNIT = REPO / "systemd" / "edge.service"


def test_one_zone_at_the_aim(rig_config: Config) -> None:
    from edge.parts import open_parts
    from edge.sweep import sweeper_for

    aim = (rig_config.rangefinder.pan_deg, rig_config.rangefinder.tilt_deg)
    with open_parts(rig_config) as parts:
        result = sweeper_for(parts).zone(0, *aim)
    print(f"zone at pan {aim[0]:+g}°, tilt {aim[1]:+g}°: {result.status} {result.range_m} m {result.detail}")
    lo, hi = rig_config.rig.range_limits_m
    assert result.status == "ok", result.detail
    assert result.range_m is not None and lo <= result.range_m <= hi
    assert set(result.lasers) == set(rig_config.rig.build().laser_names), "every laser's spot in the range"


def test_one_sweep(rig_config: Config) -> None:
    from edge.sweep import run_configured_sweep

    report = run_configured_sweep(rig_config).report
    statuses = [r.status for r in report.results]
    print(f"sweep: {statuses.count('ok')} of {len(statuses)} zones ok, {report.faults} faults, "
          f"{report.duration_s:.1f} s against a limit of {report.limit_s:.1f} s")
    assert len(report.results) == len(rig_config.sweep.poses())
    # Zones beyond the unit's limits are faults (a D46-17 stops at ±159°); no other zone may be.
    beyond = [r for r in report.results if r.status == "fault" and "outside the pan-tilt unit's limits" in r.detail]
    others = [f"zone {r.index}: {r.detail}" for r in report.results if r.status == "fault" and r not in beyond]
    assert not others, "\n".join(others)
    assert statuses.count("ok") >= 1


def _service_sets(config: Config, state: Path) -> list[str]:
    return ["--set", f'service.state_dir="{state}"', "--set", "service.watchdog=false", "--set", 'mode="rangefinder"']


def test_the_range_finder_for_10_s(rig_config: Config, rig_config_path: Path, broker, subscriber,
                                   tmp_path: Path) -> None:
    """`edge run` in range-finder mode for 10 s of the rig's time, to a local broker: a range per
    frame, and the wall ranged."""
    sets = [*_service_sets(rig_config, tmp_path / "state"), "--set", f'mqtt.host="{broker.host}"',
            "--set", f"mqtt.port={broker.port}", "--set", 'mqtt.username=""', "--set", 'mqtt.password_file=""',
            "--set", "mqtt.tls.enabled=false"]
    done = subprocess.run([sys.executable, "-m", "edge", "run", "--config", str(rig_config_path), *sets,
                           "--for", "10"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    topic = f"{rig_config.mqtt.prefix}/{rig_config.device.resolved_id()}/range"
    ranges = [json.loads(m.payload) for m in subscriber.messages(topic)]
    ok = [r for r in ranges if r["status"] == "ok"]
    frames = 10 * rig_config.camera.frame_rate_hz
    print(f"range finder: {len(ranges)} ranges in 10 s ({frames:.0f} frames), {len(ok)} ok, "
          f"median {sorted(r['range_m'] for r in ok)[len(ok) // 2] if ok else None} m")
    assert len(ranges) >= 0.8 * frames, "frames dropped: fewer ranges than frames"
    assert len(ok) >= 0.8 * len(ranges), "the wall at the aim is not ranged"


def _exec_stop_post(config: Path) -> subprocess.CompletedProcess:
    """The unit's ExecStopPost as systemd runs it, with this checkout's edge and `config`."""
    line = next(x for x in UNIT.read_text().splitlines() if x.startswith("ExecStopPost="))
    argv = shlex.split(line.partition("=")[2])
    assert argv[0].endswith("/bin/edge") and argv[-2] == "--config", argv
    return subprocess.run([sys.executable, "-m", "edge", *argv[1:-1], str(config)], cwd=REPO,
                          capture_output=True, text=True, timeout=60)


def _pin_reader(config: Config):
    """How to read each laser pin's level from outside the service: `pinctrl` on a Pi (Raspberry
    Pi OS Bookworm), the simulated wires file on the simulator."""
    if config.lasers.backend == "sim":
        if not config.lasers.sim_wires:
            pytest.skip("on the simulator this needs lasers.sim_wires in the configuration file "
                        "(tests/test_laser_safety.py covers it there)")
        from edge.sim.gpio import Wires

        return lambda pin: Wires(config.lasers.sim_wires).level(pin)
    pinctrl = shutil.which("pinctrl")
    if pinctrl is None:
        pytest.skip("needs `pinctrl` (Raspberry Pi OS Bookworm: apt install raspi-utils) to read the pins")

    def level(pin: int) -> bool | None:
        out = subprocess.run([pinctrl, "get", str(pin)], capture_output=True, text=True, timeout=10).stdout
        found = re.search(r"\|\s*(hi|lo)\b", out)
        return None if found is None else found.group(1) == "hi"

    return level


def test_the_lasers_are_off_after_sigkill_and_exec_stop_post(rig_config: Config, rig_config_path: Path,
                                                              tmp_path: Path) -> None:
    level = _pin_reader(rig_config)
    wiring = rig_config.rig.wiring()

    def lit() -> set[str]:
        return {w.name for w in wiring if level(w.pin) is w.active_high}

    proc = subprocess.Popen([sys.executable, "-m", "edge", "run", "--config", str(rig_config_path),
                             *_service_sets(rig_config, tmp_path / "state"), "--set", "mqtt.enabled=false",
                             "--for", "120"], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and proc.poll() is None and not lit():
            time.sleep(0.002)  # the range finder lights a laser every other frame
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        os.kill(proc.pid, signal.SIGKILL)
        proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    print(f"left on by the kill: {sorted(lit()) or 'none (the kill fell between two frames)'}")
    done = _exec_stop_post(rig_config_path)
    assert done.returncode == 0, done.stderr
    assert lit() == set(), "a laser is still on after ExecStopPost: do not run the service"
    for w in wiring:
        assert level(w.pin) is (not w.active_high), f"laser {w.name}: GPIO{w.pin} is not driven to its off level"
