"""Which effect drives the disagreement of emulated and truth runs (``bracketry accuracy truth-causes``).

A truth run (:mod:`~bracketry_emulator.ae.truth`) differs from an emulated one by several effects at once: the
motion blur of the whole exposure, the frame's own instant (exposed from its trigger, not centred on its source
bracket), its own noise (not the source's, amplified), a long exposure (not the longest bracket amplified by gain).
Here each effect is switched off in the truth, one at a time (``camera_model.json``'s ``truth_effects`` in a copy of
every trajectory: the same data, linked, the same world), the truth benchmark run again, and each variant compared
with the emulated and the full truth results:

- ``gap_closed``: per metric, 1 - mean over methods |variant - emulated| / mean |truth - emulated| (method medians
  over trajectories): the share of the emulated-vs-truth difference that switching the effect off removes (1: all
  of it; 0: none; negative: the variant is further from the emulation);
- ``kendall_tau_emulated``: Kendall's tau of the methods' emulated medians and the variant's (beside the truth's own
  ``kendall_tau_emulated_truth``): the ranking agreement the emulator would reach if the truth lacked the effect;
- ``kendall_tau_truth``: the variant against the full truth (how much the effect reorders the truth itself).

The effect with the largest positive ``gap_closed`` of a metric is the one that drives that metric's disagreement
(``driver``; none when no variant comes closer to the emulation than the truth).
Written as ``truth_causes.json`` and ``truth_causes.md`` next to ``truth_agreement.*``.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import yaml

from bracketry_base.errors import BracketryError

from ..ae.truth import TRUTH_EFFECTS
from ..stats.mannwhitney import METRICS
from .truth_agreement import kendall_tau

#: what each effect's variant changes in the truth (report wording)
EFFECT_LABELS = {"blur": "no motion blur (render at mid-exposure)",
                 "noise": "noise-free",
                 "instant": "centred on the source bracket's instant",
                 "exposure": "beyond the longest bracket: longest bracket x gain"}


def variant_dataset(manifest: Path, effect: str, out: Path) -> Path:
    """A copy of the manifest's suite under ``out`` whose truth images lack ``effect``: every trajectory folder
    re-made with symbolic links to the original entries, ``camera_model.json`` copied with ``truth_effects:
    {effect: false}``; returns the new manifest's path. Raises BracketryError for an unknown effect or a trajectory
    without ``camera_model.json``."""
    if effect not in TRUTH_EFFECTS:
        raise BracketryError(f"unknown effect {effect!r} (choose from {', '.join(TRUTH_EFFECTS)})")
    doc = yaml.safe_load(manifest.read_text())
    if not isinstance(doc, dict) or not isinstance(doc.get("trajectories"), list):
        raise BracketryError(f"{manifest}: not a manifest with trajectories")
    entries = []
    for e in doc["trajectories"]:
        src = (manifest.parent / e["path"]).resolve()
        cm = src / "camera_model.json"
        if not cm.is_file():
            raise BracketryError(f"{src}: not a synthetic trajectory (no camera_model.json)")
        dst = out / e["path"]
        dst.mkdir(parents=True, exist_ok=True)
        for item in src.iterdir():
            link = dst / item.name
            if item.name == "camera_model.json" or link.is_symlink() or link.exists():
                continue
            os.symlink(item, link)
        info = json.loads(cm.read_text())
        info["truth_effects"] = {effect: False}
        (dst / "camera_model.json").write_text(json.dumps(info, indent=1) + "\n")
        ent = dict(e)
        for key in ("groundtruth", "calibration", "runs"):  # explicit locations: the originals
            if ent.get(key):
                ent[key] = str((manifest.parent / ent[key]).resolve())
        entries.append(ent)
    doc["trajectories"] = entries
    out.mkdir(parents=True, exist_ok=True)
    path = out / "manifest.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _medians(results: list[dict], methods: Sequence[str]) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    for key in METRICS:
        out[key] = {}
        for m in methods:
            vals = [float(r[key]) for r in results if r.get("method") == m and key in r and r[key] is not None]
            vals = [v for v in vals if math.isfinite(v)]
            out[key][m] = float(np.median(vals)) if vals else float("nan")
    return out


def _mean_abs(a: dict[str, float], b: dict[str, float], methods: Sequence[str]) -> float:
    d = [abs(a[m] - b[m]) for m in methods if math.isfinite(a[m]) and math.isfinite(b[m])]
    return float(np.mean(d)) if d else float("nan")


def truth_causes(emulated: list[dict], truth: list[dict], variants: dict[str, list[dict]],
                 methods: Sequence[str]) -> dict:
    """The figures of the module docstring from the results rows of the emulated run, the truth run and each
    effect's variant (``{effect: rows}``)."""
    methods = list(methods)
    me, mt = _medians(emulated, methods), _medians(truth, methods)
    mv = {eff: _medians(rows, methods) for eff, rows in variants.items()}
    per_metric: dict[str, dict] = {}
    for key, (label, _higher) in METRICS.items():
        gap = _mean_abs(mt[key], me[key], methods)
        order = list(methods)
        effects: dict[str, dict] = {}
        for eff, med in mv.items():
            closer = _mean_abs(med[key], me[key], methods)
            effects[eff] = {
                "gap_closed": 1.0 - closer / gap if gap > 0 and math.isfinite(closer) else float("nan"),
                "mean_abs_diff_emulated": closer,
                "kendall_tau_emulated": kendall_tau([me[key][m] for m in order], [med[key][m] for m in order]),
                "kendall_tau_truth": kendall_tau([mt[key][m] for m in order], [med[key][m] for m in order]),
                "methods": {m: med[key][m] for m in order}}
        ranked = sorted((e for e in effects if effects[e]["gap_closed"] > 0),  # NaN and <= 0: no driver
                        key=lambda e: -effects[e]["gap_closed"])
        per_metric[key] = {"label": label, "mean_abs_diff_emulated_truth": gap,
                           "kendall_tau_emulated_truth": kendall_tau([me[key][m] for m in order],
                                                                     [mt[key][m] for m in order]),
                           "emulated": {m: me[key][m] for m in order}, "truth": {m: mt[key][m] for m in order},
                           "effects": effects, "driver": ranked[0] if ranked else None}
    return {"methods": methods, "effects": {e: EFFECT_LABELS[e] for e in variants}, "metrics": per_metric}


def _f(x: float | None, digits: int = 2) -> str:
    return "–" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def causes_markdown(doc: dict) -> list[str]:
    """The report's lines (a Markdown section)."""
    effs = list(doc["effects"])
    lines = ["## Which effect drives the disagreement (truth with one effect switched off)", "",
             "Effects: " + "; ".join(f"`{e}`: {lab}" for e, lab in doc["effects"].items()) + ".", "",
             "gap closed = 1 - mean |variant - emulated| / mean |truth - emulated| over the methods' medians "
             "(1: the effect explains the whole difference); tau = Kendall's tau over methods.", "",
             "| metric | tau emulated-truth | " + " | ".join(f"{e}: gap closed / tau emulated / tau truth"
                                                           for e in effs) + " | driver |",
             "|---|---|" + "---|" * len(effs) + "---|"]
    for m in doc["metrics"].values():
        cells = [f"{_f(m['effects'][e]['gap_closed'])} / {_f(m['effects'][e]['kendall_tau_emulated'])} / "
                 f"{_f(m['effects'][e]['kendall_tau_truth'])}" for e in effs]
        lines.append(f"| {m['label']} | {_f(m['kendall_tau_emulated_truth'])} | " + " | ".join(cells) +
                     f" | {m['driver'] or '–'} |")
    return lines


def write_truth_causes(doc: dict, report_dir: Path) -> tuple[Path, Path]:
    """``truth_causes.json`` and ``.md`` in ``report_dir``; the section is also appended to ``truth_agreement.md``
    there (replacing an earlier one). Returns the two paths."""
    report_dir.mkdir(parents=True, exist_ok=True)
    jpath = report_dir / "truth_causes.json"
    jpath.write_text(json.dumps(doc, indent=1) + "\n")
    lines = causes_markdown(doc)
    mpath = report_dir / "truth_causes.md"
    mpath.write_text("\n".join(lines) + "\n")
    agreement = report_dir / "truth_agreement.md"
    if agreement.is_file():
        text = agreement.read_text()
        head = lines[0]
        if head in text:
            text = text[:text.index(head)].rstrip("\n") + "\n"
        agreement.write_text(text + "\n" + "\n".join(lines) + "\n")
    return jpath, mpath
