"""Classical mean-brightness AE (AE30, AE50, AE70) and the fixed-exposure baseline (Fix), with the authors' rules.

Paper: Gamache et al., "Reproducible Evaluation of Camera Auto-Exposure Methods in the Field" (baselines section):
AE30/50/70 keep the mean brightness at 30/50/70 % of the 12-bit range; Fix picks its exposure once at the start of
the sequence with a 50 % brightness target.

Update rule (the authors' ``classical-P``, reproduced exactly, parity tested on the real sample), in ms::

    gray = cvtColor(mosaic, COLOR_BAYER_RG2GRAY)      # uint16 12-bit codes (see base.bayer_gray for the RG quirk)
    T = int(P / 100 * 4096)                           # 1228 / 2048 / 2867
    e = mean(gray) - T
    t_next = t            if |e| < 15
             |t - 0.002 e| otherwise                  # +0.002 ms per DN below the target

Parameters: ``percent`` (P), ``gain_ms_per_dn`` = 0.002, ``deadband_dn`` = 15. No clamp of its own (the runner's
bounds apply), as upstream. That is ``parity="upstream"``. Its two quirks: a fixed step in ms per DN is a
relative step that shrinks as the exposure grows and grows as it shrinks (loop gain 0.002 x dB/dt: above 2 below
about 1 ms on a mid-grey scene, where the exposure oscillates and never settles; about 0.05 at 40 ms, where a dark
scene takes dozens of steps), and ``abs()`` turns an overshoot below zero into a positive exposure, which makes
t = 0.001 e a false fixed point (measured: AE30 stuck at 2.17 ms with 83 % brightness on a static scene 70 %
saturated at 4 ms).

Default (the paper's proportional control towards the target, corrected so that it settles at any exposure)::

    t_next = t                                  if |e| < 15
             t max(1 - 0.002 e / 4 ms, 1/4)      otherwise

i.e. the same proportional control on the RELATIVE exposure, its gain equal to the authors' at their 4 ms start
(so the first step from 4 ms is theirs), a loop gain of about 0.5 at any exposure, and an overshoot below zero
becomes a 4x reduction instead of a reflection.

Fix:
- ``parity="upstream"`` (the authors' code): the classical-50 step for the first 4 calls (their counter 0..3),
  then the exposure is returned unchanged for the rest of the run, wherever the 4 steps ended (36 % brightness on
  the sample).
- default (the paper: "selected once, at the beginning of each sequence, by using a brightness target of 50 %"):
  Fix CONVERGES to the 50 % target once, then holds. The settling steps scale the exposure by the brightness
  ratio in linear light (t * f^-1(T) / f^-1(mean), the ratio limited to [1/4, 4] per step; f^-1 = the emulator's
  response, so on a static scene one or two steps suffice) until the mean is within ``tolerance`` = 5 % of the
  target or ``max_settle_steps`` = 12 steps have passed; from then on the exposure never changes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .base import FULL_SCALE_12BIT, check_input, gray_for


def classical_step_ms(mean_dn: float, t_ms: float, percent: float, gain_ms_per_dn: float = 0.002,
                      deadband_dn: float = 15.0) -> float:
    """One step of the authors' classical rule: next exposure (ms) from the gray mean (12-bit DN) and t (ms)."""
    target = int(percent / 100.0 * FULL_SCALE_12BIT)
    err = mean_dn - target
    if abs(err) < deadband_dn:
        return t_ms
    return abs(t_ms - gain_ms_per_dn * err)


#: Exposure (ms) at which the default classical step equals the authors' (their initial exposure).
CLASSICAL_REFERENCE_MS = 4.0


def classical_step_default_ms(mean_dn: float, t_ms: float, percent: float, gain_ms_per_dn: float = 0.002,
                              deadband_dn: float = 15.0) -> float:
    """The corrected classical step (module docstring): the authors' gain scaled by t / 4 ms (their step at 4 ms),
    never below t / 4 (no abs() reflection)."""
    target = int(percent / 100.0 * FULL_SCALE_12BIT)
    err = mean_dn - target
    if abs(err) < deadband_dn:
        return t_ms
    return t_ms * max(1.0 - gain_ms_per_dn * err / CLASSICAL_REFERENCE_MS, 0.25)


class ClassicalAE:
    """AE-P: proportional control of the mean gray brightness to P % of 4096 (ids ae30, ae50, ae70)."""

    #: relative cost of one step, for balancing worker processes (see registry.MethodTraits)
    step_cost = 1

    def __init__(self, percent: float = 50.0, gain_ms_per_dn: float = 0.002, deadband_dn: float = 15.0,
                 name: str | None = None, parity: str = "default") -> None:
        if not 0 < percent < 100:
            raise ValueError(f"brightness target must be in (0, 100) %, got {percent}")
        self.percent = percent
        self.gain_ms_per_dn = gain_ms_per_dn
        self.deadband_dn = deadband_dn
        self.name = name or f"ae{percent:g}"
        self._step = classical_step_ms if parity == "upstream" else classical_step_default_ms
        #: methods of the same group take the same steps at the start (see registry.MethodTraits)
        self.step_group = f"classical-{percent:g}-{'upstream' if parity == 'upstream' else 'default'}"

    def reset(self, init_exposure_us: float) -> None:
        """Stateless: nothing to forget."""

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        check_input(image, exposure_us)
        mean_dn = float(np.mean(gray_for(image, meta)))
        t_ms = self._step(mean_dn, exposure_us / 1000.0, self.percent, self.gain_ms_per_dn, self.deadband_dn)
        return t_ms * 1000.0


class FixAE:
    """Fix: the classical-50 step for the first ``settle_steps`` calls, then a constant exposure (id fix with
    ``--parity upstream``; the authors' rule)."""

    #: relative cost of one step, for balancing worker processes (see registry.MethodTraits)
    step_cost = 1
    #: its first steps are the classical-50 steps of the authors' arithmetic (see registry.MethodTraits)
    step_group = "classical-50-upstream"

    def __init__(self, settle_steps: int = 4, percent: float = 50.0, name: str = "fix") -> None:
        self.settle_steps = settle_steps
        self._classical = ClassicalAE(percent, parity="upstream")
        self.name = name
        self._calls = 0

    def reset(self, init_exposure_us: float) -> None:
        self._calls = 0

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        check_input(image, exposure_us)
        calls = self._calls
        self._calls += 1
        if calls < self.settle_steps:
            return self._classical.next_exposure_us(image, exposure_us, meta)
        return float(exposure_us)


class ConvergingFixAE:
    """Fix as the paper describes it: converge once to the 50 % brightness target, then hold (id fix; see the
    module docstring for the settling rule)."""

    #: relative cost of one step, for balancing worker processes (see registry.MethodTraits)
    step_cost = 1

    def __init__(self, percent: float = 50.0, tolerance: float = 0.05, max_settle_steps: int = 12,
                 max_ratio: float = 4.0, name: str = "fix") -> None:
        self.target_dn = float(int(percent / 100.0 * FULL_SCALE_12BIT))
        self.tolerance = tolerance
        self.max_settle_steps = max_settle_steps
        self.max_ratio = max_ratio
        self.name = name
        self.reset(0.0)

    def reset(self, init_exposure_us: float) -> None:
        self._calls = 0
        self.held = False

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        check_input(image, exposure_us)
        if self.held:
            return float(exposure_us)
        self._calls += 1
        mean_dn = float(np.mean(gray_for(image, meta)))
        if abs(mean_dn - self.target_dn) <= self.tolerance * self.target_dn or self._calls > self.max_settle_steps:
            self.held = True
            return float(exposure_us)
        from .crfutil import response_of

        icrf = np.asarray(response_of(meta).icrf, dtype=np.float64)
        codes = np.arange(len(icrf), dtype=np.float64)
        lin_target = float(np.interp(self.target_dn, codes, icrf))
        lin_mean = max(float(np.interp(mean_dn, codes, icrf)), 1e-9)
        ratio = float(np.clip(lin_target / lin_mean, 1.0 / self.max_ratio, self.max_ratio))
        return float(exposure_us) * ratio


class ConstantExposure:
    """A constant exposure whatever the image (id constant-<ms>, e.g. constant-8 or constant-2.5)."""

    #: relative cost of one step, for balancing worker processes (see registry.MethodTraits)
    step_cost = 1

    def __init__(self, exposure_ms: float, name: str | None = None) -> None:
        if not np.isfinite(exposure_ms) or exposure_ms <= 0:
            raise ValueError(f"constant exposure must be a positive number of ms, got {exposure_ms}")
        self.exposure_us = float(exposure_ms) * 1000.0
        self.name = name or f"constant-{exposure_ms:g}"
        self.init_exposure_us: float | None = self.exposure_us

    def reset(self, init_exposure_us: float) -> None:
        """Stateless; the runner starts a constant method at its own exposure (``init_exposure_us`` attribute)."""

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        return self.exposure_us
