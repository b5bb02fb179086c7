"""Configuration: one TOML file, validated into typed, frozen objects.

``load_config(path)`` reads the file, applies ``--set key.path=value`` overrides and returns a
:class:`Config`. Any wrong key, type or value raises :class:`~edge.errors.ConfigError` with one line
naming the file, the dotted key and what is expected. The shipped default is ``config/sim.toml``: the
simulated rig in a virtual room.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from edge.config_file import apply_overrides, default_config_path, read_table
from edge.errors import ConfigError
from edge.fsutil import output_problem
from edge.grid import GridConfig
from edge.hw.camera import CameraSettings
from edge.hw.lasers import DEFAULT_WIRING, LasersConfig, LaserWiring
from edge.hw.ptu import PtuConfig
from edge.isp import OUT as ISP_OUT
from edge.modes import Mode
from edge.modes.blindaid.logic import BlindAidConfig
from edge.modes.guard import GuardConfig
from edge.ranging import RangingConfig
from edge.rig import CAMERA_MODELS, CameraModel, Laser, Mount, Rig, default_rig, wrap_deg
from edge.schema import FieldError, build, require
from edge.sim.settings import SimConfig


@dataclass(frozen=True)
class DeviceConfig:
    id: str = ""  # empty: the host name

    def resolved_id(self) -> str:
        import socket

        return self.id or socket.gethostname()


@dataclass(frozen=True)
class CameraConfig:
    """A named camera model (``edge.rig.CAMERA_MODELS``), optionally with its numbers replaced."""

    model: str = "picam-v2"
    width: int | None = None
    height: int | None = None
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    dist: tuple[float, float, float, float, float] | None = None

    def __post_init__(self) -> None:
        require(
            self.model in CAMERA_MODELS,
            "model",
            f"unknown camera model {self.model!r} (known: {', '.join(CAMERA_MODELS)})",
        )
        self.build()  # validates the numbers

    def build(self) -> CameraModel:
        base = CAMERA_MODELS[self.model]
        changes = {
            k: getattr(self, k)
            for k in ("width", "height", "fx", "fy", "cx", "cy", "dist")
            if getattr(self, k) is not None
        }
        return replace(base, **changes)


@dataclass(frozen=True)
class LaserConfig:
    """One ``[[rig.lasers]]`` table: where the beam is (geometry, for ranging) and how it is
    switched (wiring, for the laser driver). The two go their own ways from here."""

    name: str
    origin_m: tuple[float, float, float]
    direction: tuple[float, float, float]
    pin: int | None = None  # BCM GPIO number that switches it
    active_high: bool = True
    reference: bool = False

    def __post_init__(self) -> None:
        self.geometry()  # validates the direction
        self.wiring()  # validates the pin

    def geometry(self) -> Laser:
        return Laser(self.name, self.origin_m, self.direction, self.reference)

    def wiring(self) -> LaserWiring:
        return LaserWiring(self.name, self.pin, self.active_high)


_DEFAULT_RIG = default_rig()
# geometry.md's default rig, wired as the README says.
_DEFAULT_LASERS = tuple(
    LaserConfig(laser.name, laser.origin_m, laser.direction, wire.pin, wire.active_high, laser.reference)
    for laser, wire in zip(_DEFAULT_RIG.lasers, DEFAULT_WIRING, strict=True))


@dataclass(frozen=True)
class RigConfig:
    camera: CameraConfig = field(default_factory=CameraConfig)
    lasers: tuple[LaserConfig, ...] = _DEFAULT_LASERS
    mount: Mount = field(default_factory=Mount)
    range_limits_m: tuple[float, float] = _DEFAULT_RIG.range_limits_m
    # An edge-calibration/1 file (relative to the config file) applied to the lasers and camera
    # above; empty: the service's own <state_dir>/calibration.json if there is one (edge.calibration.in_use).
    calibration: str = ""

    def __post_init__(self) -> None:
        self.build()  # Rig validates laser names, the reference flag and the limits

    def build(self) -> Rig:
        lasers = tuple(laser.geometry() for laser in self.lasers)
        return Rig(self.camera.build(), lasers, self.mount, self.range_limits_m)

    def wiring(self) -> tuple[LaserWiring, ...]:
        """How each laser is switched (its pin and polarity), for the laser driver."""
        return tuple(laser.wiring() for laser in self.lasers)


@dataclass(frozen=True)
class SweepConfig:
    """Which views a sweep takes and how many frames each."""

    zones: int = 64
    pan_start_deg: float = 0.0
    pan_step_deg: float = 360.0 / 64
    tilt_deg: float = 0.0
    # A 3D scan: the zones at each of these tilts (empty: at tilt_deg only).
    tilts_deg: tuple[float, ...] = ()
    poses_deg: tuple[tuple[float, float], ...] = ()  # explicit (pan, tilt) list; replaces the above
    pairs_per_zone: int = 2  # laser-off/laser-on frame pairs per zone
    # Between pairs the unit is nudged by this much in pan so that each pair sees different laser
    # speckle (speckle, not pixel noise, limits a pointer's precision; averaging equal speckle does
    # not help). About one position of a PTU-D46-17 (185.1428″).
    nudge_deg: float = 0.0514

    def __post_init__(self) -> None:
        require(1 <= self.zones <= 4096, "zones", f"must be 1-4096, got {self.zones}")
        for key in ("pan_start_deg", "pan_step_deg"):
            require(abs(getattr(self, key)) <= 360.0, key, "must be within ±360°")
        require(abs(self.tilt_deg) <= 90.0, "tilt_deg", "must be within ±90°")
        require(len(self.tilts_deg) <= 64, "tilts_deg", "at most 64 tilt levels")
        for i, tilt in enumerate(self.tilts_deg):
            require(abs(tilt) <= 90.0, f"tilts_deg[{i}]", f"must be within ±90°, got {tilt:g}")
            require(tilt not in self.tilts_deg[:i], f"tilts_deg[{i}]", f"tilt {tilt:g}° is listed twice")
        require(self.zones * max(1, len(self.tilts_deg)) <= 4096, "tilts_deg",
                f"zones × tilt levels must be at most 4096, got {self.zones} × {len(self.tilts_deg)}")
        require(len(self.poses_deg) <= 4096, "poses_deg", "at most 4096 poses")
        for i, (pan, tilt) in enumerate(self.poses_deg):
            require(abs(pan) <= 360.0 and abs(tilt) <= 90.0, f"poses_deg[{i}]",
                    f"pan must be within ±360° and tilt within ±90°, got [{pan:g}, {tilt:g}]")
        require(1 <= self.pairs_per_zone <= 32, "pairs_per_zone", "must be 1-32")
        require(abs(self.nudge_deg) <= 1.0, "nudge_deg", "must be within ±1°")

    def nudges_deg(self, pairs: int | None = None) -> list[float]:
        """Pan offset of each pair's view from the zone's pose: 0, +1, −1, +2, … nudges, so that
        the views stay near the zone's pose."""
        n = self.pairs_per_zone if pairs is None else pairs
        return [((k + 1) // 2) * (1 if k % 2 else -1) * self.nudge_deg if k else 0.0 for k in range(n)]

    def poses(self) -> list[tuple[float, float]]:
        """(pan, tilt) in degrees of each zone, by index: the pans of the first tilt level, then
        of the next (the sweep visits them in its own order, see edge.sweep.visiting_order)."""
        if self.poses_deg:
            return list(self.poses_deg)
        return [
            (_wrap_deg(self.pan_start_deg + i * self.pan_step_deg), tilt)
            for tilt in (self.tilts_deg or (self.tilt_deg,))
            for i in range(self.zones)
        ]


def _wrap_deg(a: float) -> float:
    return round(wrap_deg(a), 9)  # rounded: 64 steps of 5.625° must land on whole poses


@dataclass(frozen=True)
class TlsConfig:
    """TLS to the broker (``[mqtt.tls]``); off unless ``enabled``."""

    enabled: bool = False
    ca_file: str = ""  # empty: the system's trust store
    cert_file: str = ""  # client certificate (both or neither of cert_file and key_file)
    key_file: str = ""
    insecure: bool = False  # skip the host-name check (test brokers only)

    def __post_init__(self) -> None:
        require(bool(self.cert_file) == bool(self.key_file), "cert_file",
                "give both cert_file and key_file, or neither")


MAX_SESSION_EXPIRY_S = 0xFFFFFFFF


def _identifier_problem(client_id: str) -> str | None:
    """Why `client_id` cannot name us to a broker, or None (empty: the default)."""
    if len(client_id.encode()) > 65535:
        return "longer than MQTT allows (65535 bytes)"
    bad = next((c for c in client_id if c in "+#/" or not c.isprintable() or c.isspace()), None)
    if bad is not None:
        return (f"must not contain {bad!r} (Mosquitto denies every publish of a client whose id has "
                "+ or #; / and control characters break ACL patterns and logs)")
    return None


def _calibrate_problem(distances_m: tuple[float, ...]) -> str | None:
    """Why cmd/calibrate would refuse these distances, or None (checked by the command's own rules)."""
    import json

    from edge.commands import parse_command
    from edge.errors import CommandError

    try:
        parse_command("calibrate", json.dumps({"distances_m": list(distances_m)}).encode(), max_bytes=1 << 16,
                      pan_limits=(-180.0, 180.0), tilt_limits=(-90.0, 90.0))
    except CommandError as exc:
        return str(exc).removeprefix("cmd/calibrate: ").removeprefix("distances_m: ")
    return None


@dataclass(frozen=True)
class MqttConfig:
    """The broker link (``[mqtt]``), per ../spec/mqtt.md."""

    enabled: bool = True
    host: str = "localhost"
    port: int = 1883
    prefix: str = "edge"
    client_id: str = ""  # empty: "<prefix>-<device id>"
    username: str = ""
    password: str = ""
    password_file: str = ""  # read at start: keeps the secret out of the config file
    keepalive_s: int = 30
    session_expiry_s: int = 86400  # the broker keeps our session (and QoS 1 messages) this long
    reconnect_min_s: float = 1.0
    reconnect_max_s: float = 60.0
    max_payload_bytes: int = 65536  # commands larger than this are refused before parsing
    discovery: bool = True  # Home Assistant MQTT discovery
    discovery_prefix: str = "homeassistant"
    # What Home Assistant's Calibrate button sends: cmd/calibrate's distances, in the order taken.
    calibrate_distances_m: tuple[float, ...] = (2.0, 1.3, 0.8, 0.5)
    tls: TlsConfig = field(default_factory=TlsConfig)

    def __post_init__(self) -> None:
        require(1 <= self.port <= 65535, "port", f"must be 1-65535, got {self.port}")
        for key in ("prefix", "discovery_prefix"):
            value = getattr(self, key)
            require(bool(value) and not any(c in value for c in "#+\0") and not value.startswith("/")
                    and not value.endswith("/"), key, f"not a usable topic prefix: {value!r}")
        require(not (self.password and self.password_file), "password", "give password or password_file, not both")
        require(self.host.isprintable() and 0 < len(self.host) <= 253 and not self.host.isspace(),
                "host", "must be a host name or address")
        # What the broker would refuse or deny (every publish, for a client id with + or #): say so
        # now, not after a start that seems fine. MQTT strings are at most 65535 bytes.
        problem = _identifier_problem(self.client_id)
        require(problem is None, "client_id", f"{problem}")
        require(len(self.username.encode()) <= 65535, "username", "longer than MQTT allows (65535 bytes)")
        require(5 <= self.keepalive_s <= 3600, "keepalive_s", "must be 5-3600 s")
        problem = _calibrate_problem(self.calibrate_distances_m)
        require(problem is None, "calibrate_distances_m", f"{problem}")
        # A four-byte integer in MQTT 5: paho refuses anything larger, killing the link's thread.
        require(0 <= self.session_expiry_s <= MAX_SESSION_EXPIRY_S, "session_expiry_s",
                f"must be 0-{MAX_SESSION_EXPIRY_S} s (MQTT's limit; {MAX_SESSION_EXPIRY_S} never expires)")
        require(0 < self.reconnect_min_s <= self.reconnect_max_s, "reconnect_min_s",
                "must be positive and at most reconnect_max_s")
        require(self.reconnect_min_s >= 0.01, "reconnect_min_s", "must be at least 0.01 s")
        require(self.reconnect_max_s <= 3600, "reconnect_max_s", "must be at most 3600 s")
        require(256 <= self.max_payload_bytes <= 1 << 20, "max_payload_bytes", "must be 256 B - 1 MiB")


@dataclass(frozen=True)
class RangefinderConfig:
    """The range-finder mode (``[rangefinder]``): where it points until ``cmd/point`` says otherwise."""

    pan_deg: float = 0.0
    tilt_deg: float = 0.0

    def __post_init__(self) -> None:
        require(-180.0 <= self.pan_deg <= 180.0, "pan_deg", "must be -180..180")
        require(-90.0 <= self.tilt_deg <= 90.0, "tilt_deg", "must be -90..90")


@dataclass(frozen=True)
class AudioConfig:
    """Where the blind aid's sound goes (``[audio]``)."""

    # "": nowhere (cues still go out on MQTT); "alsa" or "alsa:DEVICE": the sound card through
    # aplay; anything else: a WAV file written as the run goes (for tests and listening).
    out: str = ""
    chunk_ms: float = 20.0  # sound is written in chunks this long: at most this much added latency
    lead_ms: float = 20.0  # a live sink is fed this far ahead of the clock, so it never runs dry

    def __post_init__(self) -> None:
        require(5.0 <= self.chunk_ms <= 100.0, "chunk_ms", "must be 5-100 ms")
        require(0.0 <= self.lead_ms <= 500.0, "lead_ms", "must be 0-500 ms")
        if self.out and self.out not in ("alsa", "aplay", "null") and not self.out.startswith("alsa:"):
            problem = output_problem(self.out)  # a WAV file is renamed over what is there
            require(problem is None, "out", f"{problem}; give a WAV file's path, or alsa")


@dataclass(frozen=True)
class ServiceConfig:
    """The headless loop (``[service]``)."""

    state_dir: str = ""  # empty: $STATE_DIRECTORY (systemd), else ./state
    # Range-finder mode: a map sweep this often, interrupting the ranging (0: on cmd/sweep only).
    # The guard sweeps back to back and the blind aid scans its fan; neither uses this.
    sweep_interval_s: float = 300.0
    outbox_max_messages: int = 100000  # on-disk queue bound: beyond it the oldest sweeps go first, never alerts
    watchdog: bool = True  # feed systemd's watchdog while the loop progresses
    # The guard sweeps back to back with this many laser-off/on pairs a zone: it compares ranges
    # with a learnt background and its noise, so one pair (no speckle nudge) is enough and faster.
    guard_pairs_per_zone: int = 1
    # cmd/calibrate: the whole session (someone carrying a target to each distance) ends after this.
    calibrate_timeout_s: float = 600.0

    def __post_init__(self) -> None:
        require(0 <= self.sweep_interval_s <= 86400 * 365, "sweep_interval_s", "must be 0 s to a year")
        if self.state_dir:
            problem = output_problem(self.state_dir, folder=True)
            require(problem is None, "state_dir", f"{problem}")
        require(10 <= self.calibrate_timeout_s <= 86400, "calibrate_timeout_s", "must be 10-86400 s")
        require(100 <= self.outbox_max_messages <= 10**9, "outbox_max_messages", "must be 100-1000000000")
        require(1 <= self.guard_pairs_per_zone <= 8, "guard_pairs_per_zone", "must be 1-8")

    def resolved_state_dir(self) -> Path:
        return Path(self.state_dir or os.environ.get("STATE_DIRECTORY", "").split(":")[0] or "state")


@dataclass(frozen=True)
class Config:
    source: str = "<defaults>"  # the file it came from, for messages
    device: DeviceConfig = field(default_factory=DeviceConfig)
    rig: RigConfig = field(default_factory=RigConfig)
    sweep: SweepConfig = field(default_factory=SweepConfig)
    map: GridConfig = field(default_factory=GridConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    ranging: RangingConfig = field(default_factory=RangingConfig)
    camera: CameraSettings = field(default_factory=CameraSettings)
    lasers: LasersConfig = field(default_factory=LasersConfig)
    ptu: PtuConfig = field(default_factory=PtuConfig)
    mqtt: MqttConfig = field(default_factory=MqttConfig)
    service: ServiceConfig = field(default_factory=ServiceConfig)
    rangefinder: RangefinderConfig = field(default_factory=RangefinderConfig)
    guard: GuardConfig = field(default_factory=GuardConfig)
    blindaid: BlindAidConfig = field(default_factory=BlindAidConfig)
    audio: AudioConfig = field(default_factory=AudioConfig)
    mode: Mode = "rangefinder"
    log_level: Literal["debug", "info", "warning", "error"] = "info"

    @property
    def frames_gamma(self) -> float:
        """The tone curve this configuration's camera delivers frames through: the simulated
        sensor's, or, for a real camera, the one ranging is told (camera.gamma for the Pi camera)."""
        return self.sim.sensor.gamma if self.camera.backend == "sim" else self.ranging.frame_gamma

    def __post_init__(self) -> None:
        # The Pi camera's frames come through camera.gamma's curve (the ISP is set to it): ranging
        # must undo that one, or a spot's light no longer adds to the room's in its values.
        require(self.camera.backend != "picamera2" or self.ranging.frame_gamma == self.camera.gamma,
                "ranging.frame_gamma",
                f"must be camera.gamma ({self.camera.gamma:g}) with the Pi camera, whose frames come through that "
                f"curve; got {self.ranging.frame_gamma:g}")
        if self.sim.sensor.isp:
            cam = self.rig.camera.build()
            require((cam.width, cam.height) == (ISP_OUT.width, ISP_OUT.height), "sim.sensor.isp",
                    f"the Pi camera's ISP hands over {ISP_OUT.width}x{ISP_OUT.height} frames (picam-v2); "
                    f"rig.camera is {cam.width}x{cam.height}")


def load_config(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()) -> Config:
    """Read and validate a configuration file (default: ``config/sim.toml``)."""
    file = Path(path) if path is not None else default_config_path()
    return config_from_mapping(read_table(file), str(file), overrides)


def config_from_mapping(
    data: dict[str, Any], source: str, overrides: list[str] | tuple[str, ...] = ()
) -> Config:
    apply_overrides(data, overrides)
    if "source" in data:
        raise ConfigError(f"{source}: source: unknown key")
    data = {**data, "source": source}
    try:
        return build(Config, data, source)
    except FieldError as exc:  # raised outside a table walk: still name the file
        raise ConfigError(f"{source}: {exc}") from None


def resolve_path(config: Config, name: str) -> Path:
    """A path written in a config file, relative to that file's folder."""
    p = Path(name).expanduser()
    if p.is_absolute() or config.source.startswith("<"):
        return p
    return Path(config.source).resolve().parent / p
