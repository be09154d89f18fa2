"""The stereo calibration a recording carries (RECORDING.md, "Calibration"): a calibration folder as
``bracketry calibrate solve`` writes it, read into one MCAP Metadata record and written back out as a BorealHDR
tree's ``calibration/``.

Pure file and text handling (yaml only): the recorder writes the record at the start of every file, the exporter
writes the files, the reader finds the record in the first file that has it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from bracketry_base.errors import BracketryError

#: name of the MCAP Metadata record holding the calibration (keys: file names, values: the files' texts)
CALIBRATION_RECORD = "bracketry_calibration"
#: the files of a calibration folder a recording carries, when present (the first two are needed)
CALIBRATION_FILES = ("left.yaml", "right.yaml", "calib_kitti.txt", "orbslam3_stereo.yaml", "report.json")
REQUIRED_FILES = CALIBRATION_FILES[:2]
#: at most this many bytes a file (a calibration is a few KB; report.json grows with the views)
MAX_FILE_BYTES = 4 << 20


def _camera_info(text: str, where: str) -> dict[str, Any]:
    """The ROS camera_info fields of a YAML text: width, height, k (9), d, r (9), p (12), distortion_model."""
    try:
        doc = yaml.safe_load(text)
        info: dict[str, Any] = {"width": int(doc["image_width"]), "height": int(doc["image_height"]),
                "distortion_model": str(doc.get("distortion_model", "plumb_bob")),
                "k": [float(v) for v in doc["camera_matrix"]["data"]],
                "d": [float(v) for v in doc["distortion_coefficients"]["data"]],
                "r": [float(v) for v in doc.get("rectification_matrix", {"data": [1, 0, 0, 0, 1, 0, 0, 0, 1]})["data"]],
                "p": [float(v) for v in doc["projection_matrix"]["data"]]}
    except (KeyError, TypeError, ValueError, yaml.YAMLError) as exc:
        raise BracketryError(f"{where} is not a ROS camera_info YAML ({type(exc).__name__}: "
                             f"{' '.join(str(exc).split())[:120]})") from None
    if len(info["k"]) != 9 or len(info["r"]) != 9 or len(info["p"]) != 12:
        raise BracketryError(f"{where}: camera_matrix needs 9 numbers, rectification_matrix 9, projection_matrix 12")
    return info


def read_calibration(folder: str | Path) -> dict[str, str]:
    """The files of a calibration folder a recording carries: {file name: text}, in :data:`CALIBRATION_FILES`
    order; ``left.yaml`` and ``right.yaml`` must be there and be camera_info YAMLs (else one-line
    :class:`BracketryError`)."""
    d = Path(folder)
    if not d.is_dir():
        raise BracketryError(f"calibration folder {d} does not exist (a folder bracketry calibrate solve --out wrote)")
    files: dict[str, str] = {}
    for name in CALIBRATION_FILES:
        p = d / name
        if not p.is_file():
            if name in REQUIRED_FILES:
                raise BracketryError(f"calibration folder {d} has no {name} (bracketry calibrate solve writes "
                                     "left.yaml and right.yaml)")
            continue
        try:
            if p.stat().st_size > MAX_FILE_BYTES:
                raise BracketryError(f"{p} is larger than {MAX_FILE_BYTES >> 20} MB: not a calibration file")
            files[name] = p.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise BracketryError(f"cannot read {p}: {getattr(exc, 'strerror', None) or exc}") from None
    for name in REQUIRED_FILES:
        _camera_info(files[name], str(d / name))
    return files


def camera_infos(files: dict[str, str]) -> dict[str, dict[str, Any]]:
    """Per side ("left", "right") the camera_info fields of :func:`read_calibration`'s files (the per-frame
    CameraInfo messages' K, D, R, P and distortion model)."""
    return {side: _camera_info(files[f"{side}.yaml"], f"{side}.yaml") for side in ("left", "right")}


def recorded_calibration(metadata: dict[str, dict[str, str]]) -> dict[str, str] | None:
    """The calibration files of a recording's Metadata records (``ReadReport.metadata``), or None when it carries
    none."""
    record = metadata.get(CALIBRATION_RECORD)
    if not record or not all(name in record for name in REQUIRED_FILES):
        return None
    return {name: record[name] for name in CALIBRATION_FILES if name in record}


def write_calibration(files: dict[str, str], folder: str | Path) -> Path:
    """Write the files of a calibration (``{name: text}``) into ``folder`` (created); returns it."""
    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        if name not in CALIBRATION_FILES:
            continue  # only the known file names: a record never names a path
        try:
            (d / name).write_text(text, encoding="utf-8")
        except OSError as exc:
            raise BracketryError(f"cannot write {d / name}: {exc.strerror or exc}") from None
    return d
