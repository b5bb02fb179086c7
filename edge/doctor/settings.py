"""What the doctor needs to know of the configuration, read two ways.

With numpy importable the whole typed configuration is loaded (:func:`edge.config.load_config`:
every key checked, a bad one is an error at once). Without it — the day the heavy packages are
broken, which is when the doctor is needed — the checks that need no numpy still run on the parts'
own light settings, read from the file as a table the way ``edge lasers off`` reads its wiring:
the pan-tilt unit's, the lasers', the simulator's, and a few strings (backends, the state folder).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from edge.config_file import apply_overrides, default_config_path, read_table
from edge.errors import ConfigError
from edge.hw.lasers import LasersConfig, LaserWiring, wiring_from_table
from edge.hw.ptu import PtuConfig
from edge.schema import build
from edge.sim.settings import SimConfig

if TYPE_CHECKING:
    from edge.config import Config


@dataclass(frozen=True)
class Settings:
    """The parts' light settings, as the typed configuration has them or the file says."""

    source: str
    camera_backend: str
    camera_device: str
    lasers: LasersConfig
    wiring: tuple[LaserWiring, ...]
    ptu: PtuConfig
    sim: SimConfig
    state_dir: Path
    audio_out: str

    @property
    def all_simulated(self) -> bool:
        """Every part is the simulator's (edge.parts.all_simulated, without the typed config)."""
        return self.camera_backend == "sim" and self.lasers.backend == "sim" and self.ptu.port.startswith("sim://")

    @property
    def real_parts(self) -> list[str]:
        parts = []
        if self.camera_backend != "sim":
            parts.append(f"camera ({self.camera_backend})")
        if self.lasers.backend != "sim":
            parts.append("lasers (gpio)")
        if not self.ptu.port.startswith("sim://"):
            parts.append(f"pan-tilt unit ({self.ptu.port})")
        return parts

    def clock(self) -> Any:
        """The rig's clock, as :func:`edge.parts.rig_clock` chooses it."""
        from edge.clock import REAL, SimClock

        if self.sim.clock != "real" and self.all_simulated:
            return SimClock(paced=self.sim.clock == "paced")
        return REAL


def _state_dir(configured: str) -> Path:
    # As ServiceConfig.resolved_state_dir: the key, else systemd's $STATE_DIRECTORY, else ./state.
    return Path(configured or os.environ.get("STATE_DIRECTORY", "").split(":")[0] or "state")


def from_config(config: Config) -> Settings:
    return Settings(config.source, config.camera.backend, config.camera.device, config.lasers,
                    config.rig.wiring(), config.ptu, config.sim, config.service.resolved_state_dir(),
                    config.audio.out)


def table_of(path: str | None, overrides: list[str]) -> tuple[dict[str, Any], str]:
    """The configuration file as a table with the overrides applied, and its name."""
    file = Path(path) if path is not None else default_config_path()
    data = read_table(file)
    apply_overrides(data, overrides)
    return data, str(file)


def _section(data: dict[str, Any], source: str, key: str) -> dict[str, Any]:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise ConfigError(f"{source}: {key}: expected a table")
    return value


def _string(section: dict[str, Any], source: str, key: str, default: str) -> str:
    value = section.get(key.rpartition(".")[2], default)
    if not isinstance(value, str):
        raise ConfigError(f"{source}: {key}: expected a string")
    return value


def from_table(data: dict[str, Any], source: str) -> Settings:
    """The light settings straight from the file (when the typed configuration cannot be loaded)."""
    rig = _section(data, source, "rig")
    wiring = wiring_from_table(rig, source)
    camera = _section(data, source, "camera")
    return Settings(
        source,
        _string(camera, source, "camera.backend", "sim"),
        _string(camera, source, "camera.device", "0"),
        build(LasersConfig, _section(data, source, "lasers"), source, "lasers"),
        wiring,
        build(PtuConfig, _section(data, source, "ptu"), source, "ptu"),
        build(SimConfig, _section(data, source, "sim"), source, "sim"),
        _state_dir(_string(_section(data, source, "service"), source, "service.state_dir", "")),
        _string(_section(data, source, "audio"), source, "audio.out", ""),
    )
