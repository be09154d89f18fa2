"""Benchmark metrics: RTE/RRE through evo (paper equations), robustness, success counts, manifests."""

from bracketry_emulator.metrics.evaluate import evaluate_run
from bracketry_emulator.metrics.failures import Robustness, robustness
from bracketry_emulator.metrics.manifest import TrajectorySpec, expand_datasets, load_manifest, success_counts
from bracketry_emulator.metrics.rpe import DEFAULT_WINDOWS_M, WindowError, relative_errors, trajectory_rte_rre
from bracketry_emulator.trajectory_io import read_segments

__all__ = [
    "DEFAULT_WINDOWS_M",
    "Robustness",
    "TrajectorySpec",
    "WindowError",
    "evaluate_run",
    "expand_datasets",
    "load_manifest",
    "read_segments",
    "relative_errors",
    "robustness",
    "success_counts",
    "trajectory_rte_rre",
]
