"""The doctor's checks of the computer: Python, packages, the pin factory, groups and device nodes,
the state folder, the clock. Light: none of them needs numpy.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import glob
import grp
import importlib
import importlib.metadata
import os
import platform
import pwd
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from edge.doctor.checklist import Problem, Skip
from edge.doctor.settings import Settings

# Import name → distribution name, for the dependencies every rig needs.
PACKAGES = {"numpy": "numpy", "cv2": "opencv-python-headless", "serial": "pyserial", "gpiozero": "gpiozero",
            "paho.mqtt.client": "paho-mqtt"}
# Where Raspberry Pi OS's apt installs Python packages (python3-picamera2, python3-lgpio).
SYSTEM_SITE = "/usr/lib/python3/dist-packages"
FREE_MIN_BYTES = 64 << 20  # the outbox, the boot counter and calibration frames need room


def check_python() -> str:
    v = sys.version_info
    found = f"{platform.python_implementation()} {platform.python_version()} on {platform.machine()}"
    if v < (3, 11):
        raise Problem(f"{found}: edge needs Python 3.11 or newer",
                      "use Raspberry Pi OS Bookworm (Python 3.11) or newer, and make the venv with it")
    venv = sys.prefix != sys.base_prefix
    return f"{found}{', in a venv' if venv else ''} ({sys.executable})"


def _minimum(dist: str) -> tuple[int, ...] | None:
    """edge's own lower bound on `dist` (``numpy>=1.24`` → (1, 24)), from its metadata."""
    try:
        requires = importlib.metadata.requires("edge") or []
    except importlib.metadata.PackageNotFoundError:
        return None
    for req in requires:
        m = re.match(r"\s*([A-Za-z0-9_.-]+)\s*>=\s*([0-9.]+)", req)
        if m and m.group(1).lower() == dist and "extra" not in req:
            return _version_tuple(m.group(2))
    return None


def _version_tuple(text: str) -> tuple[int, ...]:
    return tuple(int(x) for x in re.findall(r"\d+", text)[:3])


def _version(module: object, dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:  # apt's packages may carry no metadata
        return str(getattr(module, "__version__", "?"))


def _where(module: object) -> str:
    return str(Path(getattr(module, "__file__", "") or "?").parent)


def import_problem(name: str) -> str | None:
    """Why `name` cannot be imported, or None. Any exception counts: a broken package may raise
    more than ImportError (a numpy built for another CPU, a missing shared library)."""
    try:
        importlib.import_module(name)
    except BaseException as exc:  # a broken package may even raise SystemExit at import
        return f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else 'cannot import'}"
    return None


def check_packages(settings: Settings) -> str:
    found, problems = [], []
    wanted = dict(PACKAGES)
    if settings.camera_backend == "picamera2":
        wanted["picamera2"] = "picamera2"
    if settings.lasers.backend == "gpio":
        wanted["lgpio"] = "lgpio"
    for name, dist in wanted.items():
        why = import_problem(name)
        if why is not None:
            problems.append((dist, why))
            continue
        module = sys.modules[name]
        version = _version(module, dist)
        low = _minimum(dist)
        if low is not None and version != "?" and _version_tuple(version) < low:
            problems.append((dist, f"{version} is older than edge needs ({'.'.join(map(str, low))})"))
            continue
        where = ""
        if dist in ("picamera2", "lgpio"):
            where = " (system)" if _where(module).startswith(SYSTEM_SITE) else f" ({_where(module)})"
        found.append(f"{dist} {version}{where}")
    numpy = sys.modules.get("numpy")
    if settings.camera_backend == "picamera2" and numpy is not None and _version_tuple(numpy.__version__) >= (2,):
        # apt's picamera2 helpers (simplejpeg, av) are built against Debian's numpy 1.24.
        problems.append(("numpy", f"{numpy.__version__} in {_where(numpy)} hides the system's numpy 1, which "
                         "apt's picamera2 helpers are built for"))
    if problems:
        dists = {dist for dist, _ in problems}
        remedy = []
        if dists & {"picamera2", "lgpio"}:
            remedy.append("sudo apt install python3-picamera2 python3-lgpio, and make the venv with "
                          "--system-site-packages (./dev does)")
        if "numpy" in dists and settings.camera_backend == "picamera2":
            remedy.append("pip install -c tools/pi-constraints.txt 'numpy<2' 'opencv-python-headless<4.12' in "
                          "edge's venv (or pip uninstall numpy there, to use the system's)")
            dists -= {"numpy"}
        if dists - {"picamera2", "lgpio"}:
            remedy.append(f"pip install --force-reinstall {' '.join(sorted(dists - {'picamera2', 'lgpio'}))} "
                          "in edge's venv (or ./dev edge doctor, which installs them)")
        raise Problem("; ".join(f"{dist}: {why}" for dist, why in problems), "; ".join(remedy))
    return ", ".join(found)


def check_pin_factory(settings: Settings) -> str:
    if settings.lasers.backend == "sim":
        return "the simulator's mock pins (lasers.backend = \"sim\")"
    from edge.errors import LaserError
    from edge.hw.lasers import default_factory

    chosen = os.environ.get("GPIOZERO_PIN_FACTORY")
    try:
        factory = default_factory()
    except LaserError as exc:
        raise Problem(str(exc).removeprefix("lasers: "),
                      "sudo apt install python3-lgpio (Raspberry Pi OS has it), the venv made with "
                      "--system-site-packages; unset GPIOZERO_PIN_FACTORY") from None
    name = type(factory).__name__
    if name == "MockFactory" or "Mock" in name:
        raise Problem(f"gpiozero picked {name}{f' (GPIOZERO_PIN_FACTORY={chosen})' if chosen else ''}: "
                      "the lasers would switch nothing", "unset GPIOZERO_PIN_FACTORY on the device")
    return f"gpiozero {name}{f' (GPIOZERO_PIN_FACTORY={chosen})' if chosen else ''}"


def _user() -> tuple[str, list[str]]:
    try:
        name = pwd.getpwuid(os.getuid()).pw_name
    except KeyError:
        name = str(os.getuid())
    groups = []
    for gid in sorted(set(os.getgroups()) | {os.getgid()}):
        try:
            groups.append(grp.getgrgid(gid).gr_name)
        except KeyError:
            groups.append(str(gid))
    return name, groups


def _group_of(path: str) -> str:
    try:
        gid = os.stat(path).st_gid
        return grp.getgrgid(gid).gr_name
    except (OSError, KeyError):
        return "?"


def device_nodes(settings: Settings) -> list[tuple[str, list[str], str]]:
    """(what, the device nodes it needs, what to do when there are none) for each real part."""
    needs = []
    if settings.lasers.backend == "gpio":
        needs.append(("lasers' GPIO", sorted(glob.glob("/dev/gpiochip*")),
                      "no /dev/gpiochip*: not a Raspberry Pi, or a sandbox hides it (the unit's DeviceAllow)"))
    if not settings.ptu.port.startswith("sim://") and "://" not in settings.ptu.port:
        needs.append(("pan-tilt unit's port", [settings.ptu.port] if os.path.exists(settings.ptu.port) else [],
                      f"no {settings.ptu.port}: plug in the USB-RS-232 adapter (ls /dev/ttyUSB* /dev/serial/by-id/) "
                      "and set ptu.port"))
    if settings.camera_backend == "picamera2":
        nodes = sorted(glob.glob("/dev/media*") + glob.glob("/dev/video*") + glob.glob("/dev/dma_heap/*"))
        needs.append(("camera", nodes, "no /dev/media* or /dev/video*: is the camera's ribbon seated and "
                      "camera_auto_detect=1 in /boot/firmware/config.txt? (rpicam-hello --list-cameras)"))
    elif settings.camera_backend == "opencv":
        device = settings.camera_device
        path = f"/dev/video{device}" if device.isdigit() else device
        needs.append(("webcam", [path] if os.path.exists(path) else [],
                      f"no {path}: plug in the webcam (v4l2-ctl --list-devices) and set camera.device"))
    if settings.audio_out.startswith(("alsa", "aplay")):
        needs.append(("sound card", sorted(glob.glob("/dev/snd/*")), "no /dev/snd/*: no sound card (aplay -l)"))
    return needs


def check_devices(settings: Settings) -> str:
    needs = device_nodes(settings)
    if not needs:
        raise Skip("simulated parts: no device nodes needed")
    user, groups = _user()
    problems, remedies, seen = [], [], []
    for what, nodes, missing in needs:
        if not nodes:
            problems.append(f"{what}: none found")
            remedies.append(missing)
            continue
        denied = [n for n in nodes if not os.access(n, os.R_OK | os.W_OK)]
        for node in denied:
            group = _group_of(node)
            problems.append(f"{what}: no read/write access to {node} (group {group})")
            remedies.append(f"sudo usermod -aG {group} {user}, then log in again (the service's user "
                            f"`edge` is in it by systemd/edge.sysusers.conf)")
        seen += [n for n in nodes if n not in denied]
    if problems:
        raise Problem("; ".join(problems), "; ".join(dict.fromkeys(remedies)))
    shown = ", ".join(seen[:6]) + (f" and {len(seen) - 6} more" if len(seen) > 6 else "")
    return f"user {user} (groups {', '.join(groups)}) may use {shown}"


def check_state_dir(settings: Settings) -> str:
    folder = settings.state_dir
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".doctor-") as probe:
            probe.write(b"edge doctor\n")
            probe.flush()
            os.fsync(probe.fileno())
    except OSError as exc:
        raise Problem(f"{folder}: cannot write: {exc.strerror or exc}",
                      "run the doctor as the service's user (sudo -u edge edge doctor), or set "
                      "service.state_dir to a folder it may write") from None
    free = shutil.disk_usage(folder).free
    if free < FREE_MIN_BYTES:
        raise Problem(f"{folder}: only {free / 2**20:.0f} MiB free (the outbox and calibration frames need "
                      f"at least {FREE_MIN_BYTES >> 20} MiB)", "free some space, or move service.state_dir")
    return f"{folder.resolve()}: writable, {free / 2**30:.1f} GiB free"


class _Timex(ctypes.Structure):
    """struct timex of <sys/timex.h> (Linux): the fields before `tai` and room for the rest."""

    _fields_ = [("modes", ctypes.c_uint), ("offset", ctypes.c_long), ("freq", ctypes.c_long),
                ("maxerror", ctypes.c_long), ("esterror", ctypes.c_long), ("status", ctypes.c_int),
                ("constant", ctypes.c_long), ("precision", ctypes.c_long), ("tolerance", ctypes.c_long),
                ("time_sec", ctypes.c_long), ("time_usec", ctypes.c_long), ("tick", ctypes.c_long),
                ("rest", ctypes.c_long * 32)]


_TIME_ERROR = 5  # adjtimex: the clock is not synchronised


def clock_synchronised() -> tuple[bool | None, str]:
    """(synchronised?, how we know): timedatectl where systemd runs, else the kernel's adjtimex;
    None when neither can tell."""
    if shutil.which("timedatectl"):
        try:
            out = subprocess.run(["timedatectl", "show", "-p", "NTPSynchronized", "--value"], capture_output=True,
                                 text=True, timeout=5)
            if out.returncode == 0 and out.stdout.strip() in ("yes", "no"):
                return out.stdout.strip() == "yes", "timedatectl"
        except (OSError, subprocess.SubprocessError):
            pass
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            timex = _Timex()
            state = libc.adjtimex(ctypes.byref(timex))
            if state >= 0:
                return state != _TIME_ERROR, f"adjtimex, estimated error {timex.esterror / 1000:.0f} ms"
        except (OSError, AttributeError):
            pass
    return None, "neither timedatectl nor adjtimex answered"


def check_clock(settings: Settings) -> str:
    synced, how = clock_synchronised()
    if synced is None:
        raise Skip(f"cannot tell whether the clock is synchronised ({how})")
    if synced:
        return f"synchronised ({how})"
    if settings.all_simulated:  # the virtual rig keeps its own time; alert times would still be off
        return (f"the simulated rig keeps simulated time; this computer's clock is not synchronised ({how}): "
                "on a device that fails")
    raise Problem(f"not synchronised ({how}): alert and sweep times would be wrong",
                  "sudo timedatectl set-ntp true and give the device a network (or an RTC); "
                  "check with timedatectl")
