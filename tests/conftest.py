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


# ---- hardware tests (tests/hardware/): on the rig only ----


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("edge hardware")
    group.addoption("--hardware", action="store_true",
                    help="run the tests marked `hardware` on the rig (also EDGE_HARDWARE=1)")
    group.addoption("--hardware-config", metavar="FILE",
                    help="the rig's configuration for them (default: $EDGE_HARDWARE_CONFIG, else "
                         "/etc/edge/edge.toml)")


def pytest_configure(config: pytest.Config) -> None:
    # Under pytest-xdist (`./dev test`: -n auto), hand the workers one test at a time rather than
    # in blocks of an eighth of the suite each: with blocks, every test marked `slow` (moved to
    # the front below) went to the first worker; one at a time they share them as they come free.
    if getattr(config.option, "maxschedchunk", 0) is None:
        config.option.maxschedchunk = 1


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    import os

    # The slow tests first (in their order), then the others: started last, a 40-s test left one
    # worker running it alone at the end of the run while the other had nothing left to do.
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
    if config.getoption("--hardware") or os.environ.get("EDGE_HARDWARE") == "1":
        return
    skip = pytest.mark.skip(reason="needs the rig: run on the device with --hardware (or EDGE_HARDWARE=1) "
                                   "and --hardware-config /etc/edge/edge.toml")
    for item in items:
        if item.get_closest_marker("hardware") is not None:
            item.add_marker(skip)


@pytest.fixture(scope="session")
def rig_config_path(pytestconfig: pytest.Config) -> Path:
    """The rig's configuration for the hardware tests: ``--hardware-config FILE``, else
    ``$EDGE_HARDWARE_CONFIG``, else the service's own /etc/edge/edge.toml. (They run on the
    simulator too, with ``--hardware --hardware-config config/sim.toml``: so they are tried here.)"""
    import os

    chosen = pytestconfig.getoption("--hardware-config") or os.environ.get("EDGE_HARDWARE_CONFIG")
    path = Path(chosen or "/etc/edge/edge.toml")
    if not path.is_file():
        pytest.fail(f"no rig configuration at {path}: give --hardware-config FILE (README: "
                    "\"From a bare Pi to a running unit\")")
    return path.resolve()


@pytest.fixture(scope="session")
def rig_config(rig_config_path: Path):
    from edge.config import load_config

    return load_config(rig_config_path)
