"""The exposure-versus-time plot of every method of a run (the authors' exposure_times.png), headless."""

from __future__ import annotations

from pathlib import Path


def plot_exposures(series: dict[str, tuple[list[float], list[float]]], path: Path) -> Path:
    """Plot ``{method: (t_s, exposure_ms)}`` as one line per method, log exposure axis; write a PNG at ``path``."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 4.5), dpi=100)
    ax = fig.add_subplot(1, 1, 1)
    for name, (t_s, exp_ms) in series.items():
        ax.plot(t_s, exp_ms, marker="o", markersize=3, linewidth=1.2, label=name)
    ax.set_xlabel("time since the first frame (s)")
    ax.set_ylabel("exposure time (ms)")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="best", fontsize=8, ncol=2)
    # a fixed title position (y given): matplotlib's automatic one measures every tick label first (~40 % of a draw)
    ax.set_title("Exposure chosen by each AE method", y=1.0)
    fig.subplots_adjust(left=0.09, right=0.98, bottom=0.12, top=0.93)  # fixed margins: tight_layout costs ~0.3 s
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(str(path))
    return path
