"""The closed loop's pure core (ae/loop.py) on arrays: no dataset, no files, no processes."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from bracketry_base.errors import BracketryError
from bracketry_emulator.ae import ConstantExposure, Frame, run_loop
from bracketry_emulator.ae.base import CameraSetting
from bracketry_emulator.ae.registry import MethodTraits, method_traits


def _world(scenes: list[float]) -> tuple[list[tuple[int, float]], Any, list[tuple[int, float]]]:
    """Sequences (index, scene brightness in DN per us), an ``emulate`` and the log of its calls."""
    calls: list[tuple[int, float]] = []

    def emulate(seq: tuple[int, float], target_us: float) -> Frame:
        index, dn_per_us = seq
        calls.append((index, target_us))
        image = np.full((4, 6), min(4095, round(dn_per_us * target_us)), np.uint16)
        return Frame(image, 1_000_000 * index, 2000, index, {"side": "left"})

    return [(k, s) for k, s in enumerate(scenes)], emulate, calls


def test_constant_method_keeps_its_own_exposure() -> None:
    seqs, emulate, calls = _world([0.5, 0.1, 0.9])
    steps = run_loop(ConstantExposure(8.0, name="constant-8"), seqs, emulate)
    # the method's own init_exposure_us (8 ms) wins over the loop's 4 ms default; every step emulates it
    assert calls == [(0, 8000.0), (1, 8000.0), (2, 8000.0)]
    assert [(s.step, s.sequence_index, s.timestamp_ns, s.exposure_us, s.next_exposure_us, s.source_exposure_us)
            for s in steps] == [(k, k, 1_000_000 * k, 8000.0, 8000.0, 2000) for k in range(3)]
    assert all(s.ae_s >= 0 for s in steps)


class _HalfScale:
    """Asks for the exposure that brings the mean to 2048 DN; records what it saw."""

    name = "half"

    def __init__(self) -> None:
        self.seen: list[tuple[float, float, dict]] = []

    def reset(self, init_exposure_us: float) -> None:
        self.seen.clear()
        self.init = init_exposure_us

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        self.seen.append((float(image.mean()), exposure_us, dict(meta)))
        return exposure_us * 2048.0 / max(float(image.mean()), 1.0)


def test_method_sees_the_image_emulated_at_the_exposure_it_asked_for() -> None:
    seqs, emulate, calls = _world([0.5, 0.5, 0.25, 1.0])
    method = _HalfScale()
    steps = run_loop(method, seqs, emulate, init_exposure_us=1000.0, min_exposure_us=100.0, max_exposure_us=6000.0)
    assert method.init == 1000.0
    # step k's target is step k-1's answer, and the image the method saw was emulated at that target
    assert [t for _, t in calls] == [s.exposure_us for s in steps] == [1000.0, 4096.0, 4096.0, 6000.0]
    assert [m for m, _, _ in method.seen] == [500.0, 2048.0, 1024.0, 4095.0]
    assert [s.next_exposure_us for s in steps] == [4096.0, 4096.0, 6000.0, 6000.0 * 2048.0 / 4095.0]
    # the answer 8192 us at step 2 was clamped to the upper bound before it became the next target
    meta = method.seen[2][2]
    assert meta == {"step": 2, "timestamp_ns": 2_000_000, "sequence_index": 2, "source_exposure_us": 2000,
                    "bounds_us": (100.0, 6000.0), "side": "left", "gain_db": 0.0, "camera_exposure_us": 4096.0}
    assert all(s.next_gain_db is None for s in steps)  # it sets exposures only: emulate never got a gain


class _GainFirst:
    """Sets the gain itself: keeps the exposure at 2 ms and brings the mean to 2048 DN with gain (then clamped)."""

    name = "gain-first"

    def __init__(self) -> None:
        self.seen: list[tuple[float, dict]] = []

    def reset(self, init_exposure_us: float) -> None:
        self.seen.clear()

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> CameraSetting:
        self.seen.append((exposure_us, dict(meta)))
        wanted_us = exposure_us * 2048.0 / max(float(image.mean()), 1.0)
        return CameraSetting(2000.0, 20.0 * float(np.log10(max(wanted_us / 2000.0, 1e-3))))


def test_a_method_that_sets_the_gain_gets_exposure_times_gain() -> None:
    """The answer (2 ms, g dB) becomes the target 2 ms x 10^(g / 20), emulated with that gain; the gain is clamped to
    [0, max_gain_db] (a scene needing 4x gets 12 dB; one needing 64x gets the 24 dB bound, 16x)."""
    calls: list[tuple[int, float, float | None]] = []

    def emulate(seq: tuple[int, float], target_us: float, gain_db: float | None = None) -> Frame:
        index, dn_per_us = seq
        calls.append((index, target_us, gain_db))
        image = np.full((4, 6), min(4095, round(dn_per_us * target_us)), np.uint16)
        return Frame(image, index, 2000, index, {}, 0.0 if gain_db is None else gain_db)

    # 2048 DN needs 4096 us at 0.5 DN/us (2 ms x 6.23 dB), 127 ms at 0.016 DN/us (2 ms x 36 dB: clamped to 24)
    seqs = [(0, 0.5), (1, 0.5), (2, 0.016), (3, 0.016)]
    method = _GainFirst()
    steps = run_loop(method, seqs, emulate, init_exposure_us=1000.0, max_gain_db=24.0)
    assert calls[0] == (0, 1000.0, None)  # the first target: an exposure (no answer yet)
    assert calls[1][1] == pytest.approx(4096.0) and calls[1][2] == pytest.approx(6.2266, abs=1e-3)
    assert steps[2].next_gain_db == 24.0 and steps[2].next_exposure_us == pytest.approx(2000.0 * 10 ** 1.2)
    assert steps[2].next_camera_exposure_us == pytest.approx(2000.0)
    assert calls[3] == (3, pytest.approx(2000.0 * 10 ** 1.2), 24.0)
    # the method saw its image's gain and the camera's exposure in meta, and exposure x gain as exposure_us
    exposure_us, meta = method.seen[3]
    assert exposure_us == pytest.approx(2000.0 * 10 ** 1.2)
    assert meta["gain_db"] == 24.0 and meta["camera_exposure_us"] == pytest.approx(2000.0)
    assert [s.gain_db for s in steps] == [0.0, pytest.approx(6.2266, abs=1e-3), pytest.approx(6.2266, abs=1e-3),
                                          24.0]


def test_a_non_finite_gain_is_one_line() -> None:
    class Bad:
        name = "bad-gain"

        def reset(self, init_exposure_us: float) -> None:
            pass

        def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> CameraSetting:
            return CameraSetting(1000.0, float("nan"))

    seqs, emulate, _ = _world([0.5])
    with pytest.raises(BracketryError, match="returned a non-finite gain at step 0"):
        run_loop(Bad(), seqs, emulate)


@pytest.mark.parametrize("answer,words", [(float("nan"), "returned a non-finite exposure at step 0"),
                                          (ValueError("boom"), "failed at step 0: ValueError: boom")])
def test_a_failing_method_is_one_line_naming_it(answer: Any, words: str) -> None:
    class Bad:
        name = "bad"

        def reset(self, init_exposure_us: float) -> None:
            pass

        def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
            if isinstance(answer, Exception):
                raise answer
            return answer

    seqs, emulate, _ = _world([0.5])
    with pytest.raises(BracketryError, match=f"AE method my-bad {words}"):
        run_loop(Bad(), seqs, emulate, name="my-bad")


def test_methods_declare_their_scheduling_traits() -> None:
    assert method_traits("kim") == MethodTraits(40)  # its GP is numpy only (fixed hyper-parameters)
    assert method_traits("kim", parity="upstream").start_up == "scipy"
    assert method_traits("zhang", parity="upstream") == MethodTraits(45, None, "scipy")
    assert method_traits("ae50") == method_traits("ae50") == MethodTraits(1, "classical-50-default")
    assert method_traits("fix", parity="upstream") == MethodTraits(1, "classical-50-upstream")
    assert method_traits("constant-3") == MethodTraits(1, None)
    # drl is not created in the parent (torch threads): its class is checked instead
    with pytest.raises(BracketryError, match="drl method needs its weights"):
        method_traits("drl")


def test_scheduler_balances_declared_costs_and_keeps_a_step_group_together() -> None:
    from bracketry_emulator.ae.scheduler import partition

    traits = {"fix": MethodTraits(1, "g"), "kim": MethodTraits(40), "ae50": MethodTraits(1, "g"),
              "wang": MethodTraits(20), "shim": MethodTraits(10)}
    # costs with emulation (16 per step): kim 56, wang 36, fix+ae50 34, shim 26 -> longest first onto the lighter
    assert partition(traits, 2) == [["kim", "shim"], ["fix", "ae50", "wang"]]
    assert partition(traits, 1) == [list(traits)]
    assert sorted(map(len, partition(traits, 8))) == [1, 1, 1, 2]  # never an empty worker; the group stays whole


def test_scheduler_keeps_methods_sharing_a_start_up_together_where_the_balance_allows() -> None:
    from bracketry_emulator.ae.scheduler import partition

    traits = {"fix": MethodTraits(1, "c50"), "ae30": MethodTraits(1, "c30"), "ae50": MethodTraits(1, "c50"),
              "ae70": MethodTraits(1, "c70"), "shim": MethodTraits(40), "kim": MethodTraits(30, None, "scipy"),
              "zhang": MethodTraits(45, None, "scipy")}
    # with emulation (16 per step): zhang 61, shim 56, kim 46, fix+ae50 34, ae30 17, ae70 17; kim + zhang (107) is
    # within an equal share of two workers (115.5): one unit, which the longest-first split puts first
    assert partition(traits, 2) == [["ae70", "kim", "zhang"], ["fix", "ae30", "ae50", "shim"]]
    without = {s: MethodTraits(t.step_cost, t.step_group) for s, t in traits.items()}
    assert partition(without, 2) == [["fix", "ae30", "ae50", "zhang"], ["ae70", "shim", "kim"]]
    # four workers: together they would exceed a share (57.75), so they are split as any other methods
    assert [g for g in partition(traits, 4) if "kim" in g] != [g for g in partition(traits, 4) if "zhang" in g]


class _Halving:
    """Halves the exposure at every call (a method that never settles: each warm-up step shows)."""

    name = "halving"

    def __init__(self) -> None:
        self.metas: list[dict] = []

    def reset(self, init_exposure_us: float) -> None:
        self.metas.clear()

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        self.metas.append(dict(meta))
        return exposure_us / 2


def test_warmup_steps_run_on_the_first_view_and_are_not_steps() -> None:
    seqs, emulate, calls = _world([0.5, 0.1, 0.9])
    method = _Halving()
    steps = run_loop(method, seqs, emulate, init_exposure_us=8000.0, min_exposure_us=100.0, warmup_steps=3)
    # three warm-up images of the first sequence (8, 4, 2 ms), then one step per sequence from 1 ms on
    assert calls == [(0, 8000.0), (0, 4000.0), (0, 2000.0), (0, 1000.0), (1, 500.0), (2, 250.0)]
    assert [(s.step, s.sequence_index, s.exposure_us) for s in steps] == [(0, 0, 1000.0), (1, 1, 500.0),
                                                                        (2, 2, 250.0)]
    assert [m["step"] for m in method.metas] == [-3, -2, -1, 0, 1, 2]
    assert [m.get("warmup", False) for m in method.metas] == [True, True, True, False, False, False]


def test_warmup_brings_a_converging_method_to_the_first_view_exposure() -> None:
    seqs, emulate, _ = _world([0.05, 0.05, 0.05])
    cold = run_loop(_HalfScale(), seqs, emulate, init_exposure_us=1000.0, max_exposure_us=100_000.0)
    warm = run_loop(_HalfScale(), seqs, emulate, init_exposure_us=1000.0, max_exposure_us=100_000.0,
                    warmup_steps=4)
    assert cold[0].exposure_us == 1000.0  # the cold start's first image is 20x too dark
    assert warm[0].exposure_us == pytest.approx(2048 / 0.05, rel=0.01)  # settled before the walk
    assert len(warm) == len(cold) == 3
