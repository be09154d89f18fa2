"""Reference trajectories of real data: TUM, KITTI or EuRoC files in any sensor frame, moved to the left camera and
interpolated at the image times.

A trajectory folder may carry ``reference.yaml`` next to its images::

    file: gnss_ins.csv            # relative to the folder
    format: euroc                 # tum | kitti | euroc (default: from the file)
    times: poses_times.txt        # kitti only: one time per pose line (seconds, or ns when integers > 1e12);
                                  # without it, line k is the pose at the k-th left image (time order)
    extrinsic:                    # pose of the LEFT CAMERA in the reference's sensor frame (T_sensor_camera)
      matrix: [[...], [...], [...], [...]]      # a 4x4 matrix, or
      translation: [x, y, z]                    # translation (m) + quaternion (x, y, z, w)
      quaternion: [qx, qy, qz, qw]

Formats: TUM ``t_s tx ty tz qx qy qz qw`` (space-separated); KITTI 12 numbers per line (a 3x4 ``[R | t]``, no time:
``times`` gives them, else the trajectory's left images do, one pose per image in time order); EuRoC CSV
``t_ns, px, py, pz, qw, qx, qy, qz[, ...]`` (header lines start with ``#``). All
poses are sensor-to-world. The camera's pose is ``T_world_sensor(t) @ T_sensor_camera``, interpolated at each image
time: linear in translation, spherical-linear in rotation (SE(3) per component); image times outside the reference's
time span get no pose (and so no RTE pairs).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation, Slerp

from bracketry_base.errors import BracketryError

REFERENCE_FILE = "reference.yaml"
FORMATS = ("tum", "kitti", "euroc")


def extrinsic_matrix(spec: dict | list | None) -> np.ndarray:
    """4x4 float64 ``T_sensor_camera`` from ``{matrix: 4x4}`` or ``{translation, quaternion (x y z w)}``."""
    if spec is None:
        return np.eye(4)
    try:
        if isinstance(spec, dict) and "matrix" in spec:
            T = np.asarray(spec["matrix"], dtype=np.float64).reshape(4, 4)
        elif isinstance(spec, dict):
            T = np.eye(4)
            T[:3, 3] = np.asarray(spec.get("translation", [0, 0, 0]), dtype=np.float64).reshape(3)
            T[:3, :3] = Rotation.from_quat(np.asarray(spec.get("quaternion", [0, 0, 0, 1]), float)).as_matrix()
        else:
            T = np.asarray(spec, dtype=np.float64).reshape(4, 4)
    except (ValueError, TypeError) as exc:
        raise BracketryError(f"bad extrinsic {spec!r}: give a 4x4 matrix or translation + quaternion") from exc
    if not np.allclose(T[3], [0, 0, 0, 1]) or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6):
        raise BracketryError("bad extrinsic: not a rigid transform (rotation not orthonormal or last row not 0 0 0 1)")
    return T


def _rows(path: Path, sep: str | None) -> np.ndarray:
    rows = []
    for n, line in enumerate(path.read_text().splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#") or (sep == "," and not (s[0].isdigit() or s[0] in "-+.")):
            continue
        try:
            rows.append([float(x) for x in (s.split(sep) if sep else s.split())])
        except ValueError:
            raise BracketryError(f"{path}:{n}: not a number in {s[:60]!r}") from None
    if not rows:
        raise BracketryError(f"{path}: no poses")
    width = {len(r) for r in rows}
    if len(width) != 1:
        raise BracketryError(f"{path}: lines have different numbers of values {sorted(width)}")
    return np.array(rows)


def guess_format(path: Path) -> str:
    text = "\n".join(line for line in path.read_text().splitlines()[:5] if line.strip() and line[0] != "#")
    if "," in text:
        return "euroc"
    n = len(text.splitlines()[0].split()) if text else 0
    return {8: "tum", 12: "kitti"}.get(n, "tum")


def read_reference(path: str | Path, fmt: str | None = None, times: str | Path | None = None,
                   frame_times_s: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(times_s float64 N, poses float64 Nx4x4 sensor-to-world) of a TUM / KITTI / EuRoC file.

    KITTI poses carry no time: ``times`` (a file, one time per pose) gives them, else ``frame_times_s`` (float64 N,
    seconds: the trajectory's left image times in order, one per pose line)."""
    p = Path(path)
    if not p.is_file():
        raise BracketryError(f"reference file not found: {p}")
    f = fmt or guess_format(p)
    if f not in FORMATS:
        raise BracketryError(f"unknown reference format {f!r} (choose from {', '.join(FORMATS)})")
    if f == "euroc":
        d = _rows(p, ",")
        if d.shape[1] < 8:
            raise BracketryError(f"{p}: EuRoC lines need t_ns, px, py, pz, qw, qx, qy, qz")
        t = d[:, 0] * 1e-9
        xyz, quat = d[:, 1:4], d[:, [5, 6, 7, 4]]
    elif f == "tum":
        d = _rows(p, None)
        if d.shape[1] != 8:
            raise BracketryError(f"{p}: TUM lines need t tx ty tz qx qy qz qw")
        t, xyz, quat = d[:, 0], d[:, 1:4], d[:, 4:8]
    else:
        d = _rows(p, None)
        if d.shape[1] != 12:
            raise BracketryError(f"{p}: KITTI lines need 12 numbers (3x4 [R | t])")
        if times is not None:
            tv = _rows(Path(times), None)[:, 0]
            if len(tv) != len(d):
                raise BracketryError(f"{times}: {len(tv)} times for {len(d)} KITTI poses")
        elif frame_times_s is not None:
            tv = np.asarray(frame_times_s, np.float64)
            if len(tv) != len(d):
                raise BracketryError(f"{p}: {len(d)} KITTI poses for {len(tv)} left images of the trajectory (one "
                                     f"pose per left image in time order; else give 'times:' in {REFERENCE_FILE})")
        else:
            raise BracketryError(f"{p}: a KITTI reference needs its times file ('times:' in {REFERENCE_FILE})")
        t = tv * 1e-9 if np.all(tv > 1e12) else tv
        M = d.reshape(-1, 3, 4)
        poses = np.tile(np.eye(4), (len(d), 1, 1))
        poses[:, :3, :] = M
        return _sorted(t, poses)
    poses = np.tile(np.eye(4), (len(t), 1, 1))
    poses[:, :3, :3] = Rotation.from_quat(quat).as_matrix()
    poses[:, :3, 3] = xyz
    return _sorted(t, poses)


def _sorted(t: np.ndarray, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    order = np.argsort(t, kind="stable")
    t, poses = t[order], poses[order]
    keep = np.r_[True, np.diff(t) > 0]
    return t[keep], poses[keep]


def interpolate_poses(times_s: np.ndarray, poses: np.ndarray, query_s: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Poses at ``query_s`` (seconds) inside the reference's span: (kept query times, Mx4x4 poses).

    Translation linear, rotation by slerp between the two neighbouring poses.
    """
    q = np.asarray(query_s, np.float64)
    inside = (q >= times_s[0]) & (q <= times_s[-1])
    q = q[inside]
    out = np.tile(np.eye(4), (len(q), 1, 1))
    if len(q) == 0:
        return q, out
    if len(times_s) == 1:
        out[:] = poses[0]
        return q, out
    out[:, :3, :3] = Slerp(times_s, Rotation.from_matrix(poses[:, :3, :3]))(q).as_matrix()
    for i in range(3):
        out[:, i, 3] = np.interp(q, times_s, poses[:, i, 3])
    return q, out


def camera_reference(times_s: np.ndarray, poses_ws: np.ndarray, T_sensor_camera: np.ndarray,
                     image_times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Left-camera poses (camera-to-world) at the image times: ``interp(T_world_sensor) @ T_sensor_camera``."""
    t, T_ws = interpolate_poses(times_s, poses_ws, image_times_s)
    return t, T_ws @ T_sensor_camera


def load_reference_spec(folder: str | Path) -> dict | None:
    """The folder's ``reference.yaml`` as a dict with resolved paths, or None when there is none."""
    f = Path(folder) / REFERENCE_FILE
    if not f.is_file():
        return None
    try:
        doc = yaml.safe_load(f.read_text()) or {}
    except yaml.YAMLError as exc:
        raise BracketryError(f"{f}: not valid YAML ({exc})") from None
    if not isinstance(doc, dict) or "file" not in doc:
        raise BracketryError(f"{f}: needs 'file:' (and optionally format, times, extrinsic)")
    return {"file": Path(folder) / doc["file"], "format": doc.get("format"),
            "times": Path(folder) / doc["times"] if doc.get("times") else None,
            "extrinsic": extrinsic_matrix(doc.get("extrinsic"))}


def image_times_ns(folder: str | Path) -> list[int]:
    """Every image time (ns) of a trajectory folder: BorealHDR ``camera_left/<exposure>/<t_ns>.png`` and already
    emulated runs ``<method>/images_left/<t_ns>.png``."""
    root = Path(folder)
    stems = {p.stem for p in root.glob("camera_left/*/*.png")} | {p.stem for p in root.glob("*/images_left/*.png")}
    return sorted(int(s) for s in stems if s.isdigit())


def write_camera_reference(folder: str | Path, out_file: str | Path, times_ns: list[int] | None = None
                           ) -> Path | None:
    """Turn the folder's ``reference.yaml`` into a TUM left-camera reference at its image times (None: no yaml).

    ``times_ns``: the trajectory's left image times (default: :func:`image_times_ns` of ``folder``; a zip
    archive's come from the archive)."""
    from bracketry_emulator.trajectory_io import write_tum

    spec = load_reference_spec(folder)
    if spec is None:
        return None
    times = np.array(image_times_ns(folder) if times_ns is None else sorted(times_ns), np.float64) * 1e-9
    t, poses = read_reference(spec["file"], spec["format"], spec["times"], frame_times_s=times)
    if len(times) == 0:
        raise BracketryError(f"{folder}: no images to interpolate the reference at")
    qt, cam = camera_reference(t, poses, spec["extrinsic"], times)
    if len(qt) == 0:
        raise BracketryError(f"{spec['file']}: its time span misses every image of {folder}")
    out = Path(out_file)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_tum(out, qt, cam)
    return out
