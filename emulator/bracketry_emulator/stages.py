"""Where a benchmark spends its time: a small collector of seconds per named stage, and the stage table.

Stage names are fixed (table order): ``decode`` (bracket frames read and decoded), ``emulation`` (bracket selection
and emulation of every method's targets), ``ae:<method>`` (one per AE method: its ``next_exposure_us`` calls),
``png_write`` (emulated images encoded and written; only when PNGs are asked for), ``slam`` (one localisation run
per (trajectory, method, repeat): the child process from start to exit, paced runs included), ``metrics`` (RTE/RRE,
failures, coverage from a run's output) and ``report``.

Every stage carries two figures, each summed over the threads and processes that did the work (stages overlap
in time, so they do not add up to the wall clock): ``wall_s`` (time inside the stage) and ``cpu_s`` (CPU time of
the thread, or of the whole child process for SLAM; NaN where not measured). The table divides both by the
trajectory-minutes benchmarked: seconds per trajectory-minute.

Pure: :class:`StageTimes` collects, :func:`stage_rows` tabulates; only :func:`describe_machine` reads the system.
"""

from __future__ import annotations

import math
import os
import platform
import threading
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager

#: the fixed stages, in table order (``ae`` stands for every ``ae:<method>``)
STAGES = ("decode", "emulation", "ae", "png_write", "slam", "metrics", "report")


def ae_stage(method: str) -> str:
    """The stage name of one AE method's own computation."""
    return f"ae:{method}"


def _check(stage: str) -> None:
    base = stage.split(":", 1)[0]
    if base not in STAGES or (base == "ae") != (":" in stage):
        raise ValueError(f"unknown stage {stage!r} (stages: {', '.join(STAGES)}, ae:<method>)")


class StageTimes:
    """Seconds per stage (wall and CPU, summed over everything that did the work) and how often each ran.

    ``merge`` adds another collector (e.g. a worker process's, sent back as :meth:`as_dict`)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()  # decodes and PNG writes are timed on threads
        self.wall_s: dict[str, float] = {}
        self.cpu_s: dict[str, float] = {}
        self.count: dict[str, int] = {}

    def add(self, stage: str, wall_s: float, cpu_s: float = math.nan, n: int = 1) -> None:
        """Add ``wall_s`` / ``cpu_s`` seconds (NaN: not measured) of ``n`` runs of ``stage``."""
        _check(stage)
        with self._lock:
            self.wall_s[stage] = self.wall_s.get(stage, 0.0) + float(wall_s)
            if not math.isnan(cpu_s):
                self.cpu_s[stage] = self.cpu_s.get(stage, 0.0) + float(cpu_s)
            self.count[stage] = self.count.get(stage, 0) + int(n)

    @contextmanager
    def time(self, stage: str) -> Iterator[None]:
        """Time the body as one run of ``stage`` (wall: perf_counter; CPU: this thread's)."""
        t0, c0 = time.perf_counter(), time.thread_time()
        try:
            yield
        finally:
            self.add(stage, time.perf_counter() - t0, time.thread_time() - c0)

    def merge(self, other: StageTimes | Mapping[str, Mapping[str, float]]) -> StageTimes:
        """Add ``other`` (a collector or its :meth:`as_dict`) into this one; returns self."""
        doc = other.as_dict() if isinstance(other, StageTimes) else other
        for stage, v in doc.items():
            self.add(stage, v.get("wall_s", 0.0), v.get("cpu_s", math.nan), int(v.get("count", 0)))
        return self

    def as_dict(self) -> dict[str, dict[str, float]]:
        """{stage: {wall_s, cpu_s (absent when not measured), count}} in table order (JSON-ready)."""
        out: dict[str, dict[str, float]] = {}
        for stage in sorted(self.wall_s, key=_order):
            d: dict[str, float] = {"wall_s": round(self.wall_s[stage], 6), "count": self.count.get(stage, 0)}
            if stage in self.cpu_s:
                d["cpu_s"] = round(self.cpu_s[stage], 6)
            out[stage] = d
        return out


def _order(stage: str) -> tuple[int, str]:
    return STAGES.index(stage.split(":", 1)[0]), stage


def _fmt(v: float) -> str:
    return "" if v is None or math.isnan(v) else f"{v:.2f}" if abs(v) < 100 else f"{v:.0f}"


def stage_rows(stages: Mapping[str, Mapping[str, float]], trajectory_s: float,
               wall_total_s: float | None = None) -> list[list[str]]:
    """The stage table: header + one row per stage present in ``stages`` (:meth:`StageTimes.as_dict`), in table
    order, then the benchmark's wall clock (``wall_total_s``) when given.

    Columns: stage, runs, seconds, CPU seconds, s per trajectory-minute, CPU s per trajectory-minute
    (``trajectory_s``: the duration of everything benchmarked, summed over trajectories; 0 leaves the per-minute
    columns empty)."""
    minutes = trajectory_s / 60.0
    rows = [["stage", "runs", "seconds", "CPU seconds", "s per trajectory-minute", "CPU s per trajectory-minute"]]

    def per_min(v: float) -> float:
        return v / minutes if minutes > 0 else math.nan

    for stage in sorted(stages, key=_order):
        v = stages[stage]
        wall, cpu = float(v.get("wall_s", math.nan)), float(v.get("cpu_s", math.nan))
        rows.append([stage, str(int(v.get("count", 0))), _fmt(wall), _fmt(cpu), _fmt(per_min(wall)),
                     _fmt(per_min(cpu))])
    if wall_total_s is not None:
        rows.append(["benchmark (wall clock)", "", _fmt(wall_total_s), "", _fmt(per_min(wall_total_s)), ""])
    return rows


def describe_machine() -> dict[str, object]:
    """The machine the stages were measured on: CPU model, logical CPUs, load average (1, 5, 15 min), system."""
    model = platform.processor() or ""
    try:
        with open("/proc/cpuinfo") as fh:
            model = next((ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), model)
    except OSError:
        pass
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = []
    return {"cpu": model or "unknown", "cpus": os.cpu_count() or 1, "load_average": load,
            "system": f"{platform.system()} {platform.release()}", "python": platform.python_version()}


def machine_line(machine: Mapping[str, object]) -> str:
    """One line naming the machine of :func:`describe_machine`."""
    load = machine.get("load_average") or []
    load_text = (f", load average {' / '.join(str(x) for x in load)} (1/5/15 min)"  # type: ignore[attr-defined]
                 if load else "")
    return f"{machine.get('cpu')}, {machine.get('cpus')} logical CPUs, {machine.get('system')}{load_text}"
