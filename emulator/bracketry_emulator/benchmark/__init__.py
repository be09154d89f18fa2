"""Benchmark orchestration: per (trajectory, method) closed loop -> VO -> metrics, cached; local or Dask."""

from bracketry_emulator.benchmark.orchestrate import BenchmarkResult, parse_methods, run_benchmark
from bracketry_emulator.benchmark.tasks import make_task, run_task

__all__ = ["BenchmarkResult", "make_task", "parse_methods", "run_benchmark", "run_task"]
