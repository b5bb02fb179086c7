"""The install, checked without a Pi: a venv made with --system-site-packages (as ./dev and
systemd/README.md make it) takes picamera2 from the system's Python, as Raspberry Pi OS's apt
installs it; and the aarch64 wheel check's own pieces (tools/check_wheels.py, run by hand: it asks
the package index)."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import venv
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _system_python_with_picamera2(root: Path) -> Path:
    """A stand-in for Raspberry Pi OS's Python: a prefix whose standard library is this Python's
    and whose site-packages holds a `picamera2` of its own (as apt's python3-picamera2 puts one in
    the system's dist-packages). Returns its bin folder, what a venv's `home` names."""
    lib = root / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}"
    real = Path(sys.base_prefix) / lib.relative_to(root)
    (lib / "site-packages" / "picamera2").mkdir(parents=True)
    for entry in real.iterdir():
        if entry.name != "site-packages":
            (lib / entry.name).symlink_to(entry)
    (lib / "site-packages" / "picamera2" / "__init__.py").write_text("SYSTEM_STAND_IN = True\n")
    (root / "bin").mkdir()
    return root / "bin"


def _venv_on(home: Path, folder: Path, system_site_packages: bool) -> Path:
    """A venv whose base Python is the one at `home` (pyvenv.cfg's `home` is where Python looks
    for its base prefix and so for the system's site-packages)."""
    venv.EnvBuilder(system_site_packages=system_site_packages, with_pip=False, symlinks=True).create(folder)
    cfg = folder / "pyvenv.cfg"
    lines = [f"home = {home}" if line.startswith("home =") else line for line in cfg.read_text().splitlines()]
    cfg.write_text("\n".join(lines) + "\n")
    return folder / "bin" / "python"


def _find_picamera2(python: Path) -> str:
    code = ("import importlib.util; s = importlib.util.find_spec('picamera2'); "
            "print(s.origin if s else 'none')")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    return subprocess.run([str(python), "-c", code], capture_output=True, text=True, check=True, timeout=60,
                          env=env).stdout.strip()


def test_a_venv_with_system_site_packages_takes_the_systems_picamera2(tmp_path):
    home = _system_python_with_picamera2(tmp_path / "system")
    found = _find_picamera2(_venv_on(home, tmp_path / "venv", system_site_packages=True))
    assert found == str(tmp_path / "system" / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}"
                        / "site-packages" / "picamera2" / "__init__.py")
    # Without the flag the system's picamera2 stays out of sight: why ./dev and the README pass it.
    assert _find_picamera2(_venv_on(home, tmp_path / "bare", system_site_packages=False)) == "none"


def test_dev_makes_its_venv_with_system_site_packages():
    assert "-m venv --system-site-packages .venv" in (REPO / "dev").read_text()


def _check_wheels():
    spec = importlib.util.spec_from_file_location("check_wheels", REPO / "tools" / "check_wheels.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_wheel_check_asks_for_every_tag_bookworm_accepts_and_keeps_numpy_1():
    check = _check_wheels()
    tags = check.platforms()
    assert tags[0] == "manylinux_2_36_aarch64" and "manylinux_2_17_aarch64" in tags
    assert "manylinux2014_aarch64" in tags and not any("musllinux" in t for t in tags)
    assert check.dependencies()[0].startswith("numpy")
    pins = check.CONSTRAINTS.read_text()
    assert "numpy>=1.24,<2" in pins  # apt's picamera2 helpers are built against Debian's numpy 1.24
