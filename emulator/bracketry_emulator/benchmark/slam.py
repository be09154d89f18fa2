"""The benchmark's localisation step: which SLAM backend, its options, running it, and combining repeats.

Backends: ``orbslam3`` (default; ORB-SLAM3 stereo in a child process per run, see
:mod:`bracketry_emulator.slam.orbslam3`) and ``builtin`` (the OpenCV stereo VO of :mod:`bracketry_emulator.vo`,
fast and deterministic, for quick runs). Options are a :class:`SlamOptions` (frozen, picklable); its JSON form
(:meth:`SlamOptions.to_json`) goes to reports, its result-deciding part (:meth:`SlamOptions.key_json`) into every
cache key.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_emulator.defaults import DEFAULT_SLAM_PACE, SLAM_BACKENDS
from bracketry_emulator.option_table import default, rows

BACKENDS = SLAM_BACKENDS


@dataclass(frozen=True)
class SlamOptions:
    """The benchmark's SLAM options; defaults chosen from the measurements in ARCHITECTURE.md (lockstep feed, loop
    closing on).

    ``backend``: one of :data:`BACKENDS`. ``vocabulary``: DBoW2 text file (orbslam3; resolved before the runs, see
    :func:`resolve_options`). ``vocabulary_id``: ``<file name>:<sha256 prefix>`` of that file (the cache key follows
    its content). ``pace``: ``"lockstep"`` (each frame once ORB-SLAM3's mapping threads are idle: results that do not
    depend on the machine's load, :mod:`bracketry_emulator.slam.quiescence`), ``"realtime"`` (the recording's own
    timestamps) or seconds between fed frames (0 = unpaced). ``loop_closing``: ORB-SLAM3's loop-closing thread (off
    also turns relocalisation off). ``repeats``: runs
    per (trajectory, method); the report gives their median and spread.
    """

    backend: str = default("slam", "backend")
    vocabulary: str | None = None
    vocabulary_id: str | None = None
    pace: str | float = default("slam", "pace")
    loop_closing: bool = default("slam", "loop_closing")
    repeats: int = default("slam", "repeats")

    @classmethod
    def builtin(cls, repeats: int = 1) -> SlamOptions:
        """The built-in VO: not paced, no loop closing."""
        return cls(backend="builtin", pace=0.0, loop_closing=False, repeats=repeats)

    def to_json(self) -> dict[str, Any]:
        """Every option as a JSON object (the report's form)."""
        return asdict(self)

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> SlamOptions:
        """Options from :meth:`to_json`'s form; missing fields take their defaults."""
        return cls(**doc)

    def key_json(self) -> dict[str, Any]:
        """The options that decide a run's result (cache key): not the vocabulary's path but its content, and how
        ORB-SLAM3's extractor is sized (:data:`~bracketry_emulator.slam.settings.ORB_SIZING`) and what its settings file
        holds (:data:`~bracketry_emulator.slam.settings.SETTINGS_FORMAT`); the built-in VO has
        none of its own."""
        from bracketry_emulator.slam.settings import ORB_SIZING, SETTINGS_FORMAT

        if self.backend == "builtin":
            return {"backend": "builtin"}
        doc: dict[str, Any] = {"vocabulary_id": self.vocabulary_id, "orb_sizing": ORB_SIZING,
                               "settings_format": SETTINGS_FORMAT}
        for s in rows("slam"):  # the table's SLAM rows that decide results (key: always, or changed from default)
            v = getattr(self, s.target)
            if s.key == "always" or (s.key == "changed" and v != s.default_value):
                doc[s.target] = v
        return doc

    @property
    def pace_s(self) -> float | None:
        """Seconds between fed frames; None: real time; 0: unpaced (and lockstep: no wall-clock pace)."""
        if self.pace == "lockstep":
            return 0.0
        return None if self.pace == "realtime" else float(self.pace)

    @property
    def lockstep(self) -> bool:
        """ORB-SLAM3 fed in lockstep with its mapping threads."""
        return self.backend == "orbslam3" and self.pace == "lockstep"

    @property
    def paced(self) -> bool:
        """ORB-SLAM3 fed at a wall-clock pace (its runs mostly wait; a lockstep run mostly computes)."""
        return self.backend == "orbslam3" and self.pace not in (0.0, "lockstep")


#: the feeds that are words (the others are seconds between frames)
PACE_WORDS = ("lockstep", "realtime")


def parse_pace(text: str | float | None) -> str | float:
    """``lockstep``, ``realtime`` or a non-negative number of seconds -> the option value (None: the default,
    :data:`~bracketry_emulator.defaults.DEFAULT_SLAM_PACE`); anything else: one-line error."""
    if text is None:
        return DEFAULT_SLAM_PACE
    if text in PACE_WORDS:
        return str(text)
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise BracketryError(f"bad --slam-pace {text!r} (use 'lockstep', 'realtime' or seconds per frame, "
                             "e.g. 0.12)") from None
    if not np.isfinite(v) or v < 0:
        raise BracketryError(f"bad --slam-pace {text!r} (seconds per frame must be >= 0)")
    return v


def file_id(path: str | Path) -> str:
    """``name:sha256[:12]`` of a file (vocabularies are tens of MB: read in chunks)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return f"{Path(path).name}:{h.hexdigest()[:12]}"


def slam_options(backend: str = SLAM_BACKENDS[0], vocabulary: str | Path | None = None,
                 pace: str | float | None = None, loop_closing: bool = True, repeats: int = 1, echo=None,
                 resolve: bool = True, **more: Any) -> SlamOptions:
    """Checked, complete SLAM options; for ORB-SLAM3 the vocabulary is resolved (the default built once) unless
    ``resolve`` is False (then :func:`resolve_options` does it, e.g. after the rest of the input was checked).
    ``more``: the other :class:`SlamOptions` fields (the settings table's further SLAM rows)."""
    if backend not in BACKENDS:
        raise BracketryError(f"unknown SLAM backend {backend!r} (choose from {', '.join(BACKENDS)})")
    if int(repeats) < 1:
        raise BracketryError(f"--slam-repeats must be >= 1 (got {repeats})")
    pace = parse_pace(pace)
    if backend == "builtin":  # not paced, no loop closing
        return SlamOptions.builtin(int(repeats))
    opts = SlamOptions(backend, str(vocabulary) if vocabulary else None, None, pace, bool(loop_closing),
                       int(repeats), **more)
    return resolve_options(opts, echo) if resolve else opts


def resolve_options(opts: SlamOptions, echo=None) -> SlamOptions:
    """``opts`` with the ORB-SLAM3 vocabulary resolved to a file, checked (a bad one is one line, see
    :func:`~bracketry_emulator.slam.vocabulary_check.check_vocabulary`) and identified by its content. Options that
    already carry a ``vocabulary_id`` are returned as they are."""
    if opts.backend != "orbslam3" or opts.vocabulary_id:
        return opts
    from bracketry_emulator.slam.vocabulary_check import check_vocabulary
    from bracketry_emulator.slam.vocabulary_files import resolve_vocabulary

    voc = resolve_vocabulary(opts.vocabulary, echo=echo)
    check_vocabulary(voc)
    return replace(opts, vocabulary=str(voc), vocabulary_id=file_id(voc))


def describe(opts: SlamOptions | dict | None) -> str:
    """One line for the report: backend, its settings and the vocabulary (``opts``: the options or their JSON
    form; None: the built-in VO)."""
    o = opts if isinstance(opts, SlamOptions) else SlamOptions.from_json(opts) if opts else SlamOptions.builtin()
    if o.backend == "builtin":
        return "built-in stereo VO (OpenCV, ORB-SLAM2-like front end, 5-frame map, no relocalisation)"
    pace = ("in lockstep (each frame once local mapping and loop closing are idle)" if o.lockstep else
            "at real time" if o.pace_s is None else ("unpaced" if o.pace_s == 0 else f"at {o.pace_s:g} s per frame"))
    return (f"ORB-SLAM3 stereo (pyorbslam3), fed {pace}, loop closing {'on' if o.loop_closing else 'off'}, "
            f"ORB {orb_sizing_text()}, ThDepth 35, vocabulary {o.vocabulary_id}, "
            f"{o.repeats} repeat(s) per run")


def orb_sizing_text() -> str:
    """How ORB-SLAM3's extractor is sized (:data:`~bracketry_emulator.slam.settings.ORB_SIZING`), for the report."""
    from bracketry_emulator.slam.settings import ORB_SIZING, field_orb_settings

    if ORB_SIZING == "paper":
        return "3000 features / scale 1.2 / 13 levels / FAST 15-5 (the paper's)"
    big, small = field_orb_settings(640, 400), field_orb_settings(320, 200)
    return (f"sized for the paper's view ({big.n_features} features / {big.n_levels} levels at 640x400, "
            f"{small.n_features} / {small.n_levels} at 320x200; scale 1.2, FAST 15-5)")


def orbslam3_options(opts: SlamOptions) -> Any:
    """How the ORB-SLAM3 child runs with these options (:class:`~bracketry_emulator.slam.orbslam3.OrbSlam3Options`)."""
    from bracketry_emulator.slam.orbslam3 import OrbSlam3Options

    return OrbSlam3Options(str(opts.vocabulary), pace_s=opts.pace_s, lockstep=opts.lockstep,
                           loop_closing=opts.loop_closing)


def run_slam(opts: SlamOptions, run_dir: Path, calibration_dir: str, vo_dir: Path,
             max_frames: int | None) -> dict:
    """Localise one emulated run into ``vo_dir`` (frames.csv + CameraTrajectory<n>.txt); returns run facts."""
    if opts.backend == "builtin":
        import time

        from bracketry_emulator.vo.runner import run_vo

        t0 = time.perf_counter()
        vo = run_vo(run_dir, calibration_dir, vo_dir, max_frames=max_frames)
        return {"backend": "builtin", "s_per_frame": (time.perf_counter() - t0) / max(len(vo.frames), 1)}
    from bracketry_emulator.slam.orbslam3 import run_orbslam3

    info = run_orbslam3(run_dir, calibration_dir, vo_dir, orbslam3_options(opts), max_frames=max_frames)
    return {"backend": "orbslam3", "s_per_frame": info.get("track_s_median", float("nan")), **{
        k: info[k] for k in ("settings", "vocabulary_load_s", "raw_states", "wall_s", "cpu_s", "source") if k in info}}


#: metrics combined over repeats by their median
REPEAT_METRICS = ("rte_pct", "rre_deg_per_m", "tracked_fraction", "tracked_distance_fraction", "coverage_mean",
                  "matches_mean", "keypoints_mean", "time_before_failure_s", "n_failures", "n_segments",
                  "s_per_frame")


def combine_repeats(runs: list[dict]) -> dict:
    """One result per (trajectory, method) from its repeats: medians, spreads (max - min) and the runs' values.

    Failed repeats (``error``) are left out of the medians; with none left the result carries the first error.
    The per-frame lists and windows come from the repeat whose RTE is closest to the median; ``failure_runs`` lists
    ``{"repeat", "time_s", "cause"}`` of every repeat that lost track (:mod:`~.failure_analysis`). The oracle's
    ``oracle_source`` names the candidate of each repeat, in repeat order, ``/``-separated (:mod:`~.oracle_rows`).
    """
    sources = {"oracle_source": "/".join(str(r.get("oracle_source", "")) for r in runs)} \
        if any("oracle_source" in r for r in runs) else {}
    ok = [r for r in runs if not r.get("error")]
    if not ok:
        out = dict(runs[0])
        out.update(repeats=len(runs), repeats_ok=0, **sources)
        return out
    rte = np.array([r.get("rte_pct", np.nan) for r in ok], float)
    if np.isfinite(rte).any():
        med = float(np.nanmedian(rte))
        rep = ok[int(np.nanargmin(np.abs(np.where(np.isfinite(rte), rte, np.inf) - med)))]
    else:
        rep = ok[0]
    out = dict(rep)
    for k in REPEAT_METRICS:
        vals = np.array([float(r.get(k, np.nan)) for r in ok], float)
        fin = vals[np.isfinite(vals)]
        out[k] = float(np.median(fin)) if len(fin) else float("nan")
        if k in ("rte_pct", "rre_deg_per_m", "tracked_fraction", "tracked_distance_fraction"):
            out[f"{k}_runs"] = [float(v) for v in vals]
            out[f"{k}_spread"] = float(np.ptp(fin)) if len(fin) else float("nan")
    out["success"] = sum(bool(r["success"]) for r in ok) * 2 > len(ok)  # the majority of the repeats
    out["failure_runs"] = [{"repeat": int(r.get("repeat", 0)), "time_s": float(r["time_before_failure_s"]),
                            "cause": str(r["failure_cause"])} for r in ok if r.get("failure_cause")]
    out.update(repeats=len(runs), repeats_ok=len(ok), errors=[r["error"] for r in runs if r.get("error")], **sources)
    return out
