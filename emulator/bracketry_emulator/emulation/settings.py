"""An :class:`~.emulator.EmulatorConfig` from user settings: the checks shared by ``bracketry emulate`` and the
benchmark's closed loops (one place, one-line errors naming the options)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bracketry_base.errors import BracketryError

from ..defaults import PARITIES
from .emulator import EmulatorConfig


def check_crf(crf: str | Path) -> None:
    """Refuse a camera response that is neither ``srgb`` nor a readable pcalib.txt (256 or 4096 values), before
    any work."""
    if str(crf).lower() == "srgb":
        return
    if not Path(crf).is_file():
        raise BracketryError(f"--crf must be 'srgb' or a pcalib.txt file, got {crf}")
    from ..crf import load_pcalib

    load_pcalib(crf)


def emulator_config(selection: str = "highernosat", crf: str | Path = "srgb", parity: str = "default",
                    **fields: Any) -> EmulatorConfig:
    """The validated emulator settings; ``fields``: further :class:`EmulatorConfig` fields.

    With ``parity="upstream"`` the default selection ``highernosat`` becomes ``upstream`` (the authors'
    closer_least_sat goes with their arithmetic). Raises BracketryError (one line)."""
    check_crf(crf)
    if parity not in PARITIES:
        raise BracketryError(f"--parity must be default or upstream, got {parity}")
    if parity == "upstream" and selection == "highernosat":
        selection = "upstream"
    cfg = EmulatorConfig(selection=selection, crf=str(crf), parity=parity, **fields)  # type: ignore[arg-type]
    cfg.validate()
    return cfg
