"""The headless service (`edge run`) and its parts; see `edge.service.loop`."""

from edge.service.health import CAMERA_RESTART_AFTER, RigHealth
from edge.service.loop import Service

__all__ = ["CAMERA_RESTART_AFTER", "RigHealth", "Service"]
