"""The systemd unit and sysusers file: what the device depends on is there, systemd itself finds
nothing to complain about, and the sandbox stays tight (``systemd-analyze security``)."""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
UNIT = REPO / "systemd" / "edge.service"
SYSUSERS = REPO / "systemd" / "edge.sysusers.conf"
CONFIG = "/etc/edge/edge.toml"
# Measured with systemd 252: 1.7 ("OK"). A little headroom for other versions' weights; a
# protection dropped by mistake costs 0.1-0.5 and shows.
MAX_EXPOSURE = 2.5
# Keys that may (and do) repeat; any other key given twice is a mistake (the last one wins).
REPEATABLE = {"DeviceAllow", "Wants", "After", "Environment"}

ANALYZE = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(ANALYZE is None, reason="systemd-analyze is not installed")


def parse_unit(text: str) -> dict[str, list[tuple[str, str]]]:
    """Sections → (key, value) pairs in order; keys can repeat, as systemd allows."""
    sections: dict[str, list[tuple[str, str]]] = {}
    current: list[tuple[str, str]] | None = None
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], [])
            continue
        key, sep, value = line.partition("=")
        assert sep and current is not None, f"edge.service:{number}: not KEY=value in a section: {raw!r}"
        current.append((key.strip(), value.strip()))
    return sections


@pytest.fixture(scope="module")
def unit() -> dict[str, list[tuple[str, str]]]:
    return parse_unit(UNIT.read_text())


def values(unit: dict, section: str, key: str) -> list[str]:
    return [v for k, v in unit.get(section, []) if k == key]


def one(unit: dict, section: str, key: str) -> str:
    found = values(unit, section, key)
    assert len(found) == 1, f"[{section}] {key}= given {len(found)} times"
    return found[0]


def test_sections_and_no_key_set_twice_by_mistake(unit) -> None:
    assert set(unit) == {"Unit", "Service", "Install"}
    for section, pairs in unit.items():
        keys = [k for k, _ in pairs if k not in REPEATABLE]
        assert len(keys) == len(set(keys)), f"[{section}]: {sorted(k for k in keys if keys.count(k) > 1)}"
    assert one(unit, "Install", "WantedBy") == "multi-user.target"


def test_notify_watchdog_and_restart(unit) -> None:
    assert one(unit, "Service", "Type") == "notify"
    assert one(unit, "Service", "NotifyAccess") == "main"
    assert one(unit, "Service", "WatchdogSec") == "30"
    assert one(unit, "Service", "Restart") == "on-failure"
    assert one(unit, "Service", "RestartSec") == "5"
    assert one(unit, "Service", "TimeoutStopSec") == "15"
    assert "PYTHONUNBUFFERED=1" in values(unit, "Service", "Environment")


def test_it_runs_the_service_and_always_switches_the_lasers_off_after(unit) -> None:
    start = shlex.split(one(unit, "Service", "ExecStart"))
    stop_post = shlex.split(one(unit, "Service", "ExecStopPost"))
    assert start[0] == "/opt/edge/.venv/bin/edge" and start[1:] == ["run", "--config", CONFIG]
    # No "-" prefix and no condition: it runs after every kind of stop, from the same install
    # and with the same configuration (the same pins).
    assert stop_post == ["/opt/edge/.venv/bin/edge", "lasers", "off", "--config", CONFIG]


def test_user_groups_and_state(unit) -> None:
    assert one(unit, "Service", "User") == "edge"
    assert one(unit, "Service", "Group") == "edge"
    assert set(one(unit, "Service", "SupplementaryGroups").split()) == {"gpio", "dialout", "video", "audio"}
    assert one(unit, "Service", "StateDirectory") == "edge"
    # lgpio makes a FIFO in the working directory on a Pi 5: it must be the writable state folder.
    assert one(unit, "Service", "WorkingDirectory") == "/var/lib/edge"
    assert one(unit, "Service", "UMask") == "0027"


def test_devices_are_an_allow_list_not_hidden(unit) -> None:
    assert values(unit, "Service", "PrivateDevices") in ([], ["no"], ["false"])
    assert one(unit, "Service", "DevicePolicy") == "closed"
    allowed = dict(v.split() for v in values(unit, "Service", "DeviceAllow"))
    for device in ("char-gpiochip", "char-ttyUSB", "char-ttyACM", "char-ttyAMA", "char-video4linux",
                   "char-media", "char-dma_heap", "char-alsa"):
        assert allowed.get(device) == "rw", device
    assert all(re.fullmatch(r"(char-\S+|/dev/\S+)", d) for d in allowed)  # no block devices


def test_hardening(unit) -> None:
    expected = {
        "NoNewPrivileges": "yes", "ProtectSystem": "strict", "ProtectHome": "yes", "PrivateTmp": "yes",
        "ProtectKernelTunables": "yes", "ProtectKernelModules": "yes", "ProtectKernelLogs": "yes",
        "ProtectControlGroups": "yes", "ProtectClock": "yes", "ProtectHostname": "yes",
        "RestrictNamespaces": "yes", "RestrictRealtime": "yes", "RestrictSUIDSGID": "yes",
        "LockPersonality": "yes", "SystemCallArchitectures": "native",
        "SystemCallFilter": "@system-service", "CapabilityBoundingSet": "", "AmbientCapabilities": "",
    }
    for key, value in expected.items():
        assert one(unit, "Service", key) == value, key
    assert set(one(unit, "Service", "RestrictAddressFamilies").split()) == {
        "AF_UNIX", "AF_INET", "AF_INET6", "AF_NETLINK"}
    assert values(unit, "Service", "IPAddressDeny") == []  # the broker may be anywhere
    assert values(unit, "Service", "PrivateNetwork") == []
    # Off on purpose (ctypes/cffi callbacks); the unit says why.
    assert values(unit, "Service", "MemoryDenyWriteExecute") == []
    assert "MemoryDenyWriteExecute" in UNIT.read_text()


def test_sysusers_makes_the_user_and_every_group_the_unit_needs(unit) -> None:
    lines = [shlex.split(line) for line in SYSUSERS.read_text().splitlines()
             if line.strip() and not line.lstrip().startswith("#")]
    user = [fields for fields in lines if fields[0] == "u"]
    assert len(user) == 1 and user[0][1] == "edge" and user[0][-1] == "/var/lib/edge"
    members = {fields[2] for fields in lines if fields[0] == "m" and fields[1] == "edge"}
    assert set(one(unit, "Service", "SupplementaryGroups").split()) <= members


@pytest.mark.skipif(shutil.which("systemd-sysusers") is None, reason="systemd-sysusers is not installed")
def test_systemd_sysusers_accepts_the_file(tmp_path: Path) -> None:
    # --dry-run against an empty root: prints what it would create, writes nothing.
    (tmp_path / "etc").mkdir()
    run = subprocess.run(["systemd-sysusers", "--dry-run", f"--root={tmp_path}", str(SYSUSERS)],
                         capture_output=True, text=True, timeout=60)
    output = run.stdout + run.stderr
    assert run.returncode == 0, output
    assert "Creating user 'edge'" in output
    assert not re.search(r"(?i)ignoring|invalid|failed", output), output
    assert not (tmp_path / "etc" / "passwd").exists()


# --- systemd's own checks ------------------------------------------------------------------------


def runnable_copy(folder: Path, extra: str = "") -> Path:
    """The unit with its commands pointed at executables that exist here (verify checks them),
    named edge.service like the real one. User=edge stays: verify does not look users up."""
    edge = Path(sys.executable).with_name("edge")
    exe = str(edge if edge.exists() else Path(sys.executable))
    text = UNIT.read_text().replace("/opt/edge/.venv/bin/edge", exe)
    if extra:
        text = text.replace("[Service]\n", f"[Service]\n{extra}\n", 1)
    folder.mkdir(parents=True, exist_ok=True)
    copy = folder / "edge.service"
    copy.write_text(text)
    return copy


def verify_complaints(copy: Path) -> list[str]:
    """What `systemd-analyze verify` says about our unit. It exits 0 on unknown keys, so its words
    are what counts; lines about other units (this container lacks some) are not ours."""
    run = subprocess.run([ANALYZE, "verify", str(copy)], capture_output=True, text=True,
                         timeout=120, cwd=copy.parent)
    lines = (run.stdout + run.stderr).splitlines()
    ours = [line for line in lines if copy.name in line or str(copy.parent) in line]
    if run.returncode != 0:
        ours.append(f"exit status {run.returncode}: " + " | ".join(lines))
    return ours


@needs_analyze
def test_systemd_analyze_verify_has_nothing_to_say(tmp_path: Path) -> None:
    assert verify_complaints(runnable_copy(tmp_path / "good")) == []


@needs_analyze
def test_the_verify_check_does_catch_a_bad_key(tmp_path: Path) -> None:
    # Proves the test above can fail: a misspelt key is reported, naming our unit.
    complaints = verify_complaints(runnable_copy(tmp_path / "bad", extra="WatchdogSecs=30"))
    assert any("WatchdogSecs" in line for line in complaints), complaints


def _analyze_version() -> int:
    if ANALYZE is None:
        return 0
    first = subprocess.run([ANALYZE, "--version"], capture_output=True, text=True).stdout
    match = re.match(r"systemd (\d+)", first)
    return int(match.group(1)) if match else 0


@pytest.mark.skipif(_analyze_version() < 250, reason="systemd-analyze security --offline needs systemd 250+")
def test_security_exposure_stays_low(tmp_path: Path) -> None:
    copy = runnable_copy(tmp_path)
    run = subprocess.run([ANALYZE, "security", "--offline=true", "--no-pager", str(copy)],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path)
    output = run.stdout + run.stderr
    match = re.search(r"Overall exposure level for edge\.service:\s*([\d.]+)", output)
    assert match, output
    exposure = float(match.group(1))
    assert exposure < MAX_EXPOSURE, output
