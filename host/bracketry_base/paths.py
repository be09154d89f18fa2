"""Well-known locations: the repository, the real sample data, the MicroPython WebAssembly runtime, the user cache."""

from __future__ import annotations

import os
from pathlib import Path

#: Environment variable that points at the BorealHDR sample (the folder holding ``calibration/``).
SAMPLE_ENV = "BRACKETRY_SAMPLE_DATA"
#: Environment variable that points at the folder holding ``node_modules/@micropython/...``.
MPY_ENV = "BRACKETRY_MPY_WASM"
MPY_NPM_PACKAGE = "@micropython/micropython-webassembly-pyscript"


def repo_root() -> Path:
    """The repository checkout this (editable) install runs from: the parent of ``host/``."""
    return Path(__file__).resolve().parents[2]


def firmware_dir() -> Path:
    """``firmware/`` in the checkout."""
    return repo_root() / "firmware"


def hw_dir() -> Path:
    """``hw/`` in the checkout."""
    return repo_root() / "hw"


def sample_data_dir() -> Path | None:
    """The real BorealHDR sample: ``$BRACKETRY_SAMPLE_DATA`` or ``../shared/data/borealhdr_sample``; None if absent."""
    env = os.environ.get(SAMPLE_ENV)
    candidates = [Path(env)] if env else []
    candidates.append(repo_root().parent / "shared" / "data" / "borealhdr_sample")
    for c in candidates:
        if (c / "calibration").is_dir():
            return c
    return None


def sample_sequence_dir() -> Path | None:
    """The recording folder inside the sample (the one holding ``camera_left/``), or None."""
    root = sample_data_dir()
    if root is None:
        return None
    for child in sorted(root.iterdir()):
        if (child / "camera_left").is_dir():
            return child
    return None


def micropython_runtime_dir() -> Path:
    """Folder whose ``node_modules`` holds the MicroPython WebAssembly runtime (set up by ``setup.sh``)."""
    env = os.environ.get(MPY_ENV)
    if env:
        return Path(env)
    return repo_root() / ".venv" / "micropython-wasm"


def micropython_module_path() -> Path:
    """Path of ``micropython.mjs`` inside the runtime folder (it may not exist)."""
    return micropython_runtime_dir() / "node_modules" / MPY_NPM_PACKAGE / "micropython.mjs"


def user_cache_dir() -> Path:
    """The user's cache of bracketry (ORB-SLAM3 vocabularies, rendered synthetic suites): ``$BRACKETRY_CACHE``, else
    ``$XDG_CACHE_HOME/bracketry``, else ``~/.cache/bracketry``."""
    env = os.environ.get("BRACKETRY_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "bracketry"
