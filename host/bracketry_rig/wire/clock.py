"""Device-clock to host-clock model fitted from PING/PONG exchanges (offset + drift, low round-trip samples).

Each exchange gives ``host_send_ns`` (host clock when the PING left), ``host_recv_ns`` (when the PONG arrived) and
``device_us`` (device microsecond clock when it answered). The device instant is assumed to be the midpoint of the
round trip; its error is half the asymmetry of the two legs, which is smallest for the fastest round trips, so the
model is a least-squares line ``host_ns = a + b * device_us`` through the samples with the lowest round trips only.

Each sample's true instant lies inside its round trip, so its error is at most half the round trip (plus the device
clock's jitter and its 1 us resolution); the line is a weighted sum of the samples, so the error of the map at any
device time is bounded by the same weights applied to those per-sample bounds (:meth:`ClockModel.error_bound_us`).
"""

from __future__ import annotations

import math
import threading
from collections import deque


class ClockModel:
    """Linear map from a device microsecond clock to host nanoseconds.

    ``window`` samples are kept (the oldest dropped first); the fit uses the ``low_rtt_fraction`` of them with the
    lowest round trip (at least ``min_fit_samples``). With a single sample the map is an offset with nominal rate
    (1000 ns per us). Thread-safe. Integers are kept exact (host ns ~1e18 exceed float precision), floats only hold
    centred values.
    """

    def __init__(self, window: int = 256, low_rtt_fraction: float = 0.1, min_fit_samples: int = 5) -> None:
        self._samples: deque[tuple[int, int, int]] = deque(maxlen=window)  # (rtt_ns, mid_ns, device_us)
        self._low_rtt_fraction = low_rtt_fraction
        self._min_fit = min_fit_samples
        self._lock = threading.Lock()
        self._x_ref = 0  # device_us reference
        self._y_ref = 0  # host ns reference
        self._c_ns = 0.0  # fitted host ns at x_ref, relative to y_ref
        self._b_ns_per_us = 1000.0
        self._residual_us = math.inf
        self._used = 0
        self._fit_x_us: list[float] = []  # the fitted samples' device times, relative to x_ref
        self._fit_half_rtt_us: list[float] = []  # and their half round trips
        self._slope_fitted = False

    # ------------------------------------------------------------------ samples
    def add_sample(self, host_send_ns: int, host_recv_ns: int, device_us: int) -> None:
        """Add one PING/PONG exchange (host ns when sent and received, device us in the PONG) and refit."""
        if host_recv_ns < host_send_ns:
            raise ValueError("host_recv_ns before host_send_ns")
        rtt_ns = host_recv_ns - host_send_ns
        mid_ns = host_send_ns + rtt_ns // 2
        with self._lock:
            self._samples.append((rtt_ns, mid_ns, int(device_us)))
            self._fit()

    def reset(self) -> None:
        """Forget every sample (e.g. after a device reboot: its clock restarted)."""
        with self._lock:
            self._samples.clear()
            self._c_ns, self._b_ns_per_us, self._residual_us, self._used = 0.0, 1000.0, math.inf, 0
            self._fit_x_us, self._fit_half_rtt_us, self._slope_fitted = [], [], False

    def _fit(self) -> None:
        samples = sorted(self._samples)  # by rtt
        n_fit = max(self._min_fit, int(len(samples) * self._low_rtt_fraction))
        chosen = samples[:n_fit]
        self._x_ref = chosen[0][2]
        self._y_ref = chosen[0][1]
        xs = [float(d - self._x_ref) for _, _, d in chosen]
        ys = [float(m - self._y_ref) for _, m, _ in chosen]
        n = len(chosen)
        mx = sum(xs) / n
        my = sum(ys) / n
        sxx = sum((x - mx) ** 2 for x in xs)
        # A slope needs a spread of device times; over < 10 ms it is too noisy, keep the nominal rate.
        fitted = n >= 2 and sxx > 0 and (max(xs) - min(xs)) >= 10_000.0
        b = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx if fitted else 1000.0
        c = my - b * mx
        self._b_ns_per_us, self._c_ns, self._used = b, c, n
        self._fit_x_us, self._slope_fitted = xs, fitted
        self._fit_half_rtt_us = [(rtt + 1) / 2000.0 for rtt, _, _ in chosen]  # mid_ns is floored
        if n >= 2:
            sq = sum((y - (c + b * x)) ** 2 for x, y in zip(xs, ys))
            self._residual_us = math.sqrt(sq / n) / 1000.0
        else:
            self._residual_us = math.inf

    # ------------------------------------------------------------------ results
    def device_to_host_ns(self, device_us: int) -> int:
        """Host time (ns, same clock as the samples) of a device time (us). ValueError before any sample."""
        with self._lock:
            if not self._samples:
                raise ValueError("clock model has no samples yet")
            return self._y_ref + round(self._c_ns + self._b_ns_per_us * (int(device_us) - self._x_ref))

    def host_to_device_us(self, host_ns: int) -> int:
        """Inverse map: device time (us) of a host time (ns). ValueError before any sample."""
        with self._lock:
            if not self._samples:
                raise ValueError("clock model has no samples yet")
            return self._x_ref + round((host_ns - self._y_ref - self._c_ns) / self._b_ns_per_us)

    def error_bound_us(self, device_us: int, device_jitter_us: float = 0.0) -> float:
        """Worst-case error (us) of :meth:`device_to_host_ns` at ``device_us``, for a device whose clock reads its
        time to within ``device_jitter_us`` (plus its 1 us resolution) and runs at a constant rate over the samples.

        The map is ``sum_i w_i * mid_i`` over the fitted samples (weights of the least-squares line at ``device_us``;
        ``1/n`` each while the nominal rate is kept), and each ``mid_i`` is within half its round trip of the truth,
        so the bound is ``sum_i |w_i| * (rtt_i / 2 + device_jitter_us + 1)``: it grows away from the samples' span.
        While the nominal rate is kept (under 10 ms of samples) the rate error is not in the bound. ValueError before
        any sample.
        """
        with self._lock:
            if not self._samples:
                raise ValueError("clock model has no samples yet")
            xs, half = self._fit_x_us, self._fit_half_rtt_us
            n = len(xs)
            x0 = float(int(device_us) - self._x_ref)
            if self._slope_fitted:
                mx = sum(xs) / n
                sxx = sum((x - mx) ** 2 for x in xs)
                weights = [1.0 / n + (x0 - mx) * (x - mx) / sxx for x in xs]
            else:
                weights = [1.0 / n] * n
            return sum(abs(w) * (h + device_jitter_us + 1.0) for w, h in zip(weights, half))

    @property
    def residual_us(self) -> float:
        """RMS residual (us) of the fitted samples around the line; ``inf`` with fewer than 2 samples."""
        with self._lock:
            return self._residual_us

    @property
    def drift_ppm(self) -> float:
        """Device clock rate error in ppm (positive: the device clock runs fast against the host clock)."""
        with self._lock:
            return (1000.0 / self._b_ns_per_us - 1.0) * 1e6

    @property
    def n_samples(self) -> int:
        """Samples held (<= window)."""
        with self._lock:
            return len(self._samples)

    @property
    def n_fit_samples(self) -> int:
        """Samples used by the last fit (the lowest round trips)."""
        with self._lock:
            return self._used

    @property
    def min_rtt_ns(self) -> int | None:
        """Lowest round trip held (ns), None without samples."""
        with self._lock:
            return min(s[0] for s in self._samples) if self._samples else None

    def summary(self) -> dict[str, float | int | None]:
        """Numbers for logs and status: samples, fit samples, residual_us, drift_ppm, min_rtt_us and error_bound_us
        (:meth:`error_bound_us` at the latest sample's device time; None without samples)."""
        rtt = self.min_rtt_ns
        with self._lock:
            latest_us = self._samples[-1][2] if self._samples else None
        return {"samples": self.n_samples, "fit_samples": self.n_fit_samples, "residual_us": self.residual_us,
                "drift_ppm": self.drift_ppm, "min_rtt_us": None if rtt is None else rtt / 1000.0,
                "error_bound_us": None if latest_us is None else self.error_bound_us(latest_us)}
