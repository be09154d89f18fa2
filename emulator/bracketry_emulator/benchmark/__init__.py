"""Benchmark orchestration: per (trajectory, method) closed loop -> VO -> metrics, cached; local or Dask."""

from bracketry_emulator.benchmark.orchestrate import BenchmarkConfig, BenchmarkResult, run_benchmark
from bracketry_emulator.benchmark.slam import SlamOptions
from bracketry_emulator.benchmark.tasks import BenchmarkTask, RunResult, make_task, run_task

__all__ = ["BenchmarkConfig", "BenchmarkResult", "BenchmarkTask", "RunResult", "SlamOptions", "make_task",
           "run_benchmark", "run_task"]
