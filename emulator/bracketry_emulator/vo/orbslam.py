"""The external-SLAM path: export an emulated run for ORB-SLAM2/3's stereo examples, import their trajectories.

Export layout (``out_dir``), what ``stereo_euroc`` of ORB-SLAM2 and ORB-SLAM3 reads::

    mav0/cam0/data/<t_ns>.png    left image, 8-bit gray, rectified to the common camera (see calibration.py)
    mav0/cam1/data/<t_ns>.png    right image of the same pair, saved under the LEFT timestamp
    times.txt                    one t_ns per line (the left timestamps)
    settings.yaml                OpenCV YAML in the legacy ORB-SLAM2 format (ORB-SLAM3 reads it too): Camera.*
                                 of the rectified camera, Camera.bf, ThDepth 35.0, the paper's ORBextractor.* values,
                                 and LEFT/RIGHT.{K,D,R,P} set to identity rectification (images are already
                                 rectified)
    run_orbslam.sh               the command lines (ORB-SLAM2: stereo_euroc VOC settings LEFT RIGHT times.txt)

Images are converted with :func:`~bracketry_emulator.features.demosaic.to_gray8` (RGGB demosaic, luma, / 16) and
rectified here (with the same row correction as :func:`~bracketry_emulator.vo.runner.run_vo`), so ORB-SLAM sees
exactly the pixels our VO sees.

Import: ``CameraTrajectory*.txt`` (TUM, seconds; one per map as the authors' fork writes them, or a single
``CameraTrajectory.txt``) are copied as our segments, and a ``frames.csv`` is derived from ``times.txt``: a frame whose
timestamp is in a segment is tracked (OK; the first of a segment INIT), any other frame is LOST. ORB-SLAM gives no
per-frame keypoints or map matches, so those columns are NaN unless the fork's per-frame CSVs are evaluated separately.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_emulator.features.orb import OrbSettings
from bracketry_emulator.trajectory_io import FRAME_FIELDS, read_segments, write_tum
from bracketry_emulator.vo.calibration import StereoRectifier
from bracketry_emulator.vo.runner import estimate_row_offset, list_side_images, read_gray8


def _mat(name: str, m: np.ndarray) -> str:
    rows, cols = m.shape
    data = ", ".join(f"{float(v):.10g}" for v in m.ravel())
    return f"{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [{data}]\n"


def orbslam_settings_yaml(rect: StereoRectifier, fps: float, orb: OrbSettings | None = None,
                          th_depth: float = 35.0) -> str:
    """ORB-SLAM2 stereo settings (legacy format) for already rectified images of ``rect``."""
    o = orb or OrbSettings()
    Kn = rect.K
    P_left = np.hstack([Kn, np.zeros((3, 1))])
    P_right = np.hstack([Kn, np.array([[-rect.bf], [0.0], [0.0]])])
    lines = [
        "%YAML:1.0", "", 'Camera.type: "PinHole"',
        f"Camera.fx: {rect.fx:.6f}", f"Camera.fy: {rect.fy:.6f}", f"Camera.cx: {rect.cx:.6f}",
        f"Camera.cy: {rect.cy:.6f}", "Camera.k1: 0.0", "Camera.k2: 0.0", "Camera.p1: 0.0", "Camera.p2: 0.0",
        f"Camera.width: {rect.width_px}", f"Camera.height: {rect.height_px}", f"Camera.fps: {fps:.4f}",
        f"Camera.bf: {rect.bf:.6f}", "Camera.RGB: 1", f"ThDepth: {float(th_depth):.1f}", "",
        f"ORBextractor.nFeatures: {o.n_features}", f"ORBextractor.scaleFactor: {o.scale_factor}",
        f"ORBextractor.nLevels: {o.n_levels}", f"ORBextractor.iniThFAST: {o.ini_th_fast}",
        f"ORBextractor.minThFAST: {o.min_th_fast}", "",
        "Viewer.KeyFrameSize: 0.05", "Viewer.KeyFrameLineWidth: 1", "Viewer.GraphLineWidth: 0.9",
        "Viewer.PointSize: 2", "Viewer.CameraSize: 0.08", "Viewer.CameraLineWidth: 3", "Viewer.ViewpointX: 0",
        "Viewer.ViewpointY: -0.7", "Viewer.ViewpointZ: -1.8", "Viewer.ViewpointF: 500", "",
    ]
    text = "\n".join(lines) + "\n"
    for side, P in (("LEFT", P_left), ("RIGHT", P_right)):
        text += f"{side}.height: {rect.height_px}\n{side}.width: {rect.width_px}\n"
        text += _mat(f"{side}.D", np.zeros((1, 5))) + _mat(f"{side}.K", Kn) + _mat(f"{side}.R", np.eye(3))
        text += _mat(f"{side}.P", P)
    return text


def export_orbslam(run_dir: str | Path, calibration_dir: str | Path, out_dir: str | Path,
                   bayer: bool = True) -> Path:
    """Write the ORB-SLAM stereo-example layout of an emulated run; returns ``out_dir``."""
    left = list_side_images(run_dir, "left")
    right = list_side_images(run_dir, "right")
    if not left or len(left) != len(right):
        raise BracketryError(f"{run_dir}: {len(left)} left and {len(right)} right images (need equal, > 0)")
    out = Path(out_dir)
    cam0, cam1 = out / "mav0" / "cam0" / "data", out / "mav0" / "cam1" / "data"
    cam0.mkdir(parents=True, exist_ok=True)
    cam1.mkdir(parents=True, exist_ok=True)
    rect: StereoRectifier | None = None
    for (t_ns, pl), (_tr, pr) in zip(left, right):
        gl, gr = read_gray8(pl, bayer), read_gray8(pr, bayer)
        if rect is None:
            rect = StereoRectifier.from_dir(calibration_dir, gl.shape[1], gl.shape[0])
            a, b, _n = estimate_row_offset(rect, gl, gr)  # same row correction as run_vo
            if abs(a) + abs(b) * rect.width_px / 2 > 0.5:
                rect.correct_rows(a, b)
        cv2.imwrite(str(cam0 / f"{t_ns}.png"), rect.rectify(gl, "left"))
        cv2.imwrite(str(cam1 / f"{t_ns}.png"), rect.rectify(gr, "right"))
    assert rect is not None
    times = [t for t, _ in left]
    (out / "times.txt").write_text("".join(f"{t}\n" for t in times))
    fps = (len(times) - 1) / ((times[-1] - times[0]) * 1e-9) if len(times) > 1 and times[-1] > times[0] else 1.0
    (out / "settings.yaml").write_text(orbslam_settings_yaml(rect, fps))
    (out / "run_orbslam.sh").write_text(
        "#!/bin/sh\n# ORB-SLAM2 (or ORB-SLAM3) stereo example; VOC = path to ORBvoc.txt\n"
        'cd "$(dirname "$0")"\n'
        '"${ORBSLAM_DIR:?set ORBSLAM_DIR}/Examples/Stereo/stereo_euroc" "${VOC:?set VOC}" settings.yaml '
        "mav0/cam0/data mav0/cam1/data times.txt\n")
    return out


def import_orbslam(trajectory_dir: str | Path, times_file: str | Path, out_dir: str | Path,
                   tolerance_s: float = 1e-3) -> Path:
    """Turn ORB-SLAM ``CameraTrajectory*.txt`` files into our VO output (segments + ``frames.csv``)."""
    segments = read_segments(trajectory_dir)
    if not segments:
        raise BracketryError(f"no CameraTrajectory*.txt in {trajectory_dir}")
    times_ns = [int(line.split()[0]) for line in Path(times_file).read_text().splitlines() if line.strip()]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("CameraTrajectory*.txt"):
        old.unlink()
    state = {t: ("LOST", -1) for t in times_ns}
    t_arr = np.array(times_ns, dtype=np.float64) * 1e-9
    for seg, (ts, poses) in enumerate(segments):
        write_tum(out / f"CameraTrajectory{seg}.txt", ts, poses)
        for k, t in enumerate(ts):
            i = int(np.argmin(np.abs(t_arr - t))) if len(t_arr) else -1
            if i >= 0 and abs(t_arr[i] - t) <= tolerance_s:
                state[times_ns[i]] = ("INIT" if k == 0 else "OK", seg)
    with (out / "frames.csv").open("w") as fh:
        fh.write(",".join(FRAME_FIELDS) + "\n")
        for t in times_ns:
            s, seg = state[t]
            reason = "" if s != "LOST" else "no pose in the ORB-SLAM trajectories"
            fh.write(f"{t},{s},{seg},nan,nan,nan,nan,nan,nan,{reason}\n")
    return out

