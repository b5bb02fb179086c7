"""`edge lasers off` (systemd's ExecStopPost) needs nothing but the pins: in a fresh process it loads
neither numpy nor OpenCV nor any ranging, mode or configuration module, and of the simulator only
its pins when the lasers are simulated; it still works when numpy and OpenCV cannot be imported."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# Run `edge lasers off` in-process, then print which modules it loaded.
_PROBE = """
import json, sys
for name in {blocked!r}:
    sys.modules[name] = None  # import fails, as if the package were broken
from edge.cli import main
rc = main({argv!r})
print(json.dumps({{"rc": rc, "modules": sorted(sys.modules)}}))
"""

HEAVY = ("numpy", "cv2", "edge.config", "edge.rig", "edge.ranging", "edge.vision", "edge.modes",
         "edge.calibration", "edge.capture", "edge.service", "edge.mqtt", "paho")


def _lasers_off(*args: str, blocked: tuple[str, ...] = (), env: dict | None = None) -> tuple[int, set[str], str]:
    code = _PROBE.format(blocked=list(blocked), argv=["lasers", "off", *args])
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60,
                            env={**os.environ, **(env or {})})
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    return report["rc"], set(report["modules"]), result.stdout


def _loaded(modules: set[str], prefix: str) -> list[str]:
    return sorted(m for m in modules if m == prefix or m.startswith(prefix + "."))


def test_lasers_off_on_simulated_lasers_loads_only_the_pins():
    rc, modules, out = _lasers_off()
    assert rc == 0 and "GPIO17 driven low" in out
    heavy = [m for prefix in HEAVY for m in _loaded(modules, prefix)]
    assert heavy == []
    assert _loaded(modules, "edge.sim") == ["edge.sim", "edge.sim.gpio"]


def test_lasers_off_on_gpio_loads_nothing_of_the_simulator():
    rc, modules, out = _lasers_off("--set", 'lasers.backend="gpio"', env={"GPIOZERO_PIN_FACTORY": "mock"})
    assert rc == 0 and "GPIO22 driven low" in out
    assert [m for prefix in (*HEAVY, "edge.sim") for m in _loaded(modules, prefix)] == []


def test_lasers_off_works_without_numpy_and_opencv():
    rc, modules, out = _lasers_off(blocked=("numpy", "cv2"))
    assert rc == 0 and "laser sloped: GPIO22 driven low (off)" in out


def test_lasers_off_ignores_a_mistake_in_a_lasers_geometry(tmp_path):
    """Only the wiring is read: a wrong direction must not keep a laser's pin from going off."""
    config = tmp_path / "edge.toml"
    config.write_text('[[rig.lasers]]\nname = "center"\npin = 5\ndirection = [0.0, 0.0, 7.0]\n'
                      'origin_m = [0.0, 0.0, 0.0]\n')
    rc, _, out = _lasers_off("--config", str(config))
    assert rc == 0 and "laser center: GPIO5 driven low (off)" in out


@pytest.mark.parametrize("text, message", [
    ('[[rig.lasers]]\nname = "center"\npin = 40\n', "rig.lasers[0].pin: must be a BCM GPIO number 0-27, got 40"),
    ('[lasers]\nbackend = "pigpio"\n', "lasers.backend: expected one of"),
    ('[rig]\nlasers = 3\n', "rig.lasers: expected a list of tables"),
    ('[rig\n', "not valid TOML"),
    (None, "no such configuration file"),
])
def test_a_broken_wiring_switches_off_the_default_pins_and_says_why(tmp_path, text, message):
    """systemd runs it after a crash: a broken or missing file must not leave a laser lit."""
    config = tmp_path / "edge.toml"
    if text is not None:
        config.write_text(text)
    result = subprocess.run([sys.executable, "-m", "edge", "lasers", "off", "--config", str(config)],
                            cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    warning = result.stderr.strip().splitlines()
    assert len(warning) == 1 and message in warning[0] and "default wiring (GPIO17, GPIO27, GPIO22)" in warning[0]
    for pin in (17, 27, 22):
        assert f"GPIO{pin} driven low (off)" in result.stdout


def test_an_unrelated_typo_does_not_matter(tmp_path):
    config = tmp_path / "edge.toml"
    config.write_text('[guard]\nlearn_sweep = 3\n[[rig.lasers]]\nname = "center"\npin = 5\n'
                      'origin_m = [0.035, 0.0, 0.0]\ndirection = [0.0, 0.0, 1.0]\n')
    result = subprocess.run([sys.executable, "-m", "edge", "lasers", "off", "--config", str(config)],
                            cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and result.stderr == ""
    assert "laser center: GPIO5 driven low (off)" in result.stdout
