"""Configuration: one TOML file, validated into typed, frozen objects.

``load_config(path)`` reads the file, applies ``--set key.path=value`` overrides and returns a
:class:`Config`. Any wrong key, type or value raises :class:`~edge.errors.ConfigError` with one line
naming the file, the dotted key and what is expected. The shipped default is ``config/sim.toml``: the
simulated rig in a virtual room.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from edge.errors import ConfigError
from edge.modes import Mode
from edge.modes.blindaid.logic import BlindAidConfig
from edge.modes.guard import GuardConfig
from edge.ranging import RangingConfig
from edge.rig import CAMERA_MODELS, CameraModel, Laser, Mount, Rig, default_rig, wrap_deg
from edge.schema import FieldError, build, require, show

REPO_ROOT = Path(__file__).resolve().parents[1]


def config_dir() -> Path:
    """Where the shipped configuration lives: ``$EDGE_CONFIG_DIR``, else ``<repo>/config``."""
    return Path(os.environ.get("EDGE_CONFIG_DIR") or REPO_ROOT / "config")


def default_config_path() -> Path:
    return config_dir() / "sim.toml"


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


_DEFAULT_RIG = default_rig()


@dataclass(frozen=True)
class RigConfig:
    camera: CameraConfig = field(default_factory=CameraConfig)
    lasers: tuple[Laser, ...] = _DEFAULT_RIG.lasers
    mount: Mount = field(default_factory=Mount)
    range_limits_m: tuple[float, float] = _DEFAULT_RIG.range_limits_m
    # An edge-calibration/1 file (relative to the config file) applied to the lasers and camera
    # above; empty: the service's own <state_dir>/calibration.json if there is one (edge.calibration.in_use).
    calibration: str = ""

    def __post_init__(self) -> None:
        self.build()  # Rig validates laser names, the reference flag and the limits

    def build(self) -> Rig:
        return Rig(self.camera.build(), self.lasers, self.mount, self.range_limits_m)


@dataclass(frozen=True)
class SweepConfig:
    """Which views a sweep takes and how many frames each."""

    zones: int = 64
    pan_start_deg: float = 0.0
    pan_step_deg: float = 360.0 / 64
    tilt_deg: float = 0.0
    poses_deg: tuple[tuple[float, float], ...] = ()  # explicit (pan, tilt) list; replaces the above
    pairs_per_zone: int = 2  # laser-off/laser-on frame pairs per zone
    # Between pairs the unit is nudged by this much in pan so that each pair sees different laser
    # speckle (speckle, not pixel noise, limits a pointer's precision; averaging equal speckle does
    # not help). About one position of a PTU-D46-17 (185.1428″).
    nudge_deg: float = 0.0514

    def __post_init__(self) -> None:
        require(1 <= self.zones <= 4096, "zones", f"must be 1-4096, got {self.zones}")
        require(1 <= self.pairs_per_zone <= 32, "pairs_per_zone", "must be 1-32")
        require(abs(self.nudge_deg) <= 1.0, "nudge_deg", "must be within ±1°")

    def nudges_deg(self, pairs: int | None = None) -> list[float]:
        """Pan offset of each pair's view from the zone's pose: 0, +1, −1, +2, … nudges, so that
        the views stay near the zone's pose."""
        n = self.pairs_per_zone if pairs is None else pairs
        return [((k + 1) // 2) * (1 if k % 2 else -1) * self.nudge_deg if k else 0.0 for k in range(n)]

    def poses(self) -> list[tuple[float, float]]:
        """(pan, tilt) in degrees of each zone, in sweep order."""
        if self.poses_deg:
            return list(self.poses_deg)
        return [
            (_wrap_deg(self.pan_start_deg + i * self.pan_step_deg), self.tilt_deg)
            for i in range(self.zones)
        ]


def _wrap_deg(a: float) -> float:
    return round(wrap_deg(a), 9)  # rounded: 64 steps of 5.625° must land on whole poses


@dataclass(frozen=True)
class CameraSettings:
    """How the camera is driven (``[camera]``): the same for the real camera and the simulated one.

    A zone's laser-on and laser-off frames must be taken with the same fixed exposure and gain, so
    that their difference shows the lasers and nothing else.
    """

    backend: Literal["sim", "picamera2", "opencv"] = "sim"
    device: str = "0"  # opencv: a device index or path (/dev/video0)
    exposure_us: float = 10000.0
    analogue_gain: float = 1.0
    frame_rate_hz: float = 30.0
    # Webcams give no exposure timestamps: the time from the end of a frame's exposure to its
    # delivery, measured once, stands in for them (t_start = delivery − latency − exposure).
    latency_ms: float = 0.0
    timeout_s: float = 1.0  # no frame for this long is a camera fault

    def __post_init__(self) -> None:
        require(self.analogue_gain >= 1.0, "analogue_gain", "must be >= 1")
        require(self.exposure_us > 0, "exposure_us", "must be positive")
        require(0.1 <= self.frame_rate_hz <= 1000.0, "frame_rate_hz", f"must be 0.1-1000 frames a second, got {self.frame_rate_hz:g}")
        require(
            self.exposure_us <= 1e6 / self.frame_rate_hz,
            "exposure_us",
            f"must fit in one frame time ({1e6 / self.frame_rate_hz:.0f} µs)",
        )
        require(self.latency_ms >= 0, "latency_ms", "must be >= 0")
        require(self.timeout_s > 0, "timeout_s", "must be positive")

    @property
    def frame_ns(self) -> int:
        return int(round(1e9 / self.frame_rate_hz))


@dataclass(frozen=True)
class LasersConfig:
    """How the lasers are switched (``[lasers]``); pins and polarity are in ``[[rig.lasers]]``."""

    backend: Literal["sim", "gpio"] = "sim"  # gpio: gpiozero's default pin factory (lgpio on a Pi)
    max_on_s: float = 2.0  # eye safety: a laser on longer than this is switched off
    settle_ms: float = 1.0  # from the GPIO edge to full (or no) light: driver and diode
    # sim backend only: a file that keeps the simulated pins' levels after the process ends, as
    # real wires do (for testing `edge lasers off` after a kill); empty: the pins die with the process.
    sim_wires: str = ""

    def __post_init__(self) -> None:
        require(0 < self.max_on_s <= 60, "max_on_s", "must be 0-60 s")
        require(0 <= self.settle_ms <= 100, "settle_ms", "must be 0-100 ms")


@dataclass(frozen=True)
class PtuConfig:
    """The pan-tilt unit (``[ptu]``): a PTU-D46 on a serial port, or ``sim://`` for the emulator."""

    port: str = "sim://"
    baudrate: int = 9600
    timeout_s: float = 0.5  # for one reply; moves wait as long as their distance needs
    speed_deg_s: float = 60.0
    accel_deg_s2: float = 240.0
    settle_ms: float = 30.0  # let the head stop ringing before a frame is taken

    def __post_init__(self) -> None:
        require(self.baudrate in (600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200),
                "baudrate", f"not a PTU-D46 baud rate: {self.baudrate}")
        require(self.timeout_s > 0, "timeout_s", "must be positive")
        require(self.speed_deg_s > 0, "speed_deg_s", "must be positive")
        require(self.accel_deg_s2 > 0, "accel_deg_s2", "must be positive")
        require(self.settle_ms >= 0, "settle_ms", "must be >= 0")


@dataclass(frozen=True)
class TlsConfig:
    """TLS to the broker (``[mqtt.tls]``); off unless ``enabled``."""

    enabled: bool = False
    ca_file: str = ""  # empty: the system's trust store
    cert_file: str = ""  # client certificate (both or neither of cert_file and key_file)
    key_file: str = ""
    insecure: bool = False  # skip the host-name check (test brokers only)

    def __post_init__(self) -> None:
        require(bool(self.cert_file) == bool(self.key_file), "cert_file", "give both cert_file and key_file, or neither")


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
    tls: TlsConfig = field(default_factory=TlsConfig)

    def __post_init__(self) -> None:
        require(1 <= self.port <= 65535, "port", f"must be 1-65535, got {self.port}")
        for key in ("prefix", "discovery_prefix"):
            value = getattr(self, key)
            require(bool(value) and not any(c in value for c in "#+\0") and not value.startswith("/")
                    and not value.endswith("/"), key, f"not a usable topic prefix: {value!r}")
        require(not (self.password and self.password_file), "password", "give password or password_file, not both")
        require(5 <= self.keepalive_s <= 3600, "keepalive_s", "must be 5-3600 s")
        require(self.session_expiry_s >= 0, "session_expiry_s", "must be >= 0")
        require(0 < self.reconnect_min_s <= self.reconnect_max_s, "reconnect_min_s",
                "must be positive and at most reconnect_max_s")
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
        require(self.sweep_interval_s >= 0, "sweep_interval_s", "must be >= 0")
        require(10 <= self.calibrate_timeout_s <= 86400, "calibrate_timeout_s", "must be 10-86400 s")
        require(self.outbox_max_messages >= 100, "outbox_max_messages", "must be >= 100")
        require(1 <= self.guard_pairs_per_zone <= 8, "guard_pairs_per_zone", "must be 1-8")

    def resolved_state_dir(self) -> Path:
        return Path(self.state_dir or os.environ.get("STATE_DIRECTORY", "").split(":")[0] or "state")


@dataclass(frozen=True)
class SensorConfig:
    """The simulated sensor: photo-electrons to digital numbers."""

    full_well_e: float = 10000.0
    read_noise_e: float = 3.0
    adc_bits: int = 10
    output_bits: Literal[8, 16] = 8
    colour: bool = True
    jpeg_quality: int = 0  # 0: lossless PNG; 1-100: what a webcam's JPEG stream does to frames
    # Rolling shutter: row 0's exposure start to the last row's. The IMX219's 640×480 mode runs at
    # up to 206 fps, so it reads out in under 5 ms; a webcam takes most of its frame period.
    readout_ms: float = 5.0

    def __post_init__(self) -> None:
        require(self.full_well_e > 0, "full_well_e", "must be positive")
        require(self.read_noise_e >= 0, "read_noise_e", "must be >= 0")
        require(8 <= self.adc_bits <= 16, "adc_bits", f"must be 8-16, got {self.adc_bits}")
        require(0 <= self.jpeg_quality <= 100, "jpeg_quality", "must be 0-100")
        require(self.readout_ms >= 0, "readout_ms", "must be >= 0")
        require(
            not (self.jpeg_quality and self.output_bits == 16),
            "jpeg_quality",
            "JPEG frames are 8-bit; set output_bits = 8",
        )


@dataclass(frozen=True)
class OpticsConfig:
    focal_length_mm: float = 3.04  # Pi Camera v2
    f_number: float = 2.0
    focus_m: float = 1.2  # fixed-focus distance
    psf_sigma_px: float = 0.5  # lens + pixel blur of a point in focus
    vignetting: bool = True

    def __post_init__(self) -> None:
        require(self.focal_length_mm > 0, "focal_length_mm", "must be positive")
        require(self.f_number > 0, "f_number", "must be positive")
        require(self.focus_m > 0, "focus_m", "must be positive")
        require(self.psf_sigma_px >= 0.2, "psf_sigma_px", "must be >= 0.2")


@dataclass(frozen=True)
class BeamConfig:
    """The laser pointers as the simulator sees them."""

    # Photo-electrons per ms of exposure that a spot on a white (albedo 1) matte wall squarely at 1 m
    # sends to the sensor, all pixels together, before vignetting.
    e_per_ms_at_1m: float = 20000.0
    waist_m: float = 0.0012  # 1/e² beam radius at the aperture
    divergence_mrad: float = 0.6  # half-angle
    # Relative response of the B, G, R pixels to 650 nm light (Bayer filters leak a little).
    response_bgr: tuple[float, float, float] = (0.03, 0.10, 1.0)
    speckle: float = 1.0  # 0: no speckle; 1: the modelled speckle of a pointer at f/2
    speckle_cell_m: float = 0.0002  # how far the spot must move on the surface for new speckle

    def __post_init__(self) -> None:
        require(self.e_per_ms_at_1m >= 0, "e_per_ms_at_1m", "must be >= 0")
        require(self.waist_m > 0, "waist_m", "must be positive")
        require(self.divergence_mrad >= 0, "divergence_mrad", "must be >= 0")
        require(self.speckle >= 0, "speckle", "must be >= 0")
        require(self.speckle_cell_m > 0, "speckle_cell_m", "must be positive")


@dataclass(frozen=True)
class AmbientConfig:
    # Photo-electrons per ms that a white (albedo 1) wall sends to one pixel under room light.
    white_e_per_ms: float = 600.0
    # Relative amplitude of the light level's change from frame to frame (mains or LED-driver flicker
    # beating with the frame rate): each frame's ambient level is uniform in 1 ± flicker.
    flicker: float = 0.03

    def __post_init__(self) -> None:
        require(self.white_e_per_ms >= 0, "white_e_per_ms", "must be >= 0")
        require(0 <= self.flicker < 1, "flicker", "must be in [0, 1)")


@dataclass(frozen=True)
class RigErrorConfig:
    """How the simulated rig differs from the nominal one (seeded): real rigs are never exact."""

    laser_angle_deg: float = 0.0  # 1-σ tilt of each laser's direction
    laser_offset_m: float = 0.0  # 1-σ offset of each laser's origin, per axis
    focal_scale: float = 0.0  # 1-σ relative error of the focal length
    seed: int = 0

    def __post_init__(self) -> None:
        for key in ("laser_angle_deg", "laser_offset_m", "focal_scale"):
            require(getattr(self, key) >= 0, key, "must be >= 0")


@dataclass(frozen=True)
class CameraFault:
    """A fault the simulated camera plays at a time after it starts (``[[sim.camera_faults]]``):
    ``stall`` delivers no frames for `seconds`; ``corrupt`` delivers `count` frames of the wrong
    size; ``hang`` blocks the caller for `seconds` (a driver stuck without a timeout)."""

    kind: Literal["stall", "corrupt", "hang"] = "stall"
    at_s: float = 0.0
    seconds: float = 3.0
    count: int = 2

    def __post_init__(self) -> None:
        require(self.at_s >= 0, "at_s", "must be >= 0")
        require(self.seconds > 0, "seconds", "must be positive")
        require(self.count >= 1, "count", "must be >= 1")


@dataclass(frozen=True)
class LaserFault:
    """A broken simulated laser (``[[sim.laser_faults]]``): ``dead`` never lights, ``stuck``
    never goes off (a shorted driver)."""

    laser: str = ""
    kind: Literal["dead", "stuck"] = "dead"


@dataclass(frozen=True)
class SimConfig:
    scene: str = "office"
    seed: int = 1
    sensor: SensorConfig = field(default_factory=SensorConfig)
    optics: OpticsConfig = field(default_factory=OpticsConfig)
    beam: BeamConfig = field(default_factory=BeamConfig)
    ambient: AmbientConfig = field(default_factory=AmbientConfig)
    rig_error: RigErrorConfig = field(default_factory=RigErrorConfig)
    camera_faults: tuple[CameraFault, ...] = ()  # for trying the service's fault handling
    laser_faults: tuple[LaserFault, ...] = ()  # broken lasers, for trying fault reporting


@dataclass(frozen=True)
class Config:
    source: str = "<defaults>"  # the file it came from, for messages
    device: DeviceConfig = field(default_factory=DeviceConfig)
    rig: RigConfig = field(default_factory=RigConfig)
    sweep: SweepConfig = field(default_factory=SweepConfig)
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


def parse_override(text: str) -> tuple[str, Any]:
    """``key.path=value`` → (key path, value); the value is read as TOML, else as a string."""
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ConfigError(f"--set {show(text)}: expected KEY=VALUE, e.g. --set sim.scene=kitchen")
    if "\n" in text or "\r" in text:
        raise ConfigError(f"--set {show(text)}: a line break in it; give one KEY=VALUE per --set")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except (tomllib.TOMLDecodeError, ValueError, RecursionError):
        value = raw.strip()
    return key, value


def _apply_override(data: dict[str, Any], key: str, value: Any) -> None:
    node = data
    parts = key.split(".")
    for part in parts[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ConfigError(f"--set {show(key)}: {show(part)} is not a table")
        node = child
    node[parts[-1]] = value


def load_config(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()) -> Config:
    """Read and validate a configuration file (default: ``config/sim.toml``)."""
    file = Path(path) if path is not None else default_config_path()
    name = show(str(file))
    try:
        with open(file, "rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{name}: no such configuration file") from None
    except OSError as exc:
        raise ConfigError(f"{name}: cannot read: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{name}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{name}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{name}: not usable TOML: nested too deeply") from None
    except ValueError as exc:  # e.g. a whole number of more digits than Python converts
        raise ConfigError(f"{name}: not usable TOML: {str(exc).splitlines()[0]}") from None
    return config_from_mapping(data, str(file), overrides)


def config_from_mapping(
    data: dict[str, Any], source: str, overrides: list[str] | tuple[str, ...] = ()
) -> Config:
    for text in overrides:
        key, value = parse_override(text)
        _apply_override(data, key, value)
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
