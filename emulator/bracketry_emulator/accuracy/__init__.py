"""Accuracy protocols of the emulator.

- :func:`run_static` (``bracketry accuracy static STACK_DIR``): the paper's static validation - emulate every
  ground-truth exposure of a static stack from its brackets; RMSE in DN (raw, noise-corrected with the 25-frame
  repeats, and against the noise-free truth when present); per-bracket curves and per-mode curves.
- :func:`run_neighbours` (``bracketry accuracy neighbours DATASET``): real moving data - emulate bracket k from
  k-1 and k+1, with and without global alignment; RMSE and mean bias per selection mode.
Both return JSON-ready dicts; :mod:`.plots` draws them.
"""

from __future__ import annotations

from .metrics import bias_dn, noise_corrected, noise_floor_dn, rmse_dn
from .neighbours import run_neighbours
from .stack import StaticStack, open_static_stack
from .static import run_static

__all__ = ["StaticStack", "bias_dn", "noise_corrected", "noise_floor_dn", "open_static_stack", "rmse_dn",
           "run_neighbours", "run_static"]
