"""Dataset manifests: the trajectories of a benchmark and the subset (deployment) each belongs to.

A manifest is a YAML (or JSON) file::

    trajectories:
      - path: forest/backpack_2023-09-25-15-05-03   # relative to the manifest's folder
        subset: Forest
        name: forest_01                               # optional, default: the folder name
      - path: campus/run2
        subset: Campus2
        groundtruth: campus/run2_gt.txt               # optional, default: <path>/groundtruth.txt
        calibration: campus/calibration               # optional, default: <path>/calibration or ../calibration
        runs: campus/emulated_run2                    # optional: already emulated runs (<runs>/<method>/...)
        split: test                                   # optional: train | test (for learning methods), default test
        warmup_steps: 12                              # optional: overrides the manifest's own (below)
        windows_m: [1, 2, 3]                          # optional: overrides the manifest's own (below)
    warmup_steps: 12    # optional: closed-loop steps each method takes on a trajectory's first view before it
    windows_m: [1, 2, 3]  # optional: RTE/RRE windows (m) for walks shorter than the paper's 5-50 m

``warmup_steps`` (top level, or per entry): the walks begin with a camera already running (short walks cut from a
longer recording); ``bracketry benchmark --warmup-steps N`` overrides it. ``windows_m`` (top level, or per entry):
the relative-error windows of trajectories too short for the default ones; ``bracketry benchmark --windows``
overrides it.

A dataset path that is a folder (not a manifest) is one trajectory of subset ``all``. A folder that already holds
emulated runs (``<folder>/<method>/images_left/``) is used as they are (no closed loop is run for those methods).
"""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import yaml

from bracketry_base.errors import BracketryError
from bracketry_emulator.defaults import MAX_WARMUP_STEPS

#: The splits a manifest entry may name (``split:``): trajectories to train learning methods on, and held-out ones.
SPLITS = ("train", "test")


@dataclass(frozen=True)
class TrajectorySpec:
    """One trajectory: unique ``name``, dataset ``path``, ``subset`` label, optional explicit file locations."""

    name: str
    path: Path
    subset: str = "all"
    groundtruth: Path | None = None
    calibration: Path | None = None
    runs: Path | None = None
    split: str = "test"
    #: closed-loop steps on the first view before the trajectory (None: not declared)
    warmup_steps: int | None = None
    #: RTE/RRE windows in metres (None: not declared)
    windows_m: tuple[float, ...] | None = None
    #: the synth code digest of the rendered suite it belongs to (a manifest's ``suite.code``; None: not declared)
    suite_code: str | None = None

    def is_zip(self) -> bool:
        """True when the trajectory is a zip archive read in place (``dataset.ziptree``)."""
        return self.path.suffix.lower() == ".zip" and self.path.is_file()

    def side_files(self) -> Path:
        """The folder of the trajectory's own files (groundtruth.txt, reference.yaml, calibration/): the trajectory
        folder, or for a zip archive the folder its side files are copied to."""
        if self.is_zip():
            from bracketry_emulator.dataset.ziptree import side_files

            return side_files(self.path)
        return self.path

    def groundtruth_path(self) -> Path | None:
        """The TUM reference of this trajectory, or None when it has none."""
        cand = self.groundtruth or self.side_files() / "groundtruth.txt"
        return cand if cand.is_file() else None

    def calibration_dir(self) -> Path | None:
        """The folder with the left/right camera_info YAMLs."""
        if self.calibration is not None:
            return self.calibration
        if self.is_zip():
            from bracketry_emulator.dataset.ziptree import calibration_dir, locate

            return calibration_dir(locate(self.path), self.side_files())
        for cand in (self.path / "calibration", self.path.parent / "calibration"):
            if cand.is_dir():
                return cand
        return None

    def existing_run(self, method: str) -> Path | None:
        """An already emulated run of ``method`` for this trajectory, if any."""
        for root in (self.runs, self.path):
            if root is not None and (root / method / "images_left").is_dir():
                return root / method
        return None


def load_manifest(path: str | Path) -> list[TrajectorySpec]:
    """Read a manifest file into trajectory specs (paths resolved against the manifest's folder)."""
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text())
        if not isinstance(doc, dict) or not isinstance(doc.get("trajectories"), list) or not doc["trajectories"]:
            raise BracketryError(f"bad dataset manifest {p}: expected a mapping with a non-empty list "
                                 "'trajectories:' of entries")
        entries = doc["trajectories"]
        default_warmup = _warmup(doc.get("warmup_steps"), p, "warmup_steps")
        default_windows = _windows(doc.get("windows_m"), p, "windows_m")
        suite = doc.get("suite")
        suite_code = str(suite["code"]) if isinstance(suite, dict) and suite.get("code") is not None else None
        out = []
        for k, e in enumerate(entries):
            if not isinstance(e, dict) or not isinstance(e.get("path"), str):
                raise BracketryError(f"bad dataset manifest {p}: trajectories[{k}] must be a mapping with a "
                                     f"'path:' string (got {e!r:.60})")
            tp = (p.parent / e["path"]).resolve()
            extra = {k: (p.parent / e[k]).resolve() for k in ("groundtruth", "calibration", "runs") if e.get(k)}
            split = str(e.get("split", "test"))
            if split not in SPLITS:
                raise BracketryError(f"bad dataset manifest {p}: trajectories[{k}].split is {split!r}; "
                                     f"expected one of {', '.join(SPLITS)}")
            warmup = _warmup(e.get("warmup_steps"), p, f"trajectories[{k}].warmup_steps")
            windows = _windows(e.get("windows_m"), p, f"trajectories[{k}].windows_m")
            out.append(TrajectorySpec(str(e.get("name") or tp.name), tp, str(e.get("subset", "all")), **extra,
                                      split=split, warmup_steps=default_warmup if warmup is None else warmup,
                                      windows_m=windows or default_windows, suite_code=suite_code))
    except (OSError, KeyError, TypeError, yaml.YAMLError) as exc:
        raise BracketryError(f"bad dataset manifest {p}: {exc}") from exc
    return out


def _warmup(value: object, path: Path, where: str) -> int | None:
    """A manifest's ``warmup_steps`` value (None when absent); one line on anything but a whole number
    0..:data:`~bracketry_emulator.defaults.MAX_WARMUP_STEPS`."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_WARMUP_STEPS:
        raise BracketryError(f"bad dataset manifest {path}: {where} must be a whole number of steps from 0 to "
                             f"{MAX_WARMUP_STEPS} "
                             f"(got {value!r:.40})")
    return value


def _windows(value: object, path: Path, where: str) -> tuple[float, ...] | None:
    """A manifest's ``windows_m`` (None when absent); one line on anything but a non-empty list of positive
    lengths in metres."""
    if value is None:
        return None
    if not isinstance(value, list) or not value or not all(
            isinstance(w, (int, float)) and not isinstance(w, bool) and 0 < w < 1e6 for w in value):
        raise BracketryError(f"bad dataset manifest {path}: {where} must be a non-empty list of window lengths in "
                             f"metres, each > 0 (got {value!r:.40})")
    return tuple(sorted({float(w) for w in value}))


def expand_datasets(paths: list[str | Path]) -> list[TrajectorySpec]:
    """Trajectory specs of command-line dataset arguments (folders or manifest files); names made unique."""
    specs: list[TrajectorySpec] = []
    for raw in paths:
        p = Path(raw)
        if p.is_file() and p.suffix.lower() in (".yaml", ".yml", ".json"):
            specs.extend(load_manifest(p))
        elif p.is_dir():
            specs.append(TrajectorySpec(p.resolve().name, p.resolve(), "all"))
        elif p.is_file() and p.suffix.lower() == ".zip":
            from bracketry_emulator.dataset.ziptree import locate

            specs.append(TrajectorySpec(locate(p).name, p.resolve(), "all"))
        else:
            raise BracketryError(f"dataset not found (need a folder, a trajectory .zip or a manifest .yaml): {p}")
    seen: dict[str, int] = defaultdict(int)
    unique = []
    for s in specs:
        seen[s.name] += 1
        name = s.name if seen[s.name] == 1 else f"{s.name}_{seen[s.name]}"
        unique.append(dataclasses.replace(s, name=name))
    return unique


def success_counts(rows: list[dict]) -> dict[str, dict[str, tuple[int, int]]]:
    """{subset: {method: (successful trajectories, trajectories)}} from rows with subset, method, success.

    A ``Total`` subset sums all rows.
    """
    out: dict[str, dict[str, list[int]]] = defaultdict(lambda: defaultdict(lambda: [0, 0]))
    for r in rows:
        for subset in (r["subset"], "Total"):
            cell = out[subset][r["method"]]
            cell[0] += int(bool(r["success"]))
            cell[1] += 1
    return {s: {m: (c[0], c[1]) for m, c in d.items()} for s, d in out.items()}
