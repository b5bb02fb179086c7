"""Shared fixtures. Tests mirror the package: tests/test_<module>.py."""

from __future__ import annotations

import tempfile
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


@pytest.fixture(scope="session")
def _state_directories(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("state")


@pytest.fixture(autouse=True)
def _state_directory(_state_directories: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A state folder of each test's own for what runs without `service.state_dir`, in this process
    and in the `edge` processes it starts (they inherit the environment). Without it they would use
    ./state of the checkout (its boot counter, its calibration.json), one folder for all the
    parallel workers, and for the developer's own runs."""
    monkeypatch.setenv("STATE_DIRECTORY", tempfile.mkdtemp(dir=_state_directories))
