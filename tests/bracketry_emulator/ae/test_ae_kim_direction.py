"""Kim (default mode) goes AE50's way from 4 ms on static views no one tuned it to (static_views.py: five kinds,
three seeds each, and two views of the real sample, bright and dark), and ends within a factor of AE50.

"AE50's way": AE50 settles far from the 4 ms start (0.6 ms on a bright view, 20 ms on a dark one, factors 6.7 and
5); Kim's median exposure over its last 3 of 10 steps must be on the same side of 4 ms, and within FACTOR of AE50's
(clipped to Kim's 0.5..35 ms range). FACTOR = 4, Kim's reach (one step of its search): it may settle where its own
metric peaks rather than at AE50's mean, but not more than one of its steps away. Known exceptions are strict xfails
(each must keep failing, so a change that fixes one shows).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ae_scenes import closed_loop
from static_views import KINDS, at_ae50, sample_view

from bracketry_emulator.ae import get_method

FACTOR = 4.0
START_US = 4000.0
LEVELS_US = {"bright": 600.0, "dark": 20_000.0}
#: dark trunks against a bright sky, AE50 at 0.6 ms: Kim's metric is near its peak at 3-5 ms (the trunks' texture),
#: Kim ends on AE50's side at 2.9-3.6 ms, 5-6x from it
METRIC_DISAGREES = {("dusk_forest", 0, "bright"), ("dusk_forest", 1, "bright"), ("dusk_forest", 2, "bright")}
#: a dark frozen lake whose metric is flat between 4 and 6 ms: Kim settles at 4.6 ms (within 4.35x of AE50's 20 ms)
PLATEAU = {("lake", 2, "dark")}


def _cases() -> list:
    out = []
    for kind in KINDS:
        for seed in range(3):
            for level in LEVELS_US:
                case = (kind, seed, level)
                reason = "Kim's metric is near its peak at 3-5 ms here" if case in METRIC_DISAGREES else \
                    "Kim's metric is flat at 4-6 ms here" if case in PLATEAU else ""
                marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
                out.append(pytest.param(kind, seed, level, marks=marks, id=f"{kind}-{seed}-{level}"))
    return out


@pytest.mark.parametrize("kind,seed,level", _cases())
def test_kim_goes_ae50s_way_on_static_views(kind: str, seed: int, level: str) -> None:
    _check(KINDS[kind](np.random.default_rng(seed)), level)


@pytest.mark.parametrize("index", [0, 2])
@pytest.mark.parametrize("level", list(LEVELS_US))
def test_kim_goes_ae50s_way_on_the_real_samples_views(borealhdr_sequence: Path, index: int, level: str) -> None:
    _check(sample_view(borealhdr_sequence, index), level)


def _check(view: np.ndarray, level: str) -> None:
    irr, ae50_us = at_ae50(view, LEVELS_US[level])
    assert abs(np.log(ae50_us / LEVELS_US[level])) < np.log(1.1), ae50_us
    kim = closed_loop(get_method("kim"), irr, START_US, 10)
    settled_us = float(np.median(kim[-3:]))
    reference_us = float(np.clip(ae50_us, 500.0, 35_000.0))
    trace = " ".join(f"{t / 1000:.2f}" for t in kim)
    assert (settled_us < START_US) == (reference_us < START_US), f"wrong way: AE50 {ae50_us / 1000:.2f} ms, {trace}"
    assert abs(np.log(settled_us / reference_us)) <= np.log(FACTOR), f"AE50 {ae50_us / 1000:.2f} ms, Kim {trace}"
