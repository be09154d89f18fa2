"""A trajectory in a zip archive, read in place (BorealHDR distributes one zip per trajectory).

The zip holds a trajectory folder the benchmark accepts (DATASET.md, "BorealHDR tree"), either at the zip's root or
inside one top-level folder (a recording folder ``camera_left/``, ``camera_right/``, or a parent holding one
recording and ``calibration/``, as the BorealHDR sample). The PNGs (stored or deflated) are never unpacked to disk:
each frame's loader reads its member's bytes straight from the archive at their offset (``pread``) and decodes them in
memory by the compiled decoder (``read_png12_member``): a stored member as a PNG file (the PNG's own CRCs and zlib
checksum are checked), a deflated one inflated and checked against its CRC-32 first; without the compiled decoder (or
for a PNG it does not decode) the member's bytes are read through :mod:`zipfile` and decoded by OpenCV. The archive
is opened once per process (``os.getpid()`` keyed), never shared across a fork.

The trajectory's small side files (``groundtruth.txt``, ``reference.yaml`` and what it names, ``calibration/``, any
other file outside the camera and lidar folders, up to :data:`MAX_SIDE_FILE_BYTES` each) are copied once into
``<user cache>/zip-side-files/<key>/`` (key: the archive's path, size and modification time), where the readers of
ground truth and calibration find them as files. A calibration folder beside the archive is used when it has none.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import struct
import tempfile
import threading
import zipfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from .borealhdr import SIDE_FOLDERS, exposure_us_from_folder, side_sequences
from .imageio import read_png12_bytes, read_png12_member
from .model import Dataset, DatasetError, Frame

#: Side files larger than this are not copied out of the archive (rosbags, point clouds).
MAX_SIDE_FILE_BYTES = 256 * 1024 * 1024
#: Folders of a trajectory whose files are not side files.
_NOT_SIDE_FILES = ("camera_left", "camera_right", "lidar")
_LOCAL_HEADER = struct.Struct("<4sHHHHHIIIHH")  # the zip format's local file header (30 bytes)
_LOCAL_MAGIC = b"PK\x03\x04"


def is_zip_path(path: Path) -> bool:
    """True when ``path`` names a file ending in ``.zip`` (what :func:`open_zip` is for)."""
    return path.suffix.lower() == ".zip" and path.is_file()


@dataclass(frozen=True)
class ZipTrajectory:
    """Where the trajectory is in an archive: ``zip_path`` (resolved), ``root`` (the recording folder's member prefix,
    ``""`` or ``"name/"`` or ``"top/name/"``), ``calibration`` (the member prefix of its calibration folder, or None),
    ``name`` (the recording folder's name, else the archive's stem) and ``members`` (every file's ZipInfo by name)."""

    zip_path: Path
    root: str
    calibration: str | None
    name: str
    members: dict[str, zipfile.ZipInfo]


def _open(path: Path) -> zipfile.ZipFile:
    try:
        return zipfile.ZipFile(path)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, ValueError) as exc:
        raise DatasetError(f"not a readable zip archive (bad or truncated): {path} ({exc})") from None


def _safe(name: str) -> bool:
    p = PurePosixPath(name)
    return not p.is_absolute() and ".." not in p.parts and "\\" not in name


def locate(path: str | Path) -> ZipTrajectory:
    """Find the trajectory in the archive ``path``. One-line DatasetError for a bad or truncated archive, one with no
    trajectory and one with several."""
    p = Path(path).resolve()
    with _open(p) as zf:
        try:
            infos = zf.infolist()
        except (zipfile.BadZipFile, OSError) as exc:
            raise DatasetError(f"not a readable zip archive (bad or truncated): {p} ({exc})") from None
    # macOS archivers add __MACOSX/ (resource forks mirroring the tree): not a second recording
    members = {i.filename: i for i in infos
               if not i.is_dir() and _safe(i.filename) and not i.filename.startswith("__MACOSX/")}
    roots = set()
    for name in members:
        parts = name.split("/")
        for k, part in enumerate(parts[:-1]):
            if part in SIDE_FOLDERS.values() and k <= 2:
                roots.add("/".join(parts[:k]) + "/" if k else "")
                break
    if not roots:
        raise DatasetError(f"{p}: no trajectory in the archive (no camera_left/ or camera_right/ at its root or in "
                           "one or two folders)")
    if len(roots) > 1:
        listed = ", ".join(sorted(r.rstrip("/") or "." for r in roots))
        raise DatasetError(f"{p}: the archive holds several recordings ({listed}); zip one trajectory per archive")
    root = roots.pop()
    calibration = None
    parent = "/".join(root.rstrip("/").split("/")[:-1])
    for cand in (f"{root}calibration/", f"{parent}/calibration/" if parent else "calibration/"):
        if any(n.startswith(cand) for n in members):
            calibration = cand
            break
    name = root.rstrip("/").split("/")[-1] if root else p.stem
    return ZipTrajectory(p, root, calibration, name, members)


def _side_file_dir(z: ZipTrajectory) -> Path:
    """The folder holding the trajectory's side files (copied once; see the module docstring)."""
    from bracketry_base.paths import user_cache_dir

    st = z.zip_path.stat()
    key = hashlib.sha256(f"{z.zip_path}\0{st.st_size}\0{st.st_mtime_ns}".encode()).hexdigest()[:16]
    dest = user_cache_dir() / "zip-side-files" / key
    if dest.is_dir():
        return dest
    wanted: dict[str, str] = {}  # member -> path inside dest
    for name, info in z.members.items():
        if info.file_size > MAX_SIDE_FILE_BYTES:
            continue
        if name.startswith(z.root):
            rel = name[len(z.root):]
            if rel.split("/")[0] not in _NOT_SIDE_FILES:
                wanted[name] = f"trajectory/{rel}"
        elif z.calibration is not None and name.startswith(z.calibration):
            wanted[name] = f"trajectory/calibration/{name[len(z.calibration):]}"
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{key}-", dir=dest.parent))
    try:
        (tmp / "trajectory").mkdir()
        with _open(z.zip_path) as zf:
            for name, rel in wanted.items():
                target = tmp / rel
                target.parent.mkdir(parents=True, exist_ok=True)
                try:
                    target.write_bytes(zf.read(name))
                except (zipfile.BadZipFile, OSError, EOFError) as exc:
                    raise DatasetError(f"cannot read {name} in {z.zip_path}: {exc}") from None
        try:
            tmp.rename(dest)
        except OSError:  # another process copied them first
            if not dest.is_dir():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return dest


def side_files(path: str | Path) -> Path:
    """The folder holding the side files of the archive's trajectory (``groundtruth.txt``, ``reference.yaml``,
    ``calibration/``...; see the module docstring)."""
    return _side_file_dir(locate(path)) / "trajectory"


def calibration_dir(z: ZipTrajectory, files: Path) -> Path | None:
    """The calibration folder of the trajectory: copied from the archive, else ``calibration/`` beside it."""
    if (files / "calibration").is_dir():
        return files / "calibration"
    beside = z.zip_path.parent / "calibration"
    return beside if beside.is_dir() else None


# one open archive per (process, path): a forked worker opens its own
_OPEN: dict[str, tuple[int, int, zipfile.ZipFile | None]] = {}
_OPEN_LOCK = threading.Lock()


def _handles(zip_path: str) -> tuple[int, zipfile.ZipFile]:
    """(file descriptor, ZipFile) of ``zip_path`` opened by this process (the ZipFile opened on first need)."""
    pid = os.getpid()
    with _OPEN_LOCK:
        got = _OPEN.get(zip_path)
        if got is None or got[0] != pid:
            try:
                fd = os.open(zip_path, os.O_RDONLY | os.O_CLOEXEC)
            except OSError as exc:
                raise DatasetError(f"cannot read {zip_path}: {exc.strerror or exc}") from None
            got = (pid, fd, _open(Path(zip_path)))
            _OPEN[zip_path] = got
        return got[1], got[2]  # type: ignore[return-value]


class ZipPngLoader:
    """Loads one bracket PNG held in an archive (a :data:`~.model.FrameLoader`, as ``PngLoader``): ``zip_path``,
    ``member``, its ``header_offset``, ``size`` (compressed), ``file_size`` and ``crc``, whether it is ``stored``
    or ``deflated`` (neither: another method or encrypted, read through zipfile). Picklable."""

    __slots__ = ("crc", "deflated", "file_size", "header_offset", "member", "size", "stored", "zip_path")

    def __init__(self, zip_path: str, info: zipfile.ZipInfo) -> None:
        self.zip_path = zip_path
        self.member = info.filename
        self.header_offset = info.header_offset
        self.size = info.compress_size
        self.file_size = info.file_size
        self.crc = info.CRC
        plain = not info.flag_bits & 0x1
        self.stored = info.compress_type == zipfile.ZIP_STORED and plain
        self.deflated = info.compress_type == zipfile.ZIP_DEFLATED and plain

    @property
    def source(self) -> str:
        return f"{self.zip_path}:{self.member}"

    def _data_offset(self, fd: int) -> int:
        """Where the member's data starts in the archive (after its local header)."""
        try:
            head = os.pread(fd, _LOCAL_HEADER.size, self.header_offset)
        except OSError as exc:
            raise DatasetError(f"cannot read zip member {self.source}: {exc.strerror or exc}") from None
        if len(head) == _LOCAL_HEADER.size:
            fields = _LOCAL_HEADER.unpack(head)
            if fields[0] == _LOCAL_MAGIC:
                return self.header_offset + _LOCAL_HEADER.size + int(fields[9]) + int(fields[10])
        raise DatasetError(f"truncated or corrupt zip member: {self.source}")

    def raw(self) -> bytes:
        """The member's bytes as the archive holds them (compressed when deflated), read at their offset."""
        fd, _ = _handles(self.zip_path)
        start = self._data_offset(fd)
        try:
            data = os.pread(fd, self.size, start)
        except OSError as exc:
            raise DatasetError(f"cannot read zip member {self.source}: {exc.strerror or exc}") from None
        if len(data) != self.size:
            raise DatasetError(f"truncated or corrupt zip member: {self.source}")
        return data

    def data(self) -> bytes:
        """The member's bytes (the PNG file)."""
        if self.stored:
            return self.raw()
        _, zf = _handles(self.zip_path)
        try:
            return zf.read(self.member)
        except (zipfile.BadZipFile, OSError, EOFError, NotImplementedError, RuntimeError, ValueError) as exc:
            raise DatasetError(f"cannot read zip member {self.source}: {exc}") from None

    def _load(self, out: np.ndarray | None) -> np.ndarray:
        if self.stored or self.deflated:
            fd, _ = _handles(self.zip_path)
            img = read_png12_member(fd, self._data_offset(fd), self.size, -1 if self.stored else self.file_size,
                                    self.crc, self.source, out)
            if img is not None:
                return img
        return read_png12_bytes(self.data(), self.source, out)

    def __call__(self) -> np.ndarray:
        return self._load(None)

    def into(self, out: np.ndarray) -> np.ndarray:
        return self._load(out)

    def __getstate__(self) -> tuple:
        return tuple(getattr(self, k) for k in self.__slots__)

    def __setstate__(self, state: tuple) -> None:
        for k, v in zip(self.__slots__, state, strict=True):
            setattr(self, k, v)

    def __repr__(self) -> str:
        return f"ZipPngLoader({self.source!r})"


def _scan_side(z: ZipTrajectory, side: str, problems: list[str]) -> list[Frame]:
    """All frames of one ``camera_<side>`` folder of the archive (as ``borealhdr.scan_side``)."""
    prefix = f"{z.root}{SIDE_FOLDERS[side]}/"
    frames: list[Frame] = []
    zip_path = str(z.zip_path)
    for name in sorted(n for n in z.members if n.startswith(prefix)):
        parts = name[len(prefix):].split("/")
        if len(parts) != 2 or not parts[1].lower().endswith(".png"):
            continue
        exposure_us = exposure_us_from_folder(parts[0])
        stem = parts[1][:-4]
        info = z.members[name]
        if not stem.isdigit():
            problems.append(f"{side}: skipped {zip_path}:{name} (name is not a timestamp in ns)")
            continue
        if info.file_size == 0:
            problems.append(f"{side}: skipped empty file {zip_path}:{name}")
            continue
        frames.append(Frame(side, exposure_us, int(stem), f"{zip_path}:{name}", ZipPngLoader(zip_path, info)))
    return frames


def open_zip(path: str | Path, sides: tuple[str, ...] | None = None, *, tolerance_ns: int = 2_000_000) -> Dataset:
    """Open the trajectory in the archive ``path`` (see the module docstring) as ``open_tree`` opens a folder."""
    z = locate(path)
    present = tuple(s for s, folder in SIDE_FOLDERS.items() if any(n.startswith(f"{z.root}{folder}/")
                                                                   for n in z.members))
    wanted = sides or present
    problems: list[str] = []
    sequences = side_sequences(wanted, present, lambda side: _scan_side(z, side, problems),
                               lambda side: f"{z.root}{SIDE_FOLDERS[side]}/ in {z.zip_path}", str(z.zip_path),
                               problems, tolerance_ns)
    files = _side_file_dir(z) / "trajectory"
    gt = files / "groundtruth.txt"
    return Dataset(path=z.zip_path, kind="synthetic" if gt.is_file() else "borealhdr", sides=tuple(wanted),
                   calibration_dir=calibration_dir(z, files), groundtruth_path=gt if gt.is_file() else None,
                   _sequences=sequences, problems=problems)


def left_image_times_ns(path: str | Path) -> list[int]:
    """Every left image time (ns) of the archive's trajectory, sorted (as ``metrics.reference.image_times_ns``)."""
    z = locate(path)
    prefix = f"{z.root}camera_left/"
    stems = {n.rsplit("/", 1)[-1][:-4] for n in z.members if n.startswith(prefix) and n.lower().endswith(".png")}
    return sorted(int(s) for s in stems if s.isdigit())
