"""The suite's gait against the real backpack: turn per bracket cycle and its change, real IMU beside synthetic walks.

Usage:
    .venv/bin/python benchmarks/bench_gait_imu.py [--imu IMU_CSV] [GROUNDTRUTH_OR_SUITE ...]

IMU_CSV: a BorealHDR ``imu/imu.csv`` (default: the real sample's, found as the tests find it:
``$BRACKETRY_SAMPLE_DATA`` or ``../shared/data/borealhdr_sample``). Each further argument is a synthetic walk's
``groundtruth.txt`` (TUM), a trajectory folder holding one, or a suite folder (every ``*/*/groundtruth.txt`` under
it). Prints, per source, the median and 90th percentile of the camera's turn over one bracket cycle (0.27 s) and of
its change from the previous cycle's turn (degrees; :mod:`bracketry_emulator.metrics.cycle_rotation`), as
emulator/DATASET.md's gait table gives them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from bracketry_base import paths
from bracketry_base.errors import BracketryError
from bracketry_emulator.metrics.cycle_rotation import (
    cycle_turns_from_gyro,
    cycle_turns_from_poses,
    turn_and_change_deg,
)
from bracketry_emulator.trajectory_io import read_tum


def imu_turns(path: Path) -> np.ndarray:
    """Cycle rotation vectors (rad) of a BorealHDR ``imu.csv`` (timestamp ns, ros_time, gyro_x/y/z rad/s, ...)."""
    x = np.loadtxt(path, delimiter=",", skiprows=1, usecols=(0, 2, 3, 4))
    return cycle_turns_from_gyro((x[:, 0] - x[0, 0]) * 1e-9, x[:, 1:4])


def groundtruth_turns(path: Path) -> np.ndarray:
    """Cycle rotation vectors (rad) of a TUM ``groundtruth.txt``."""
    return cycle_turns_from_poses(*read_tum(path))


def row(name: str, turns: np.ndarray) -> str:
    turn, change = turn_and_change_deg(turns)
    return (f"| {name} | {len(turn)} | {np.median(turn):.2f} ({np.percentile(turn, 90):.2f}) | "
            f"{np.median(change):.2f} ({np.percentile(change, 90):.2f}) |")


def groundtruth_files(arg: Path) -> list[Path]:
    if arg.is_file():
        return [arg]
    if (arg / "groundtruth.txt").is_file():
        return [arg / "groundtruth.txt"]
    return sorted(arg.glob("*/*/groundtruth.txt"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--imu", type=Path, default=None, help="a BorealHDR imu/imu.csv (default: the real sample's)")
    ap.add_argument("walks", type=Path, nargs="*", help="groundtruth.txt files, trajectory or suite folders")
    args = ap.parse_args()
    imu = args.imu
    if imu is None:
        sample = paths.sample_data_dir()
        found = sorted(sample.glob("*/imu/imu.csv")) if sample is not None else []
        if not found:
            sys.exit("no --imu given and no real sample found ($BRACKETRY_SAMPLE_DATA or ../shared/data)")
        imu = found[0]
    if not imu.is_file():
        sys.exit(f"--imu {imu}: no such file")
    walks = []
    for arg in args.walks:  # every argument checked before anything is printed
        files = groundtruth_files(arg)
        if not files:
            sys.exit(f"{arg}: no groundtruth.txt there")
        walks.extend(files)
    try:
        lines = [row(f"real IMU {imu.parent.parent.name}", imu_turns(imu))]
        for f in walks:
            lines.append(row(f"{f.parent.parent.name}/{f.parent.name}", groundtruth_turns(f)))
    except (BracketryError, OSError, ValueError, IndexError) as exc:
        sys.exit(f"cannot read the motion: {exc}")
    print("| source | cycles | turn over one cycle, deg: median (90th pct) | change from the previous cycle |")
    print("|---|---|---|---|")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
