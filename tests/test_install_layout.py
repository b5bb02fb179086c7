"""edge installed as the README's bare-Pi steps install it: a plain (not editable) `pip install` of
/opt/edge into /opt/edge/.venv, so the package sits in site-packages with no config/ beside it.
The commands that default to the shipped sim.toml and scenes must find them beside the venv.
Found by installing on an emulated aarch64 Debian 12: `edge bench ranging` looked for
site-packages/config/sim.toml."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def installed(tmp_path: Path) -> tuple[Path, Path, dict[str, str]]:
    """/opt/edge (its config/) with a venv whose site-packages holds a copy of the package."""
    opt = tmp_path / "opt" / "edge"
    shutil.copytree(REPO / "config", opt / "config")
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(opt / ".venv")], check=True)
    site = opt / "site"
    shutil.copytree(REPO / "edge", site / "edge", ignore=shutil.ignore_patterns("__pycache__"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_")}
    # The copy first; numpy and the rest from the test's own environment.
    # (PYTHONPATH's folders are not searched for .pth files: the checkout's editable hook stays out.)
    env["PYTHONPATH"] = os.pathsep.join([str(site), *(p for p in sys.path if p.endswith("site-packages"))])
    return opt, opt / ".venv" / "bin" / "python", env


def edge(python: Path, env: dict[str, str], cwd: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(python), "-m", "edge", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=120)


def test_the_installed_package_is_the_copy_not_the_checkout(installed, tmp_path):
    opt, python, env = installed
    out = subprocess.run([str(python), "-c", "import edge, sys; print(edge.__file__); print(sys.prefix)"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, check=True).stdout.split()
    assert out == [str(opt / "site" / "edge" / "__init__.py"), str(opt / ".venv")]


def test_the_default_configuration_and_scenes_are_found_beside_the_venv(installed, tmp_path):
    opt, python, env = installed
    done = edge(python, env, tmp_path, "config")
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[0] == f"{opt / 'config' / 'sim.toml'}: ok"
    recorded = edge(python, env, tmp_path, "sim", "record", "--scene", "kitchen", "--zones", "1", "--frames", "2",
                    "--out", str(tmp_path / "kitchen"))
    assert recorded.returncode == 0, recorded.stderr
    assert (tmp_path / "kitchen" / "sweep.json").is_file()


def test_without_a_shipped_configuration_one_line_says_where_it_looked_and_what_to_do(installed, tmp_path):
    opt, python, env = installed
    shutil.rmtree(opt / "config")
    done = edge(python, env, tmp_path, "config")
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1, done.stderr
    assert str(opt / "config") in done.stderr and "EDGE_CONFIG_DIR" in done.stderr and "--config" in done.stderr
    # A configuration of one's own needs nothing shipped: the device's file is enough.
    own = tmp_path / "device.toml"
    shutil.copy(REPO / "config" / "device.toml", own)
    done = edge(python, env, tmp_path, "config", "--config", str(own))
    assert done.returncode == 0, done.stderr
