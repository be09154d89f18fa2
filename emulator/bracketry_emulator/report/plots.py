"""Matplotlib figures of the benchmark report (Agg backend, PNG files)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def box_plot(values: dict[str, list[float]], ylabel: str, title: str, path: Path, horizontal: bool = False) -> Path:
    """One box per method (methods with no value are shown empty). ``horizontal``: one box per row, the method names
    on the left (long plug-in names stay readable; the figure grows with the number of methods)."""
    plt = _plt()
    names = list(values)
    if horizontal:
        fig, ax = plt.subplots(figsize=(6.0, 0.32 * len(values) + 1.1))
    else:
        fig, ax = plt.subplots(figsize=(max(4.0, 0.9 * len(values) + 1.5), 3.2))
    data = [np.asarray(values[n], float)[np.isfinite(np.asarray(values[n], float))] for n in names]
    boxes = [d if len(d) else [np.nan] for d in data]
    try:  # matplotlib >= 3.10
        ax.boxplot(boxes, showfliers=True, orientation="horizontal" if horizontal else "vertical")
    except TypeError:  # older: vert=
        ax.boxplot(boxes, showfliers=True, vert=not horizontal)
    if horizontal:
        ax.set_yticks(range(1, len(names) + 1), names, fontsize=8)
        ax.invert_yaxis()  # the first method on top, as in the tables
        ax.set_xlabel(ylabel)
        ax.grid(axis="x", alpha=0.3)
    else:
        ax.set_xticks(range(1, len(names) + 1), names, rotation=30, ha="right")
        ax.set_ylabel(ylabel)
        ax.grid(axis="y", alpha=0.3)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def read_exposure_trace(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """(t_s from the run start, target exposure ms) from a run's ``steps.csv`` (empty arrays when absent)."""
    p = run_dir / "steps.csv"
    if not p.is_file():
        return np.zeros(0), np.zeros(0)
    with p.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        return np.zeros(0), np.zeros(0)
    t = np.array([int(r["timestamp_ns"]) for r in rows], float)
    return (t - t[0]) * 1e-9, np.array([float(r["target_exposure_ms"]) for r in rows])


def exposure_traces(traces: dict[str, tuple[np.ndarray, np.ndarray]], title: str, path: Path) -> Path:
    """Exposure (ms, log scale) over time per method for one trajectory."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.0, 3.2))
    for name, (t, e) in traces.items():
        if len(t):
            ax.plot(t, e, label=name, lw=1.2)
    ax.set_yscale("log")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("exposure (ms)")
    ax.set_title(title)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def qualitative_grid(images: dict[str, np.ndarray], title: str, path: Path) -> Path:
    """The same frame (uint8 gray HxW) under each method, in a grid with the method names."""
    plt = _plt()
    n = max(len(images), 1)
    cols = min(n, 3)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.3 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, (name, img) in zip(axes.ravel(), images.items()):
        ax.imshow(img, cmap="gray", vmin=0, vmax=255)
        ax.set_title(name, fontsize=9)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
