"""A trajectory zip read in place: the same frames as the folder, one process's archive not shared with a forked one,
and a bad, truncated or trajectory-less archive refused in one line (exit 2)."""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from bracketry_base.paths import repo_root
from bracketry_emulator.dataset import DatasetError, open_dataset
from bracketry_emulator.dataset.ziptree import ZipPngLoader, locate


def _zip(folder: Path, archive: Path, prefix: str, compression: int) -> Path:
    """Zip every file under ``folder`` into ``archive`` with names ``prefix + relative path``."""
    with zipfile.ZipFile(archive, "w", compression=compression) as zf:
        for f in sorted(folder.rglob("*")):
            if f.is_file():
                zf.write(f, prefix + f.relative_to(folder).as_posix())
    return archive


def _env(tmp_path: Path) -> dict[str, str]:
    root = repo_root()
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(root / "host"), str(root / "emulator")]),
            "BRACKETRY_CACHE": str(tmp_path / "cache")}


def _bracketry(tmp_path: Path, *args: str, timeout_s: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bracketry", *args], env=_env(tmp_path), capture_output=True,
                          text=True, timeout=timeout_s)


def _same_frames(a_path: Path, b_path: Path) -> int:
    a, b = open_dataset(a_path), open_dataset(b_path)
    sa, sb = a.sequences(), b.sequences()
    assert len(sa) == len(sb) > 0 and a.sides == b.sides and a.exposures_us == b.exposures_us
    n = 0
    for x, y in zip(sa, sb):
        assert x.timestamps_ns == y.timestamps_ns
        for side in a.sides:
            ix, iy = x.load(side), y.load(side)
            for e in ix:
                assert ix[e].dtype == iy[e].dtype == np.uint16 and np.array_equal(ix[e], iy[e])
                n += 1
    return n


@pytest.mark.realdata
@pytest.mark.parametrize("layout", ["root-stored", "folder-deflated", "sample-root-stored"])
def test_zip_gives_the_folders_frames(borealhdr_sample: Path, borealhdr_sequence: Path, tmp_path: Path,
                                      monkeypatch: pytest.MonkeyPatch, layout: str) -> None:
    monkeypatch.setenv("BRACKETRY_CACHE", str(tmp_path / "cache"))
    archive = tmp_path / "trajectory.zip"
    if layout == "root-stored":  # camera_left/ ... at the archive's root
        _zip(borealhdr_sequence, archive, "", zipfile.ZIP_STORED)
    elif layout == "folder-deflated":  # inside one top-level folder, the PNGs deflated
        _zip(borealhdr_sequence, archive, f"{borealhdr_sequence.name}/", zipfile.ZIP_DEFLATED)
    else:  # the sample's own root: calibration/ beside the recording folder
        _zip(borealhdr_sample, archive, "borealhdr_sample/", zipfile.ZIP_STORED)
    assert _same_frames(borealhdr_sequence, archive) == 36  # 3 cycles x 6 brackets x 2 cameras
    ds = open_dataset(archive)
    assert ds.path == archive.resolve() and ds.kind == "borealhdr" and ds.groundtruth_path is None
    if layout == "sample-root-stored":  # the calibration in the archive is found (copied out, small files only)
        assert ds.calibration_dir is not None and (ds.calibration_dir / "left.yaml").read_bytes() == (
            borealhdr_sample / "calibration" / "left.yaml").read_bytes()
        assert ds.pcalib_path() is not None
    else:
        assert ds.calibration_dir is None
    name = locate(archive).name
    assert name == (borealhdr_sequence.name if layout != "root-stored" else "trajectory")


def _checksum_in_child(loader: ZipPngLoader, conn) -> None:  # type: ignore[no-untyped-def]
    from bracketry_emulator.dataset import ziptree

    img = loader()
    conn.send((os.getpid(), int(img.astype(np.int64).sum()), {p for p, _, _ in ziptree._OPEN.values()}))
    conn.close()


@pytest.mark.realdata
def test_zip_is_opened_per_process_across_fork(borealhdr_sequence: Path, tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """The parent reads a frame (its archive open), a forked child reads the same frame through the same loader: the
    child opens its own archive (the handles it holds are its pid's), the pixels are the same."""
    from bracketry_emulator.dataset import ziptree

    monkeypatch.setenv("BRACKETRY_CACHE", str(tmp_path / "cache"))
    archive = _zip(borealhdr_sequence, tmp_path / "t.zip", "", zipfile.ZIP_DEFLATED)
    frame = open_dataset(archive).sequences()[1].frames["left"][8000]
    loader = frame.loader
    assert isinstance(loader, ZipPngLoader)
    parent_sum = int(frame.load().astype(np.int64).sum())
    assert {p for p, _, _ in ziptree._OPEN.values()} == {os.getpid()}
    ctx = multiprocessing.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)
    child = ctx.Process(target=_checksum_in_child, args=(loader, send))
    child.start()
    assert recv.poll(60), "the forked reader sent nothing in 60 s"
    child_pid, child_sum, pids = recv.recv()
    child.join(30)
    assert child.exitcode == 0 and child_sum == parent_sum and child_pid != os.getpid()
    assert child_pid in pids  # the child's own archive handle, opened after the fork


@pytest.mark.realdata
def test_truncated_or_trajectory_less_zip_is_one_line_exit_2(borealhdr_sample: Path, borealhdr_sequence: Path,
                                                              tmp_path: Path) -> None:
    good = _zip(borealhdr_sequence, tmp_path / "good.zip", "", zipfile.ZIP_STORED)
    data = good.read_bytes()
    truncated = tmp_path / "truncated.zip"
    truncated.write_bytes(data[: len(data) * 2 // 3])
    not_zip = tmp_path / "notzip.zip"
    not_zip.write_text("this is not an archive\n")
    no_traj = _zip(borealhdr_sample / "calibration", tmp_path / "calibration_only.zip", "calibration/",
                   zipfile.ZIP_DEFLATED)
    for archive, words in ((truncated, "bad or truncated"), (not_zip, "bad or truncated"),
                           (no_traj, "no trajectory")):
        with pytest.raises(DatasetError, match=words):
            open_dataset(archive)
        for cmd in (("benchmark", str(archive), "--slam", "builtin", "--out", str(tmp_path / f"b_{archive.stem}")),
                    ("emulate", str(archive), "--out", str(tmp_path / f"e_{archive.stem}"))):
            r = _bracketry(tmp_path, *cmd, timeout_s=120)
            lines = r.stderr.strip().splitlines()
            assert r.returncode == 2 and len(lines) == 1 and words in lines[0] and "Traceback" not in r.stderr, \
                (cmd, r.returncode, r.stderr)


@pytest.mark.realdata
def test_truncated_member_is_one_line(borealhdr_sequence: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                      ) -> None:
    """A stored member whose bytes end early (a damaged archive whose directory is intact): one DatasetError."""
    monkeypatch.setenv("BRACKETRY_CACHE", str(tmp_path / "cache"))
    archive = _zip(borealhdr_sequence, tmp_path / "t.zip", "", zipfile.ZIP_STORED)
    frame = open_dataset(archive).sequences()[0].frames["left"][1000]
    loader = frame.loader
    assert isinstance(loader, ZipPngLoader)
    state = dict(zip(ZipPngLoader.__slots__, loader.__getstate__()))
    damaged = ZipPngLoader.__new__(ZipPngLoader)
    damaged.__setstate__(tuple({**state, "size": archive.stat().st_size}[k] for k in ZipPngLoader.__slots__))
    with pytest.raises(DatasetError, match="truncated or corrupt zip member"):
        damaged()
    # a deflated member with a byte changed in the middle of its data: its CRC-32 fails, one line
    deflated = _zip(borealhdr_sequence, tmp_path / "d.zip", "", zipfile.ZIP_DEFLATED)
    frame = open_dataset(deflated).sequences()[0].frames["left"][1000]
    loader = frame.loader
    assert isinstance(loader, ZipPngLoader) and loader.deflated
    good = frame.load().copy()
    raw = bytearray(deflated.read_bytes())
    at = loader.header_offset + 30 + len(loader.member) + loader.size // 2
    raw[at] ^= 0x55
    broken = tmp_path / "broken.zip"
    broken.write_bytes(bytes(raw))
    frames = open_dataset(broken).sequences()[0].frames["left"]
    with pytest.raises(DatasetError, match=r"cannot read zip member .*broken\.zip"):
        frames[1000].load()
    assert np.array_equal(frames[2000].load(), open_dataset(deflated).sequences()[0].frames["left"][2000].load())
    assert not np.array_equal(good, frames[2000].load())


@pytest.mark.realdata
@pytest.mark.slow
def test_benchmark_of_a_zip_without_ground_truth(borealhdr_sample: Path, tmp_path: Path) -> None:
    """The shared sample zipped (no ground truth): exit 0; image metrics and survival computed, RTE/RRE absent (NaN,
    ``reference`` says why), the line printed per run says so."""
    archive = _zip(borealhdr_sample, tmp_path / "sample.zip", "borealhdr_sample/", zipfile.ZIP_STORED)
    out = tmp_path / "bench"
    r = _bracketry(tmp_path, "benchmark", str(archive), "--methods", "ae50,fix", "--slam", "builtin", "--workers",
                   "1", "--out", str(out), "-q", timeout_s=600)
    assert r.returncode == 0, r.stderr
    results = json.loads((out / "report" / "results.json").read_text())
    assert {x["method"] for x in results} == {"ae50", "fix"}
    for x in results:
        assert x["trajectory"] == "backpack_2023-09-25-15-05-03" and not x.get("error")
        assert isinstance(x["success"], bool) and math.isfinite(x["time_before_failure_s"])
        assert 0 < x["coverage_mean"] <= 1 and x["matches_mean"] > 0
        assert math.isnan(x["rte_pct"]) and math.isnan(x["rre_deg_per_m"])
        assert x["reference"].startswith("no reference")
    assert "RTE/RRE: no reference" in (out / "report" / "report.md").read_text()


@pytest.mark.realdata
def test_zip_without_the_compiled_decoder_gives_the_same_frames(borealhdr_sequence: Path, tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """Without ``_pngcodec`` the members are read through zipfile and decoded by OpenCV: the same pixels."""
    from bracketry_emulator.extensions import extensions_disabled

    monkeypatch.setenv("BRACKETRY_CACHE", str(tmp_path / "cache"))
    archive = _zip(borealhdr_sequence, tmp_path / "t.zip", "", zipfile.ZIP_DEFLATED)
    folder_seq, zip_seq = open_dataset(borealhdr_sequence).sequences()[0], open_dataset(archive).sequences()[0]
    with extensions_disabled():
        got = zip_seq.load("right")
    want = folder_seq.load("right")
    assert set(got) == set(want) and all(np.array_equal(got[e], want[e]) for e in want)
