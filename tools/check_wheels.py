#!/usr/bin/env python3
"""Check, without a Raspberry Pi, that edge installs on one: every dependency has a wheel for a
64-bit Raspberry Pi OS (Bookworm: Debian 12, aarch64, glibc 2.36, CPython 3.11), or comes from
the system.

    python3 tools/check_wheels.py            # exit 0 when every dependency has such a wheel

How: pip itself resolves edge's dependencies (pyproject.toml's [project] dependencies, their own
dependencies, and tools/pi-constraints.txt) for that platform, wheels only (``--only-binary
:all:``: nothing may need compiling on the Pi), without downloading the wheels (``--dry-run
--report``). The platform is every manylinux tag a glibc 2.36 aarch64 system accepts (pip on the
Pi accepts the same; musllinux wheels are for Alpine's musl and do not count). pip evaluates
environment markers for the machine it runs on, not for the target: edge's own dependencies carry
none that matter.

What does not come from wheels, by design:

- picamera2 (and libcamera's Python binding under it): Raspberry Pi OS's apt package
  python3-picamera2; the venv is made with --system-site-packages to see it (./dev does; so does
  systemd/README.md). Not on PyPI as a wheel with libcamera.
- lgpio (gpiozero's pin factory on Bookworm, Pi 5 included): apt's python3-lgpio, the same way.
- numpy stays below 2 on the Pi (tools/pi-constraints.txt): apt's python3-picamera2 pulls in
  compiled helpers (python3-simplejpeg, python3-av) built against Debian's numpy 1.24, which a
  numpy 2 in the venv would break at import. The constraint makes pip keep the system's numpy and
  pick an OpenCV built for numpy 1 (opencv-python-headless 4.11: the last such release).
- 32-bit Raspberry Pi OS (armv7l): PyPI has no armv7l wheels of numpy or OpenCV; Raspberry Pi OS
  points pip at piwheels, which builds them for armv7l. Not reachable from here: not checked.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CONSTRAINTS = REPO / "tools" / "pi-constraints.txt"
GLIBC_MINOR = 36  # Debian 12 (Bookworm)
SYSTEM = {
    "picamera2": "apt install python3-picamera2 (Raspberry Pi OS), seen through --system-site-packages",
    "lgpio": "apt install python3-lgpio (Raspberry Pi OS), seen through --system-site-packages",
}


def platforms(glibc_minor: int = GLIBC_MINOR, arch: str = "aarch64") -> list[str]:
    """Every manylinux tag a glibc 2.<glibc_minor> system on `arch` accepts (pip 23 does not widen
    a given --platform to the older tags by itself)."""
    tags = [f"manylinux_2_{minor}_{arch}" for minor in range(glibc_minor, 16, -1)]
    return [*tags, f"manylinux2014_{arch}"]


def dependencies() -> list[str]:
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    return list(project["dependencies"])


def resolve(requirements: list[str], python: str, arch: str) -> dict:
    """pip's installation report for `requirements` on the target, wheels only; raises
    CalledProcessError (with pip's words) when some requirement has no wheel there."""
    with tempfile.TemporaryDirectory(prefix="edge-wheels-") as tmp:
        report = Path(tmp) / "report.json"
        command = [sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed", "--quiet",
                   "--disable-pip-version-check", "--only-binary", ":all:", "--python-version", python,
                   "--implementation", "cp", "--target", str(Path(tmp) / "target"), "--report", str(report),
                   "-c", str(CONSTRAINTS)]
        for tag in platforms(arch=arch):
            command += ["--platform", tag]
        subprocess.run([*command, *requirements], check=True, capture_output=True, text=True)
        return json.loads(report.read_text())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument("--python", default="3.11", help="the target's Python (Bookworm: 3.11)")
    parser.add_argument("--arch", default="aarch64", help="the target's machine (64-bit Raspberry Pi OS: aarch64)")
    args = parser.parse_args(argv)
    wanted = dependencies()
    print(f"edge's dependencies on CPython {args.python}, {args.arch}, glibc 2.{GLIBC_MINOR} "
          f"(Raspberry Pi OS Bookworm), wheels only, with {CONSTRAINTS.relative_to(REPO)}:")
    try:
        report = resolve(wanted, args.python, args.arch)
    except subprocess.CalledProcessError as exc:
        problem = [line for line in exc.stderr.splitlines() if line.startswith("ERROR")] or exc.stderr.splitlines()[-3:]
        print("FAIL: pip found no wheel for every dependency:\n  " + "\n  ".join(problem))
        return 1
    for item in report["install"]:
        meta = item["metadata"]
        wheel = item["download_info"]["url"].rsplit("/", 1)[-1]
        why = "" if item.get("requested") else " (needed by another)"
        print(f"  ok  {meta['name']} {meta['version']}: {wheel}{why}")
    for name, where in SYSTEM.items():
        print(f"  sys {name}: {where}")
    print("  (32-bit armv7l: numpy and OpenCV come from piwheels, Raspberry Pi OS's extra index: not checked here)")
    print("all dependencies have aarch64 wheels for CPython " + args.python)
    return 0


if __name__ == "__main__":
    sys.exit(main())
