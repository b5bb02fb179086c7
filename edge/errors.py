"""One exception hierarchy for the whole project.

Every error a user can cause or meet carries a message that says what is wrong, where (file, key,
zone, topic) and, where it helps, what to do. The CLI prints it as one line; nothing else should.
"""


class EdgeError(Exception):
    """Root of every error this project raises on purpose."""

    exit_code = 1


class ConfigError(EdgeError):
    """A configuration file, key or value is wrong (exit status 2)."""

    exit_code = 2


class UsageError(EdgeError):
    """The command line is wrong (exit status 2)."""

    exit_code = 2


class RecordingError(EdgeError):
    """A sweep recording cannot be read or written as `edge-sweep/1` says (exit status 2: the
    recording given is bad input, as a configuration is)."""

    exit_code = 2


class SceneError(EdgeError):
    """A simulated scene file is wrong."""

    exit_code = 2


class HardwareError(EdgeError):
    """A part of the rig (camera, lasers, pan-tilt unit) did not deliver.

    ``part`` names the part to blame ("camera", "lasers", "ptu", "audio": the subclasses' own), or
    None when no single part is: the service routes health and recovery by it, never by the words
    of the message, which are for people. Drivers raise the subclass of their part.
    """

    exit_code = 1
    part: str | None = None

    def __init__(self, message: str = "", *, part: str | None = None) -> None:
        super().__init__(message)
        if part is not None:
            self.part = part


class CameraError(HardwareError):
    """The camera: no frame in time, a torn or corrupt frame, it would not open or restart."""

    part = "camera"


class LaserError(HardwareError):
    """The lasers: GPIO not available, a pin that cannot be driven, switching that never settles."""

    part = "lasers"


class PtuError(HardwareError):
    """The pan-tilt unit: no or garbled replies, a refused setting, a move out of its limits."""

    part = "ptu"


class AudioError(HardwareError):
    """The blind aid's sound output (a sound card or a WAV file)."""

    part = "audio"



class CalibrationError(EdgeError):
    """A calibration cannot be fitted from the data given, or a calibration file is wrong."""

    exit_code = 1


class CommandError(EdgeError):
    """An MQTT command is refused: bad JSON, unknown name, a value out of range (`ok: false`)."""

    exit_code = 2


class StorageError(EdgeError):
    """The state directory (outgoing queue, calibration) cannot be read or written."""

    exit_code = 1
