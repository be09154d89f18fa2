"""The stereo calibration attached to what is recorded (#42 item 3): the rig config's ``calibration`` key names a
folder ``bracketry calibrate solve`` wrote; every file of the recording carries it (one MCAP Metadata record, the
per-frame CameraInfo); ``bracketry export --format borealhdr`` writes it as the tree's ``calibration/``, byte for
byte; the benchmark uses it. End to end on the simulated rig: board session -> solve -> config key -> simulate ->
export -> benchmark (built-in VO)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest
from test_recording_mcap import BRACKETS, H, W, make_set

from bracketry.cli import main as cli_main
from bracketry_base.paths import repo_root
from bracketry_base.recording import topics as T
from bracketry_base.recording.calibration import CALIBRATION_RECORD, read_calibration, recorded_calibration
from bracketry_base.recording.decode import decode
from bracketry_base.recording.reader import RecordingReader
from bracketry_emulator.synth.calibration import default_calibration, write_calibration
from bracketry_emulator.vo.calibration import StereoRectifier
from bracketry_rig.cameras.netns import netns_available
from bracketry_rig.daemon.config import ConfigError, parse_config
from bracketry_rig.export.borealhdr import export_borealhdr
from bracketry_rig.recording.recorder import Recorder, RecorderConfig
from bracketry_testkit import missing_component

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning:mcap_ros2.reader")


def calibration_folder(path: Path) -> Path:
    """A calibration folder as ``calibrate solve`` writes it (camera_info YAMLs, KITTI file, a report)."""
    write_calibration(default_calibration(W, H), path)
    (path / "report.json").write_text('{"stereo_rms_px": 0.1}\n')
    return path


def record(tmp: Path, n: int, calibration: Path | None, **kw) -> list[Path]:  # type: ignore[no-untyped-def]
    files = read_calibration(calibration) if calibration is not None else None
    rec = Recorder(tmp, "t", RecorderConfig(queue_max_items=1000, **kw), calibration_files=files,
                   metadata={"brackets_us": ",".join(map(str, BRACKETS)), "fps": "22.0"}).start()
    for k in range(n):
        pset = make_set(k)
        assert rec.put_event(pset.event) and rec.put_set(pset)
        time.sleep(0.001)
    rec.stop()
    return [Path(f) for f in rec.summary.files]


def test_every_file_carries_the_calibration_and_export_writes_it_byte_for_byte(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    cal = calibration_folder(tmp_path / "cal")
    files = record(tmp_path / "rec", 24, cal, split_bytes=20_000, chunk_max_bytes=8_000)
    assert len(files) >= 2  # split: each file carries it (a file is self-contained)
    infos = []
    for f in files:
        reader = RecordingReader(f)
        infos += [decode(m.schema_name, m.data) for m in reader.messages({T.camera_info_topic("left")})]
        assert recorded_calibration(reader.report.metadata) == read_calibration(cal)
        assert set(reader.report.metadata[CALIBRATION_RECORD]) == {
            "left.yaml", "right.yaml", "calib_kitti.txt", "report.json"}
    # the per-frame CameraInfo gets K, D, R, P of the calibration
    assert len(infos) == 24
    assert all(list(i.k) == pytest.approx(default_calibration(W, H).left.K.ravel()) for i in infos)
    # a file cut in the middle (kill -9) still carries it: the record is written before any message
    cut = tmp_path / "cut" / "t_000.mcap"
    cut.parent.mkdir()
    cut.write_bytes(files[0].read_bytes()[: files[0].stat().st_size // 2])
    assert cli_main(["export", str(cut.parent), "--out", str(tmp_path / "cut_tree"), "--quiet"]) == 0
    assert (tmp_path / "cut_tree" / "calibration" / "left.yaml").read_bytes() == (cal / "left.yaml").read_bytes()

    tree = tmp_path / "tree"
    capsys.readouterr()
    assert cli_main(["export", str(tmp_path / "rec"), "--out", str(tree), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert f"calibration: {tree / 'calibration'}" in out
    assert sorted(p.name for p in (tree / "calibration").iterdir()) == sorted(p.name for p in cal.iterdir())
    for p in cal.iterdir():
        assert (tree / "calibration" / p.name).read_bytes() == p.read_bytes(), p.name


def test_a_recording_without_calibration_exports_without_and_says_so_in_one_line(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    record(tmp_path / "rec", 12, None)
    tree = tmp_path / "tree"
    assert cli_main(["export", str(tmp_path / "rec"), "--out", str(tree), "--quiet"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if "calibration" in line]
    assert len(lines) == 1 and lines[0].startswith("calibration: none") and "rig.calibration" in lines[0]
    assert not (tree / "calibration").exists() and (tree / "camera_left").is_dir()
    assert export_borealhdr(tmp_path / "rec", tmp_path / "again", progress=False).calibration is None


def test_the_config_key_is_resolved_against_the_config_and_checked(tmp_path: Path) -> None:
    data = tomllib.loads((repo_root() / "host" / "deploy" / "rig.example.toml").read_text())
    calibration_folder(tmp_path / "cal")
    data["rig"]["calibration"] = "cal"
    assert parse_config(data, str(tmp_path / "rig.toml")).calibration == tmp_path / "cal"
    assert parse_config({**data, "rig": {**data["rig"], "calibration": str(tmp_path / "cal")}}).calibration \
        == tmp_path / "cal"
    assert parse_config(tomllib.loads((repo_root() / "host" / "deploy" / "rig.example.toml").read_text())
                        ).calibration is None
    (tmp_path / "half").mkdir()
    (tmp_path / "half" / "left.yaml").write_text((tmp_path / "cal" / "left.yaml").read_text())
    (tmp_path / "bad").mkdir()
    shutil.copy(tmp_path / "cal" / "left.yaml", tmp_path / "bad" / "left.yaml")
    (tmp_path / "bad" / "right.yaml").write_text("image_width: 32\n")
    for folder, problem in (("missing", "does not exist"), ("half", "has no right.yaml"),
                            ("bad", "right.yaml is not a ROS camera_info YAML")):
        data["rig"]["calibration"] = folder
        with pytest.raises(ConfigError, match=f"rig.toml: rig.calibration: .*{problem}") as exc:
            parse_config(data, str(tmp_path / "rig.toml"))
        assert "\n" not in str(exc.value)


@pytest.mark.slow
@pytest.mark.aravis
@pytest.mark.socat
def test_calibration_from_capture_to_benchmark_on_the_simulated_rig(tmp_path: Path) -> None:
    reason = netns_available()
    if reason:
        missing_component(f"private network namespace unavailable: {reason}")
    board, cal, rig, tree = (tmp_path / n for n in ("board", "cal", "rig", "tree"))
    assert cli_main(["synth", "calibration", "--out", str(board), "--seed", "1", "--views", "20", "--quiet"]) == 0
    assert cli_main(["calibrate", "solve", str(board), "--out", str(cal), "--trials", "8", "--quiet"]) == 0
    # the rig config's key (simulate writes it into the daemon's config); the daemon attaches it
    res = subprocess.run([sys.executable, "-m", "bracketry", "simulate", "--duration-s", "4", "--fps", "10",
                          "--out", str(rig), "--calibration", str(cal)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert tomllib.loads((rig / "sim_rig.toml").read_text())["rig"]["calibration"] == str(cal.resolve())
    [seg] = json.loads((rig / "simulation.json").read_text())["recordings"]
    assert cli_main(["export", seg, "--out", str(tree), "--quiet"]) == 0
    for p in cal.iterdir():  # the exported calibration is the solved one
        assert (tree / "calibration" / p.name).read_bytes() == p.read_bytes(), p.name
    shutil.copy(rig / "groundtruth.txt", tree)
    bench = tmp_path / "bench"
    assert cli_main(["benchmark", str(tree), "--out", str(bench), "--methods", "ae50", "--slam", "builtin",
                     "--workers", "1", "--windows", "1:2:1", "--quiet"]) == 0
    vo = bench / "vo" / "tree" / "ae50"
    assert json.loads((vo / "request.json").read_text())["calibration_dir"] == str(tree / "calibration")
    rect = json.loads((vo / "rectification.json").read_text())
    assert rect["baseline_m"] == pytest.approx(StereoRectifier.from_dir(cal).baseline_m, rel=1e-9)
    assert (bench / "report" / "results.csv").is_file()


def test_simulate_refuses_a_folder_that_is_no_calibration_in_one_line(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    (tmp_path / "empty").mkdir()
    assert cli_main(["simulate", "--out", str(tmp_path / "rig"), "--calibration", str(tmp_path / "empty")]) == 2
    err = capsys.readouterr().err.strip()
    assert "has no left.yaml" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "rig").exists()
