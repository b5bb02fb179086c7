"""Shared fixtures. Tests mirror the package: tests/test_<module>.py."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# The MQTT fixtures (`broker`, `subscriber`) live in tests/broker.py with the broker they start;
# registering the module as a plugin shares them with every test file, which then imports only the
# helpers it calls (Mosquitto, publish, ...), not the fixtures by name.
pytest_plugins = ["broker"]


@pytest.fixture
def repo() -> Path:
    return REPO
