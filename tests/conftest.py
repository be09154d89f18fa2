"""pytest configuration: component markers (skip, or fail in strict mode), the real sample data fixtures."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

from bracketry_rig.trigger.qemu import QemuTrigger, build_firmware
from bracketry_testkit import MARKER_NEEDS, STRICT, require_marker_components, sample_dir


def pytest_runtest_setup(item: pytest.Item) -> None:
    for marker in MARKER_NEEDS:
        if item.get_closest_marker(marker) is not None:
            require_marker_components(marker)


@pytest.fixture(scope="session")
def borealhdr_sample() -> Path:
    """Root of the real BorealHDR sample (``calibration/`` and one recording folder)."""
    return sample_dir()


@pytest.fixture(scope="session")
def borealhdr_sequence(borealhdr_sample: Path) -> Path:
    """The sample's recording folder, holding ``camera_left/<exposure_ms>/<timestamp_ns>.png``."""
    for child in sorted(borealhdr_sample.iterdir()):
        if (child / "camera_left").is_dir():
            return child
    pytest.fail(f"no recording folder with camera_left/ under {borealhdr_sample}")
    raise AssertionError("unreachable")


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Strict mode (CI): a skipped test or an empty collection fails the run, whatever skipped it."""
    if not STRICT or exitstatus not in (pytest.ExitCode.OK, pytest.ExitCode.NO_TESTS_COLLECTED):
        return
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    skipped = reporter.stats.get("skipped", []) if reporter is not None else []
    if skipped or session.testscollected == 0:
        what = f"{len(skipped)} test(s) skipped" if skipped else "no test collected"
        if reporter is not None:
            reporter.write_line(f"BRACKETRY_STRICT=1: {what}; strict mode allows none", red=True)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


@pytest.fixture(scope="session")
def trigger_elf(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The trigger firmware ELF (firmware/stm32_trigger), built once per session."""
    return build_firmware(tmp_path_factory.mktemp("stm32_build"))


@pytest.fixture
def trigger_qemu(trigger_elf: Path) -> Iterator[QemuTrigger]:
    """The trigger firmware running in QEMU netduinoplus2, its serial port on a local TCP socket (``.url``)."""
    with QemuTrigger(trigger_elf, serial="tcp") as runner:
        yield runner

