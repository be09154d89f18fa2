"""Dataset readers: BorealHDR tree grouping by timestamp, left/right matching, clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bracketry_emulator.dataset import DatasetError, open_dataset
from emu_synthetic import BRACKETS_US, radiance_map, write_tree


@pytest.mark.realdata
def test_emu_sample_groups_three_time_ordered_sequences(borealhdr_sample: Path, borealhdr_sequence: Path) -> None:
    ds = open_dataset(borealhdr_sample)  # the sample root: descends into its one recording
    assert ds.path == borealhdr_sequence
    assert ds.kind == "borealhdr"
    assert ds.sides == ("left", "right")
    assert ds.calibration_dir == borealhdr_sample / "calibration"
    assert ds.pcalib_path() is not None and ds.pcalib_path().name == "pcalib_inside1.txt"
    seqs = ds.sequences()
    assert len(seqs) == 3
    assert ds.exposures_us == (1000, 2000, 4000, 8000, 16000, 32000)
    for seq in seqs:
        for side in ds.sides:
            stamps = [seq.timestamps_ns[side][e] for e in seq.exposures_us]
            assert stamps == sorted(stamps)  # 1 ms first, 32 ms last, in time
            assert stamps[-1] - stamps[0] < 300_000_000
        assert seq.timestamps_ns["left"] == seq.timestamps_ns["right"]  # matched by timestamp
    assert seqs[0].timestamps_ns["left"][1000] == 1695668703498682368
    imgs = seqs[0].load("right")
    assert set(imgs) == set(BRACKETS_US)
    assert all(i.dtype == np.uint16 and i.shape == (1200, 1920) for i in imgs.values())
    assert int(imgs[32000].max()) == 4094


def test_emu_tree_incomplete_sequence_reported(tmp_path: Path) -> None:
    root = write_tree(tmp_path / "rec", radiance_map(8, 12), n_sequences=3)
    # drop the 4 ms frame of the second cycle on the left: that cycle is incomplete, and right's has no match
    victim = sorted((root / "camera_left" / "4.0").iterdir())[1]
    victim.unlink()
    ds = open_dataset(root)
    assert len(ds.sequences()) == 2
    assert any("incomplete sequence" in p for p in ds.problems)
    assert any("no match on left" in p for p in ds.problems)
    assert [s.index for s in ds.sequences()] == [0, 1]


def test_emu_tree_left_right_matched_by_timestamp_not_index(tmp_path: Path) -> None:
    root = write_tree(tmp_path / "rec", radiance_map(8, 12), n_sequences=2)
    # an extra leading partial cycle on the left only (like the real sample): index grouping would misalign
    extra = tmp_path / "rec" / "camera_left" / "32.0" / "1600000000000000000.png"
    extra.write_bytes((root / "camera_left" / "32.0").iterdir().__next__().read_bytes())
    ds = open_dataset(root)
    assert len(ds.sequences()) == 2
    for seq in ds.sequences():
        assert seq.timestamps_ns["left"] == seq.timestamps_ns["right"]


def test_emu_tree_errors_are_clear(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="dataset not found"):
        open_dataset(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="not a dataset"):
        open_dataset(tmp_path / "empty")
    root = write_tree(tmp_path / "rec", radiance_map(8, 12), n_sequences=1)
    bad = sorted((root / "camera_right" / "8.0").iterdir())[0]
    bad.write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    ds = open_dataset(root)
    with pytest.raises(DatasetError, match="corrupt or unreadable PNG"):
        ds.sequences()[0].load("right")
    (root / "camera_right" / "fast").mkdir()
    with pytest.raises(DatasetError, match="not an exposure in ms"):
        open_dataset(root)


def test_emu_tree_single_side_and_no_complete_sequence(tmp_path: Path) -> None:
    root = write_tree(tmp_path / "rec", radiance_map(8, 12), n_sequences=1, sides=("left",))
    ds = open_dataset(root)
    assert ds.sides == ("left",)
    assert len(ds.sequences()) == 1
    for png in (root / "camera_left" / "16.0").iterdir():
        png.unlink()
    with pytest.raises(DatasetError):
        open_dataset(root)
