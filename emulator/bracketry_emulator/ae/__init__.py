"""Auto-exposure methods and their closed-loop runs on emulated images.

Python API::

    from bracketry_emulator.ae import get_method, run_methods
    m = get_method("ae50")                   # fix, ae30, ae50, ae70, shim, wang, kim, zhang, drl, constant-<ms>,
                                             # pkg.module:Class, or an entry point of group bracketry.ae_methods
    m.reset(4000.0)
    t_next_us = m.next_exposure_us(mosaic_uint16, 4000.0, {"step": 0})
    steps = run_loop(m, sequences, emulate)  # the pure loop: emulate(sequence, target_us) -> Frame
    summary = run_methods("dataset/", ["ae50", "shim"], "out/", workers=2)   # load, run every loop, save

The closed loop: :mod:`.loop` (pure core), :mod:`.scheduler` (processes, shared decoding, step order),
:mod:`.writers` (PNG, CSV, JSON, plot), :mod:`.runner` (``run_methods``).

One module per method documents its paper, parameters and deviations: classical (Fix, AE30/50/70, constant), shim,
wang, kim (+ gp), zhang, drl (torch, optional extra). Plugins: PLUGINS.md.
"""

from __future__ import annotations

from .base import AEMethod, CameraSetting, bayer_gray
from .classical import ClassicalAE, ConstantExposure, FixAE, classical_step_ms
from .loop import (
    DEFAULT_INIT_EXPOSURE_US,
    DEFAULT_MAX_EXPOSURE_US,
    DEFAULT_MIN_EXPOSURE_US,
    Frame,
    MethodRun,
    Step,
    iter_loop,
    run_loop,
)
from .registry import (
    BUILTIN_METHODS,
    ENTRY_POINT_GROUP,
    PAPER_METHODS,
    MethodSpec,
    get_method,
    load_plugin,
    parse_method_options,
    parse_methods,
    resolve_methods,
)
from .runner import LoopConfig, RunSummary, run_methods

__all__ = ["BUILTIN_METHODS", "DEFAULT_INIT_EXPOSURE_US", "DEFAULT_MAX_EXPOSURE_US", "DEFAULT_MIN_EXPOSURE_US",
           "ENTRY_POINT_GROUP", "PAPER_METHODS", "AEMethod", "CameraSetting", "ClassicalAE", "ConstantExposure",
           "FixAE", "Frame",
           "LoopConfig", "MethodRun", "MethodSpec", "RunSummary", "Step", "bayer_gray", "classical_step_ms",
           "get_method", "iter_loop", "load_plugin", "parse_method_options", "parse_methods", "resolve_methods",
           "run_loop",
           "run_methods"]
