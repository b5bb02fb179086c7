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
    """A sweep recording cannot be read or written as `edge-sweep/1` says."""

    exit_code = 1


class SceneError(EdgeError):
    """A simulated scene file is wrong."""

    exit_code = 2


class HardwareError(EdgeError):
    """A part of the rig (camera, lasers, pan-tilt unit) did not deliver."""

    exit_code = 1


class CalibrationError(EdgeError):
    """A calibration cannot be fitted from the data given, or a calibration file is wrong."""

    exit_code = 1


class CommandError(EdgeError):
    """An MQTT command is refused: bad JSON, unknown name, a value out of range (`ok: false`)."""

    exit_code = 2


class StorageError(EdgeError):
    """The state directory (outgoing queue, calibration) cannot be read or written."""

    exit_code = 1
