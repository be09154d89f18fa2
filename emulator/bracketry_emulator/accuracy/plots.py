"""Plots of the accuracy protocols (matplotlib, Agg backend, PNG)."""

from __future__ import annotations

from pathlib import Path

MODE_STYLE = {"highernosat": ("black", "-", 2.0), "upstream": ("0.5", ":", 1.5), "fusion": ("tab:red", "--", 2.0),
              "fusion-all": ("tab:purple", "-.", 1.5)}


def plot_static(result: dict, path: Path, metric: str = "corrected") -> Path:
    """RMSE vs target exposure: one thin curve per single bracket, thick curves per selection mode (the paper's
    figure, left panel), for ``metric`` ("corrected", "raw" or "truth"), plus a second panel with the other metric."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["targets"]
    x = [r["exposure_us"] / 1000.0 for r in rows]
    first = next(iter(rows[0]["modes"].values())) if rows else {}
    others = [m for m in ("truth", "raw") if m != metric and first.get(m) is not None]
    metrics = [metric, *others[:1]]
    fig, axes = plt.subplots(1, len(metrics), figsize=(6.5 * len(metrics), 4.5), squeeze=False)
    cmap = plt.get_cmap("viridis")
    brackets = result["brackets_us"]
    for ax, met in zip(axes[0], metrics, strict=False):
        for j, b in enumerate(brackets):
            y = [r["brackets"][str(b)][met] for r in rows]
            ax.plot(x, y, color=cmap(j / max(len(brackets) - 1, 1)), lw=0.8, alpha=0.8, label=f"from {b / 1000:g} ms")
        for mode in rows[0]["modes"] if rows else []:
            color, ls, lw = MODE_STYLE.get(mode, ("tab:blue", "-", 1.5))
            ax.plot(x, [r["modes"][mode][met] for r in rows], color=color, ls=ls, lw=lw, label=mode)
        for b in brackets:
            ax.axvline(b / 1000.0, color="0.85", lw=0.5, zorder=0)
        ax.set_xscale("log")
        ax.set_yscale("symlog", linthresh=10)
        ax.set_ylim(bottom=0)
        ax.set_xlabel("target exposure (ms)")
        ax.set_ylabel(f"RMSE (DN, {met})")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=7, ncol=2)
    fig.suptitle(f"static protocol: {result['n_targets']} targets, crf {result['crf']}")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_neighbours(result: dict, path: Path) -> Path:
    """Median RMSE and mean bias per selection mode, with and without alignment (bar charts)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summ = result["summary"]
    modes = list(next(iter(summ.values())).keys()) if summ else []
    aligns = list(summ)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    width = 0.8 / max(len(aligns), 1)
    for k, al in enumerate(aligns):
        xs = [i + k * width for i in range(len(modes))]
        axes[0].bar(xs, [summ[al][m]["rmse_dn"]["median"] for m in modes], width, label=al)
        axes[1].bar(xs, [summ[al][m]["bias_dn"]["median"] for m in modes], width, label=al)
    for ax, title in zip(axes, ("median RMSE (DN)", "median mean bias (DN)"), strict=True):
        ax.set_xticks([i + width * (len(aligns) - 1) / 2 for i in range(len(modes))], modes, rotation=20)
        ax.set_title(title)
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].legend()
    fig.suptitle(f"neighbour protocol: {result['n_pairs']} emulated frames")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
