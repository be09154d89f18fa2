"""pytest configuration: component markers (skip, or fail in strict mode), the real sample data fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

from bracketry_testkit import MARKER_NEEDS, require_marker_components, sample_dir


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
