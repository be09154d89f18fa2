"""An AE plugin that holds its closed loop at its first step until a gate file exists (the Slurm tests' event).

``slurm_gate_plugin:Gated`` with ``gated.gate=PATH``: the first :meth:`Gated.next_exposure_us` of each instance writes
``PATH.started.<pid>.<n>`` (a run has begun on that worker), then waits until ``PATH`` exists; then it steers like a
mean-intensity AE. So a test knows that a job is mid-run, cancels it, and lets the runs go on by creating the gate;
a run made with the gate already there gives the same result.
"""

from __future__ import annotations

import itertools
import os
import time
from pathlib import Path

_COUNTER = itertools.count()


class Gated:
    """Mean intensity to 45 % of full scale, half the error in stops a step, after the gate opened."""

    name = "gated"

    def __init__(self, gate: str = "") -> None:
        self.gate = Path(gate)
        self.waited = False

    def reset(self, init_exposure_us: float) -> None:
        pass

    def next_exposure_us(self, image, exposure_us: float, meta) -> float:
        if not self.waited:
            self.waited = True
            Path(f"{self.gate}.started.{os.getpid()}.{next(_COUNTER)}").touch()
            while not self.gate.exists():  # the test's event: it creates the file
                time.sleep(0.05)
        mean = max(float(image[::4, ::4].mean()), 1.0)
        return exposure_us * (0.45 * 4095 / mean) ** 0.5
