"""ClockModel on a simulated device clock with offset, drift and jittery, asymmetric round trips (no real time)."""

from __future__ import annotations

import math
import random

import pytest

from bracketry_rig.wire.clock import ClockModel

T0_NS = 1_700_000_000_000_000_000


def _simulate(seed: int, drift_ppm: float, n: int = 200, mean_leg_us: float = 300.0,
              tick_jitter_us: float = 1.0) -> tuple[ClockModel, list[float], list[float]]:
    """Pings every ~55 ms; each leg = 60 us + exponential(mean_leg_us); device clock = offset + (1+drift) * t.
    Returns the model, its true errors (us) every 250 ms of the sampled span and its error bounds there."""
    rng = random.Random(seed)
    model = ClockModel()
    offset_us = 4_000_000_123

    def device_us(host_ns: int) -> float:
        return offset_us + (host_ns - T0_NS) * (1 + drift_ppm * 1e-6) / 1000.0

    t = T0_NS
    for _ in range(n):
        t += 50_000_000 + rng.randrange(10_000_000)
        up = 60_000 + int(rng.expovariate(1 / (mean_leg_us * 1000)))
        down = 60_000 + int(rng.expovariate(1 / (mean_leg_us * 1000)))
        reading = int(device_us(t + up) + rng.uniform(-tick_jitter_us, tick_jitter_us))
        model.add_sample(t, t + up + down, reading)
    # true error of the model over the sampled span, in us
    errors, bounds = [], []
    for h in range(T0_NS + 1_000_000_000, t + 2_000_000_000, 250_000_000):  # and 2 s past the last sample
        d = int(device_us(h))
        truth_ns = T0_NS + (d - offset_us) * 1000.0 / (1 + drift_ppm * 1e-6)  # the instant the clock reads d
        errors.append((model.device_to_host_ns(d) - truth_ns) / 1000.0)
        bounds.append(model.error_bound_us(d, device_jitter_us=tick_jitter_us))
    return model, errors, bounds


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("drift_ppm", [-120.0, 0.0, 45.0])
def test_wire_clock_residual_under_50us(seed: int, drift_ppm: float) -> None:
    model, errors, _ = _simulate(seed, drift_ppm)
    assert model.residual_us < 50.0
    assert max(abs(e) for e in errors) < 50.0
    assert abs(model.drift_ppm - drift_ppm) < 10.0


def test_wire_clock_uses_low_round_trips() -> None:
    """A few very slow exchanges (e.g. the host was descheduled) do not move the model."""
    model, _, _ = _simulate(7, 30.0, n=100)
    before = model.device_to_host_ns(4_000_000_123 + 3_000_000)
    for i in range(10):  # 50 ms round trips, device reading taken right at the start (maximal asymmetry)
        send = T0_NS + 6_000_000_000 + i * 10_000_000
        model.add_sample(send, send + 50_000_000, int(4_000_000_123 + (send - T0_NS) * (1 + 30e-6) / 1000))
    assert abs(model.device_to_host_ns(4_000_000_123 + 3_000_000) - before) < 20_000


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("mean_leg_us", [30.0, 300.0, 3000.0])
def test_wire_clock_error_bound_holds_and_is_tight(seed: int, mean_leg_us: float) -> None:
    """The bound covers the true error everywhere (past the samples too) and is within a few round trips of it."""
    _, errors, bounds = _simulate(seed, 80.0, mean_leg_us=mean_leg_us)
    assert all(abs(e) <= b for e, b in zip(errors, bounds))
    min_leg_us = 60.0
    assert max(bounds) < 2 * (min_leg_us + mean_leg_us) + 10.0


def test_wire_clock_error_bound_of_one_sample() -> None:
    """One sample: half its round trip plus the device's jitter and resolution."""
    model = ClockModel()
    with pytest.raises(ValueError):
        model.error_bound_us(5)
    model.add_sample(1_000_000, 1_200_000, 77)
    assert model.error_bound_us(77, device_jitter_us=2.0) == pytest.approx(100.0 + 2.0 + 1.0, abs=1e-3)
    model.reset()
    with pytest.raises(ValueError):
        model.error_bound_us(77)


def test_wire_clock_few_samples() -> None:
    model = ClockModel()
    with pytest.raises(ValueError):
        model.device_to_host_ns(5)
    model.add_sample(1_000_000, 1_200_000, 77)
    assert model.device_to_host_ns(77) == 1_100_000
    assert model.device_to_host_ns(78) == 1_101_000  # nominal rate
    assert math.isinf(model.residual_us)
    assert model.host_to_device_us(1_100_000) == 77
    with pytest.raises(ValueError):
        model.add_sample(10, 5, 1)
    model.reset()
    assert model.n_samples == 0
