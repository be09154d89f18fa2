"""Auto-exposure methods and their closed-loop runs on emulated images.

Python API::

    from bracketry_emulator.ae import get_method, run_methods
    m = get_method("ae50")                   # fix, ae30, ae50, ae70, shim, wang, kim, zhang, drl, constant-<ms>,
                                             # pkg.module:Class, or an entry point of group bracketry.ae_methods
    m.reset(4000.0)
    t_next_us = m.next_exposure_us(mosaic_uint16, 4000.0, {"step": 0})
    summary = run_methods("dataset/", ["ae50", "shim"], "out/", workers=2)

One module per method documents its paper, parameters and deviations: classical (Fix, AE30/50/70, constant), shim,
wang, kim (+ gp), zhang, drl (torch, optional extra). Plugins: PLUGINS.md.
"""

from __future__ import annotations

from .base import AEMethod, bayer_gray
from .classical import ClassicalAE, ConstantExposure, FixAE, classical_step_ms
from .closedloop import (
    DEFAULT_INIT_EXPOSURE_US,
    DEFAULT_MAX_EXPOSURE_US,
    DEFAULT_MIN_EXPOSURE_US,
    LoopConfig,
    MethodRun,
    RunSummary,
    run_methods,
)
from .registry import BUILTIN_METHODS, ENTRY_POINT_GROUP, PAPER_METHODS, expand_methods, get_method, load_plugin

__all__ = ["BUILTIN_METHODS", "DEFAULT_INIT_EXPOSURE_US", "DEFAULT_MAX_EXPOSURE_US", "DEFAULT_MIN_EXPOSURE_US",
           "ENTRY_POINT_GROUP", "PAPER_METHODS", "AEMethod", "ClassicalAE", "ConstantExposure", "FixAE", "LoopConfig",
           "MethodRun", "RunSummary", "bayer_gray", "classical_step_ms", "expand_methods", "get_method",
           "load_plugin", "run_methods"]
