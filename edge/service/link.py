"""What the service needs of its link to the broker, and a link to nobody.

The service publishes and takes commands through a `Link` and never asks whether it has one: with
MQTT disabled it is given a `NullLink` (frigate's `Communicator` is the model). `edge.mqtt.MqttLink`
is the real one, with its outbox on disk for what must not be lost.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any, Protocol

from edge import __version__
from edge.config import Config


class Link(Protocol):
    def start(self) -> None: ...

    def stop(self) -> None: ...

    def commands(self) -> list[tuple[str, bytes]]:
        """The commands received since the last call, oldest first: (name, raw payload)."""
        ...

    def publish_state(self, payload: dict[str, Any], at_once: bool = False) -> None:
        """The state snapshot; `at_once`: a part's health changed, and it goes out now."""
        ...

    def publish_event(self, kind: str, payload: dict[str, Any]) -> object:
        """A sweep or an alert: kept until the broker has it."""
        ...

    def publish_live(self, kind: str, payload: dict[str, Any]) -> object:
        """A range or a cue: now or never."""
        ...

    def publish_result(self, name: str, ok: bool, error: str | None = None, request_id: str | None = None,
                       extra: dict[str, Any] | None = None) -> None: ...

    def publish_snapshot(self, kind: str, payload: dict[str, Any] | bytes, min_interval_s: float = 0.6) -> None:
        """A retained snapshot whose latest value alone matters (Home Assistant's topics)."""
        ...


class NullLink:
    """No broker: nothing goes out, no command comes in."""

    def start(self) -> None:
        pass

    def stop(self) -> None:
        pass

    def commands(self) -> list[tuple[str, bytes]]:
        return []

    def publish_state(self, payload: dict[str, Any], at_once: bool = False) -> None:
        pass

    def publish_event(self, kind: str, payload: dict[str, Any]) -> None:
        pass

    def publish_live(self, kind: str, payload: dict[str, Any]) -> None:
        pass

    def publish_result(self, name: str, ok: bool, error: str | None = None, request_id: str | None = None,
                       extra: dict[str, Any] | None = None) -> None:
        pass

    def publish_snapshot(self, kind: str, payload: dict[str, Any] | bytes, min_interval_s: float = 0.6) -> None:
        pass


@contextlib.contextmanager
def open_link(config: Config, device_id: str,
              on_storage: Callable[[str], object] | None = None) -> Iterator[Link]:
    """The configured link, started: MQTT with its outbox in the state folder, or a NullLink.
    Stopped (and the outbox closed) when the block ends. `on_storage`: the outbox's condition."""
    if not config.mqtt.enabled:
        yield NullLink()
        return
    from edge.mqtt import MqttLink
    from edge.outbox import Outbox

    state_dir = config.service.resolved_state_dir()
    outbox = Outbox(state_dir / "outbox.sqlite3", config.service.outbox_max_messages, on_storage)
    try:
        link: Link = MqttLink(config.mqtt, device_id, outbox, version=__version__)
        try:
            link.start()
            yield link
        finally:
            link.stop()
    finally:
        outbox.close()
