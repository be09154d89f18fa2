"""Writers of synthetic datasets: the bracketed walk (BorealHDR tree + ground truth) and the static protocol.

Trajectory output (``write_trajectory``)::

    DIR/camera_left|camera_right/<exposure_ms>/<timestamp_ns>.png   16-bit PNG, raw RGGB 12-bit codes
    DIR/groundtruth.txt      TUM: t_s tx ty tz qx qy qz qw of the left camera at each frame's timestamp
                             (its mid-exposure instant), one line per frame
    DIR/calibration/         left.yaml, right.yaml (ROS camera_info), calib_kitti.txt, pcalib.txt (TUM response)
    DIR/camera_model.json    camera model + world + timing parameters

Frame timing (both cameras triggered together, so a stereo pair shares its timestamp): frame k is triggered at
t_s = start_s + k / fps (22 fps: brackets 45.5 ms apart; the real sample's are 45.7 ms apart on average, its cycle of
six 274 ms) with exposure E = brackets[k % n], and exposed over [t_s, t_s + E]: with motion blur (the
World's default) the scene is integrated over that interval, else rendered at its middle. Its timestamp (file name
and ``groundtruth.txt``) is the mid-exposure instant, t0_ns + round((k / fps + E / 2) * 1e9), the instant the real
rig stamps (``FrameMeta.mid_exposure_host_ns``; VersaVIS stamps BorealHDR images so), and its ground-truth pose is
the camera's pose at that instant: one ground-truth line per frame, each bracket of a cycle at its own instant.

Static protocol output (``write_static``), one camera at one fixed pose::

    DIR/static.json                 index of everything below
    DIR/sweep/<i:04d>.png           N exposures log-spaced in [min_us, max_us] (sweep/exposures.csv: i, exposure_us)
    DIR/repeats/<exposure_us>/<k:02d>.png    25 frames per repeat exposure (independent noise)
    DIR/camera_left/<exposure_ms>/<timestamp_ns>.png   the bracket set (one complete sequence, BorealHDR tree)
    DIR/truth/sweep/<i:04d>.png     exact noise-free image of every sweep exposure (same for repeats/ brackets:
                                    truth/exposure_<exposure_us>.png)
    DIR/truth/rate_e_per_us.npy     float32 (H, W): exact expected photo-electrons per microsecond of each pixel
    DIR/truth/radiance.npy          float32 (H, W): scene radiance in the channel of each pixel
    DIR/calibration/, DIR/camera_model.json as above
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_emulator.synth.calibration import write_calibration
from bracketry_emulator.synth.trajectory import mat_mul, quat_from_matrix
from bracketry_emulator.synth.world import World

#: Default first timestamp (ns since the Unix epoch) of synthetic recordings: 2023-11-14 22:13:20 UTC.
DEFAULT_T0_NS = 1_700_000_000_000_000_000
DEFAULT_BRACKETS_MS = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
_PNG = [cv2.IMWRITE_PNG_COMPRESSION, 1]

Progress = Callable[[int, int], None]


def exposure_dir_name(exposure_us: float) -> str:
    """BorealHDR folder name of an exposure: milliseconds as a float ("1.0", "0.5", "32.0")."""
    return str(float(exposure_us) / 1000.0)


def write_png(path: Path, image: np.ndarray) -> None:
    """Write a uint16 image as a 16-bit single-channel PNG (raises BracketryError on failure)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), np.ascontiguousarray(image, dtype=np.uint16), _PNG):
        raise BracketryError(f"cannot write {path}")


def _radiance_range_db(world: World, t_s: float) -> float:
    rad = world.radiance("left", t_s).radiance
    positive = rad[rad > 0]
    if positive.size == 0:
        return 0.0
    return float(20.0 * np.log10(positive.max() / positive.min()))


def write_common(world: World, out_dir: Path, extra: dict) -> None:
    """``calibration/`` and ``camera_model.json``."""
    calib_dir = out_dir / "calibration"
    write_calibration(world.calibration, calib_dir)
    world.camera.write_pcalib(calib_dir / "pcalib.txt")
    info = {"world": world.describe()}
    info.update(extra)
    world.camera.write_json(out_dir / "camera_model.json", info)


def relative_pose(T0: np.ndarray, T: np.ndarray) -> np.ndarray:
    """inv(T0) @ T of rigid 4x4 poses (rotation transposed, no LAPACK or BLAS: the same bits on every CPU)."""
    R0t = np.ascontiguousarray(T0[:3, :3].T)
    out = np.eye(4)
    out[:3, :3] = mat_mul(R0t, T[:3, :3])
    out[:3, 3] = mat_mul(R0t, T[:3, 3] - T0[:3, 3])
    return out


def tum_line(t_ns: int, T: np.ndarray) -> str:
    """One TUM trajectory line of a 4x4 camera-to-frame pose at ``t_ns`` (seconds written exactly from the ns)."""
    q = quat_from_matrix(T[:3, :3])
    tx, ty, tz = T[:3, 3]
    stamp = f"{t_ns // 1_000_000_000}.{t_ns % 1_000_000_000:09d}"
    return " ".join([stamp, *(f"{x:.9f}" for x in (tx, ty, tz, *q))])


def write_trajectory(world: World, out_dir: Path, seconds: float = 10.0,
                     brackets_ms: Sequence[float] = DEFAULT_BRACKETS_MS, fps: float = 22.0,
                     t0_ns: int = DEFAULT_T0_NS, sides: Sequence[str] = ("left", "right"),
                     start_s: float = 0.0, progress: Progress | None = None) -> dict:
    """Render the bracketed walk: every frame of the cycle at its own time. Returns a summary dict.

    The number of frames is rounded to whole bracket cycles (at least one). ``start_s`` shifts the walk
    (t_s of frame k = start_s + k / fps; timestamps stay t0_ns + k / fps)."""
    out_dir = Path(out_dir)
    if not brackets_ms or any(b <= 0 for b in brackets_ms):
        raise BracketryError("brackets must be positive exposure times in ms")
    if fps <= 0 or seconds <= 0:
        raise BracketryError("fps and seconds must be > 0")
    period_ms = 1000.0 / fps
    if max(brackets_ms) >= period_ms:
        raise BracketryError(f"bracket {max(brackets_ms)} ms does not fit in the frame period {period_ms:.1f} ms")
    n = len(brackets_ms)
    cycles = max(1, round(seconds * fps / n))
    n_frames = cycles * n
    out_dir.mkdir(parents=True, exist_ok=True)
    exposures_us = [float(b) * 1000.0 for b in brackets_ms]
    gt_lines = ["# bracketry synthetic ground truth (TUM): t_s tx ty tz qx qy qz qw",
                "# pose of the left camera (optical frame: x right, y down, z forward) in the left camera frame "
                "at the first trigger; one line per frame, at its timestamp = its mid-exposure instant"]
    total = n_frames * len(sides)
    done = 0
    for k in range(n_frames):
        t_s = start_s + k / fps  # trigger: the exposure is [t_s, t_s + exp_us]
        exp_us = exposures_us[k % n]
        mid_s = world.mid_exposure_s(t_s, exp_us)
        t_ns = t0_ns + round((k / fps + 0.5 * exp_us * 1e-6) * 1e9)
        for side in sides:
            img = world.render(side, t_s, exp_us, rng=world.frame_rng(side, t_s, exp_us))
            write_png(out_dir / f"camera_{side}" / exposure_dir_name(exp_us) / f"{t_ns}.png", img)
            done += 1
            if progress is not None:
                progress(done, total)
        T = world.pose(mid_s) if start_s == 0.0 else relative_pose(world.pose(start_s), world.pose(mid_s))
        gt_lines.append(tum_line(t_ns, T))
    (out_dir / "groundtruth.txt").write_text("\n".join(gt_lines) + "\n")
    summary = {"frames": n_frames, "cycles": cycles, "sides": list(sides), "fps": fps,
               "brackets_ms": [float(b) for b in brackets_ms], "t0_ns": t0_ns, "start_s": start_s,
               "duration_s": n_frames / fps,
               "timing": "frame k: triggered at k / fps, exposed over [k / fps, k / fps + E], E = brackets[k % n]; "
                         "t_ns = t0_ns + round((k / fps + E / 2) * 1e9) (mid-exposure), its pose at t_ns",
               "radiance_range_db": _radiance_range_db(world, start_s)}
    write_common(world, out_dir, {"dataset": "trajectory", "recording": summary})
    return summary


def log_exposures_us(n: int, min_us: float = 20.0, max_us: float = 50000.0) -> np.ndarray:
    """``n`` exposure times log-spaced in [min_us, max_us], float64."""
    if n < 2 or min_us <= 0 or max_us <= min_us:
        raise BracketryError("static sweep: need n >= 2 and 0 < min_us < max_us")
    return np.geomspace(min_us, max_us, n)


def write_static(world: World, out_dir: Path, n_exposures: int = 1000, min_us: float = 20.0,
                 max_us: float = 50000.0, repeats: int = 25,
                 repeat_exposures_ms: Sequence[float] = (0.1, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0),
                 brackets_ms: Sequence[float] = DEFAULT_BRACKETS_MS, side: str = "left", t_s: float = 0.0,
                 t0_ns: int = DEFAULT_T0_NS, progress: Progress | None = None) -> dict:
    """The emulator-validation protocol on one static view (``side`` at pose time ``t_s``). Returns the index."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    sweep_us = log_exposures_us(n_exposures, min_us, max_us)
    rate = world.rate_e_per_us(side, t_s)
    res = world.radiance(side, t_s)
    truth_dir = out_dir / "truth"
    truth_dir.mkdir(exist_ok=True)
    np.save(truth_dir / "rate_e_per_us.npy", rate.astype(np.float32))
    np.save(truth_dir / "radiance.npy", res.radiance.astype(np.float32))
    cam = world.camera
    total = n_exposures * 2 + repeats * len(repeat_exposures_ms) + len(brackets_ms) * 2 + len(repeat_exposures_ms)
    done = 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total)

    def noisy(exp_us: float, k: int) -> np.ndarray:
        rng = np.random.default_rng(np.random.SeedSequence([world.seed, 7, round(exp_us * 1000), k]))
        return cam.expose(rate, exp_us, rng)

    sweep_rows = []
    for i, exp_us in enumerate(sweep_us):
        name = f"{i:04d}.png"
        write_png(out_dir / "sweep" / name, noisy(float(exp_us), 0))
        tick()
        write_png(truth_dir / "sweep" / name, cam.noise_free_codes(rate, float(exp_us)))
        tick()
        sweep_rows.append((i, float(exp_us), f"sweep/{name}", f"truth/sweep/{name}"))
    with (out_dir / "sweep" / "exposures.csv").open("w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["index", "exposure_us", "file", "truth_file"])
        for row in sweep_rows:
            wr.writerow([row[0], f"{row[1]:.6f}", row[2], row[3]])
    repeat_index: dict[str, list[str]] = {}
    truth_index: dict[str, str] = {}
    for exp_ms in repeat_exposures_ms:
        exp_us = float(exp_ms) * 1000.0
        key = f"{exp_us:g}"
        files = []
        for k in range(repeats):
            rel = f"repeats/{key}/{k:02d}.png"
            write_png(out_dir / rel, noisy(exp_us, k + 1))
            files.append(rel)
            tick()
        repeat_index[key] = files
        rel_t = f"truth/exposure_{key}.png"
        write_png(out_dir / rel_t, cam.noise_free_codes(rate, exp_us))
        truth_index[key] = rel_t
        tick()
    bracket_index: dict[str, str] = {}
    for j, exp_ms in enumerate(brackets_ms):
        exp_us = float(exp_ms) * 1000.0
        t_ns = t0_ns + round(j * 1e9 / 22.0)
        rel = f"camera_{side}/{exposure_dir_name(exp_us)}/{t_ns}.png"
        write_png(out_dir / rel, noisy(exp_us, 1000 + j))
        bracket_index[f"{exp_us:g}"] = rel
        tick()
        rel_t = f"truth/exposure_{exp_us:g}.png"
        write_png(out_dir / rel_t, cam.noise_free_codes(rate, exp_us))
        truth_index[f"{exp_us:g}"] = rel_t
        tick()
    index = {
        "protocol": "static",
        "side": side,
        "t_s": t_s,
        "resolution": list(world.resolution),
        "sweep": {"n": n_exposures, "min_us": min_us, "max_us": max_us, "csv": "sweep/exposures.csv"},
        "repeats": {"n": repeats, "exposures_us": [float(e) * 1000.0 for e in repeat_exposures_ms],
                    "files": repeat_index},
        "brackets": {"exposures_us": [float(e) * 1000.0 for e in brackets_ms], "files": bracket_index},
        "truth": {"rate_e_per_us": "truth/rate_e_per_us.npy", "radiance": "truth/radiance.npy",
                  "images": truth_index, "sweep_dir": "truth/sweep",
                  "definition": "code = lut[clip(round(black_level_dn + min(rate*t_us, full_well_e)/gain_e_per_dn), "
                                "0, 4095)] (noise-free)"},
        "radiance_range_db": _radiance_range_db(world, t_s) if side == "left" else None,
    }
    (out_dir / "static.json").write_text(json.dumps(index, indent=2) + "\n")
    write_common(world, out_dir, {"dataset": "static", "static": {k: index[k] for k in ("side", "t_s", "sweep")}})
    return index
