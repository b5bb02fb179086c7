"""No laser stays on, however the service ends — here SIGKILL, then systemd's ExecStopPost.

The simulated pins keep their levels in a wires file (``[lasers] sim_wires``), as real wires do
after the process that drove them dies, so these tests see what a kill leaves behind and what the
next process — the unit's own ExecStopPost command — finds and does. (SIGTERM, SIGINT and an
exception in the loop: test_service_local.py; the watchdog's SIGABRT: test_service.py.)"""

from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

from test_systemd_unit import UNIT, one, parse_unit

from edge.config import load_config
from edge.sim.gpio import Wires

REPO = Path(__file__).resolve().parents[1]


def write_config(tmp_path: Path) -> tuple[Path, Path]:
    """A site config for the simulated rig whose pins live in a wires file: (config, wires)."""
    wires = tmp_path / "wires"
    config = tmp_path / "edge.toml"
    config.write_text(
        f'mode = "rangefinder"\n[lasers]\nsim_wires = {json.dumps(str(wires))}\n'
        f'[service]\nstate_dir = {json.dumps(str(tmp_path / "state"))}\n[mqtt]\nenabled = false\n'
        '[rangefinder]\npan_deg = -90.0\n'
    )
    return config, wires


def exec_stop_post(config: Path) -> subprocess.CompletedProcess:
    """Run the unit's ExecStopPost as systemd would, from this checkout and with `config`."""
    argv = shlex.split(one(parse_unit(UNIT.read_text()), "Service", "ExecStopPost"))
    assert argv[0].endswith("/bin/edge") and argv[-2] == "--config", argv
    argv = [sys.executable, "-m", "edge", *argv[1:-1], str(config)]
    return subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=60)


def lit(wires: Path, config: Path) -> set[str]:
    """The lasers whose wire carries their active level."""
    levels = Wires(wires).levels()
    return {laser.name for laser in load_config(config).rig.wiring()
            if levels.get(laser.pin) is laser.active_high}


def assert_all_off(wires: Path, config: Path) -> None:
    levels = Wires(wires).levels()
    for laser in load_config(config).rig.wiring():
        assert levels.get(laser.pin) is (not laser.active_high), f"laser {laser.name}: GPIO{laser.pin} {levels}"


def test_sigkill_leaves_a_laser_on_and_exec_stop_post_switches_it_off(tmp_path: Path) -> None:
    config, wires = write_config(tmp_path)
    left_on: set[str] = set()
    for _attempt in range(3):  # the kill may land in a laser-off frame: then try again
        wires.unlink(missing_ok=True)
        proc = subprocess.Popen([sys.executable, "-m", "edge", "run", "--config", str(config), "--for", "60"],
                                cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 40
            while time.monotonic() < deadline and proc.poll() is None:
                if wires.exists() and wires.stat().st_size == Wires.SIZE and lit(wires, config):
                    break
                time.sleep(0.001)
            assert proc.poll() is None, proc.communicate()[1][-2000:]
            os.kill(proc.pid, signal.SIGKILL)
            proc.communicate(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        assert proc.returncode == -signal.SIGKILL
        left_on = lit(wires, config)
        if left_on:
            break
    # The kill left a laser on: nothing in the dead process could switch it off.
    assert left_on, "no attempt left a laser on; the test proves nothing"
    time.sleep(0.3)
    assert lit(wires, config) == left_on
    result = exec_stop_post(config)
    assert result.returncode == 0, result.stderr
    assert "driven low (off)" in result.stdout
    assert_all_off(wires, config)
    assert lit(wires, config) == set()
