"""Every subcommand against a table of bad inputs, as a new user would type them.

Each row asserts: exactly one line on stderr (no traceback), the documented exit code (2 usage or input error, 1 a
result "problems found"), the expected words in that line, and nothing created or changed on disk (the whole
scratch folder is compared before and after; paths the command was asked to create must not appear). Rows run
in-process through ``bracketry.cli.main`` (no interpreter start per row), so the table stays fast.

Below the table: the readers of a truncated recording agree (verify, export, emulate), export never writes half a
stereo pair silently, and ``emulate --overwrite`` replaces an earlier run instead of mixing two.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bracketry.cli import COMMANDS, main
from bracketry_base.options import EXIT_INTERNAL, EXIT_PROBLEMS, EXIT_USAGE
from bracketry_base.paths import repo_root
from bracketry_base.recording import topics as T
from bracketry_rig.events import TriggerEvent
from bracketry_rig.pairing.pairer import PairedSet
from bracketry_rig.recording.recorder import Recorder, RecorderConfig

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

H, W = 20, 32
BRACKETS_US = [1000, 2000, 4000, 8000, 16000, 32000]


def _set(k: int, drop: str | None = None) -> PairedSet:
    ev = TriggerEvent(7, k, k % 6, BRACKETS_US[k % 6], 1_000_000 + k * 45_454,
                      1_700_000_000_000_000_000 + k * 45_454_000)
    rng = np.random.default_rng(k)
    frames = {}
    for side in T.SIDES:
        frames[side] = None if side == drop else SimpleNamespace(
            side=side, frame_id=k + 1, frame_index=k, skipped_ids=0, status="success",
            image=rng.integers(0, 4096, size=(H, W), dtype=np.uint16), cam_timestamp_ns=k * 45_454_000,
            host_receive_ns=ev.t_start_host_ns + 9_000_000, missing_packets=0, exposure_us_reported=None)
    return PairedSet(k, ev, frames, ev.t_start_host_ns)


def _record(folder: Path, n: int, drop: dict[int, str] | None = None) -> Path:
    folder.mkdir(parents=True)
    meta = {"brackets_us": ",".join(map(str, BRACKETS_US)), "fps": "22.0"}
    rec = Recorder(folder, "t", RecorderConfig(queue_max_items=1000, chunk_max_bytes=20_000), metadata=meta).start()
    for k in range(n):
        pset = _set(k, (drop or {}).get(k))
        assert rec.put_event(pset.event)
        assert rec.put_set(pset)
        time.sleep(0.001)
    rec.stop()
    return Path(rec.summary.files[0])


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Read-only inputs shared by the rows (outside the scratch folder each row watches)."""
    root = tmp_path_factory.mktemp("inputs")
    good = _record(root / "good", 40)
    data = good.read_bytes()
    trunc = root / "trunc.mcap"
    trunc.write_bytes(data[: int(len(data) * 0.6)])
    trunc2 = root / "trunc2.mcap"
    trunc2.write_bytes(data[: int(len(data) * 0.5)])
    (root / "zero.mcap").write_bytes(b"")
    (root / "text.mcap").write_text("this is not a recording\n")
    (root / "random.bin").write_bytes(bytes(np.random.default_rng(1).integers(1, 256, 64, dtype=np.uint8)))
    (root / "weights.pth").write_text("not a state dict")
    (root / "manifest.yaml").write_text("trajectories: [1, 2]\n")
    (root / "neg_pcalib.txt").write_text(" ".join(str(v) for v in np.linspace(-5.0, 4095.0, 256)) + "\n")
    stack = root / "stack"
    stack.mkdir()
    (stack / "static.json").write_text("{}")
    cfg = (repo_root() / "host" / "deploy" / "rig.simulated.toml").read_text()
    (root / "rig_proc.toml").write_text(cfg.replace('output_dir = "/tmp/bracketry-sim/recordings"',
                                                    'output_dir = "/proc/nope"'))
    assert "/proc/nope" in (root / "rig_proc.toml").read_text()
    return {"good": good, "trunc": trunc, "trunc2": trunc2, "zero": root / "zero.mcap", "text": root / "text.mcap",
            "random": root / "random.bin", "weights": root / "weights.pth", "manifest": root / "manifest.yaml",
            "neg_pcalib": root / "neg_pcalib.txt", "stack": stack, "rig_proc": root / "rig_proc.toml"}


@dataclass(frozen=True)
class Row:
    cls: str  # the class of bad input: number, path, file, recording, network
    argv: str  # {x} placeholders: inputs, and {tmp} the watched scratch folder
    code: int = EXIT_USAGE
    words: str = ""  # a fragment the error line must hold (case-insensitive)


ROWS = [
    # ---- numbers: out of range, not finite, negative where it must be positive
    Row("number", "trigger start --port {tmp}/none --session 1 --period-us 99999999999 --exposures-us 1000",
        words="--period-us"),
    Row("number", "trigger start --port {tmp}/none --session 1 --timeout-s -1", words="--timeout-s"),
    Row("number", "trigger monitor --port {tmp}/none --timeout-s nan", words="finite"),
    Row("number", "trigger simulate --link {tmp}/link --drop-prob 2", words="--drop-prob"),
    Row("number", "trigger simulate --link {tmp}/link --duration-s 0", words="--duration-s"),
    Row("number", "trigger qemu --tcp-port 80", words="--tcp-port"),
    Row("number", "record --config {rig_proc} --duration 99999999999h", words="--duration-s"),
    Row("number", "record --config {rig_proc} --duration-s -5", words="--duration-s"),
    Row("number", "emulate {good} --out {tmp}/emu --gain-db nan", words="--gain-db"),
    Row("number", "emulate {good} --out {tmp}/emu --gain-db 1000", words="--gain-db"),
    Row("number", "emulate {good} --out {tmp}/emu --max-exposure-ms 1e308", words="--max-exposure-ms"),
    Row("number", "emulate {good} --out {tmp}/emu --min-exposure-ms 10 --init-exposure-ms 4", words="--min-exposure"),
    Row("number", "emulate {good} --out {tmp}/emu --workers -3", words="--workers"),
    Row("number", "export {good} --out {tmp}/exp --workers -3", words="--workers"),
    Row("number", "accuracy neighbours {good} --out {tmp}/acc --max-sequences -1", words="--max-sequences"),
    Row("number", "accuracy static {stack} --out {tmp}/acc --max-targets -1", words="--max-targets"),
    Row("number", "accuracy static {stack} --out {tmp}/acc --alpha inf", words="--alpha"),
    Row("number", "accuracy motion --out {tmp}/acc --instants 0", words="--instants"),
    Row("number", "hw bandwidth --fps 1e308", words="--fps"),
    Row("number", "hw bandwidth --fps -inf", words="--fps"),
    Row("number", "hw bandwidth --cameras 0", words="--cameras"),
    Row("number", "hw power --efficiency 0", words="--efficiency"),
    Row("number", "wire ping {tmp}/none --count 0", words="--count"),
    Row("number", "wire ping {tmp}/none --timeout 1e999", words="--timeout-s"),
    Row("number", "wire encode PING --seq 70000", words="--seq"),
    Row("number", "synth trajectory --out {tmp}/syn --seconds -1", words="--duration-s"),
    Row("number", "synth trajectory --out {tmp}/syn --fps 0", words="--fps"),
    Row("number", "synth static --out {tmp}/syn --min-us nan", words="--min-us"),
    Row("number", "synth calibration --out {tmp}/syn --views 2", words="--views"),
    Row("number", "synth calibration --out {tmp}/syn --baseline-m nan", words="--baseline-m"),
    Row("file", "synth calibration --out {tmp}/syn --board {tmp}/keep.txt", words="board definition"),
    Row("number", "simulate --out {tmp}/sim --fps 1e9", words="--fps"),
    Row("number", "simulate --out {tmp}/sim --seconds 0", words="--duration-s"),
    Row("number", "demo --out {tmp}/demo --seconds 1", words="--duration-s"),
    Row("number", "demo --out {tmp}/demo --duration-s 2s", words="at least 3 s"),
    Row("number", "demo --out {tmp}/demo --duration-s 11m", words="at most 600 s"),
    Row("number", "benchmark {good} --out {tmp}/bench --alpha 2", words="--alpha"),
    Row("number", "benchmark {good} --out {tmp}/bench --workers -1", words="--workers"),
    Row("number", "calibrate-crf {stack} --out {tmp}/p.txt --iterations 0", words="--iterations"),
    Row("number", "cameras grab --address 127.0.0.1 --count 0", words="--count"),
    Row("number", "cameras grab --address 127.0.0.1 --width -4", words="--width"),
    Row("number", "slam vocabulary {random} --out {tmp}/voc.txt --k 1", words="--k"),
    Row("number", "train drl {good} --steps 0 --out {tmp}/w.pth", words="--steps"),
    Row("number", "benchmark {good} --out {tmp}/bench --slam-repeats 0", words="--slam-repeats"),
    Row("number", "benchmark {good} --out {tmp}/bench --cluster slurm --jobs 0", words="--jobs"),
    Row("number", "benchmark {good} --out {tmp}/bench --cluster slurm --job-cores 0", words="--job-cores"),
    Row("number", "benchmark {good} --out {tmp}/bench --cluster slurm --job-memory 8", words="--job-memory"),
    Row("number", "benchmark {good} --out {tmp}/bench --cluster slurm --job-walltime 0", words="--job-walltime"),
    Row("number", "simulate --out {tmp}/sim --monitor 80", words="--monitor"),
    Row("number", "simulate --out {tmp}/sim --world-seconds nan", words="--world-seconds"),
    Row("number", "panel simulate --link {tmp}/none --duration-s nan", words="--duration-s"),
    # ---- output paths: existing file, missing parent, not writable, file where a folder is expected, wrong kind
    Row("path", "verify --repair --out {tmp}/keep.mcap {trunc}", words="--overwrite"),
    Row("path", "verify --repair --out /nonexistent/dir/x.mcap {trunc}", words="does not exist"),
    Row("path", "verify --repair --out {tmp}/new.mcap {trunc} {trunc2}", words="2 files need repair"),
    Row("path", "verify --out {tmp}/new.mcap {trunc}", words="--repair"),
    Row("path", "export {good} --out {tmp}/keep.txt", words="expected a folder"),
    Row("path", "export {good} --out /proc/x", words="cannot write"),
    Row("path", "export {good} --out {tmp}/full", words="--overwrite"),
    Row("path", "export {good} --format rosbag1 --out /nonexistent/dir/x.bag", words="does not exist"),
    Row("path", "export {good} --format rosbag1 --out {tmp}/keep.bag", words="--overwrite"),
    Row("path", "emulate {good} --out {tmp}/keep.txt", words="expected a folder"),
    Row("path", "emulate {good} --out {tmp}/full", words="--overwrite"),
    Row("path", "accuracy neighbours {good} --out {tmp}/keep.txt", words="expected a folder"),
    Row("path", "accuracy neighbours {good} --out {tmp}/full", words="--overwrite"),
    Row("path", "accuracy static {stack} --out /nonexistent/a/b", words="does not exist"),
    Row("path", "accuracy motion --out /nonexistent/a/b", words="does not exist"),
    Row("path", "calibrate-crf {stack} --out /nonexistent/dir/p.txt", words="does not exist"),
    Row("path", "calibrate-crf {stack} --out {tmp}/keep.txt", words="--overwrite"),
    Row("path", "calibrate-crf {stack} --out {tmp}/full", words="is a folder"),
    Row("path", "hw diagram --out {tmp}/x.png", words=".svg or .dot"),
    Row("path", "hw diagram --out {tmp}/keep.svg", words="--overwrite"),
    Row("path", "wire encode PING --out {tmp}/keep.txt", words="--overwrite"),
    Row("path", "devices --from-json {tmp}/keep.json --udev-rules {tmp}/keep.txt", words="--overwrite"),
    Row("path", "synth trajectory --out {tmp}/full", words="--overwrite"),
    Row("path", "synth static --out {tmp}/keep.txt", words="expected a folder"),
    Row("path", "simulate --out {tmp}/keep.txt", words="expected a folder"),
    Row("path", "demo --out {tmp}/full", words="--overwrite"),
    Row("path", "cameras grab --address 127.0.0.1 --out {tmp}/keep.txt", words="expected a folder"),
    Row("path", "benchmark {good} --out {tmp}/keep.txt", words="expected a folder"),
    Row("path", "benchmark {good} --out {tmp}/full", words="--resume"),
    Row("path", "benchmark {good} --out {tmp}/full --resume --overwrite", words="exclude each other"),
    Row("path", "trigger simulate --link {tmp}/keep.txt", words="--overwrite"),
    Row("path", "panel simulate --link {tmp}/none --screen-file /nonexistent/dir/s.txt", words="does not exist"),
    Row("path", "slam vocabulary {random} --out {tmp}/keep.txt", words="--overwrite"),
    Row("path", "train drl {good} --steps 10 --out {tmp}/keep.txt", words=".pth file"),
    Row("path", "train drl {good} --steps 10 --out {tmp}/w.pth --resume", words="no checkpoint"),
    Row("path", "train drl {good} --steps 10 --out {weights}", words="--resume"),
    Row("path", "slam vocabulary {random} --out /nonexistent/dir/voc.txt", words="does not exist"),
    Row("path", "daemon --check --config {rig_proc}", words="output_dir"),
    # ---- input files: missing, wrong content
    Row("file", "emulate {good} --out {tmp}/emu -m drl --drl-weights {weights}", words="DRL weights"),
    Row("file", "benchmark {manifest} --out {tmp}/bench", words="trajectories[0]"),
    Row("file", "benchmark {stack} --methods bogus --out {tmp}/bench", words="unknown AE method 'bogus'"),
    Row("file", "emulate {good} --out {tmp}/emu --method-options {tmp}/none.yaml", words="does not exist"),
    Row("file", "benchmark {good} --out {tmp}/bench --method-options {weights}", words="mapping"),
    Row("file", "demo --out {tmp}/demo --methods ae50 --method-option ae50x=1", words="--method-option"),
    Row("file", "demo --out {tmp}/demo --methods ae50,nope:Cls", words="cannot import"),
    Row("file", "emulate {good} --out {tmp}/emu --crf {neg_pcalib}", words="pcalib"),
    Row("file", "emulate {good} --out {tmp}/emu --crf {tmp}/none.txt", words="--crf"),
    Row("file", "wire decode 0000000000", code=EXIT_PROBLEMS, words="no complete frame"),
    Row("file", "wire decode 01020304", code=EXIT_PROBLEMS, words="no complete frame"),
    Row("file", "wire decode {random}", code=EXIT_PROBLEMS, words="no complete frame"),
    Row("file", "slam vocabulary {tmp}/none.png --out {tmp}/voc.txt", words="does not exist"),
    Row("file", "train drl {tmp}/none --steps 10 --out {tmp}/w.pth", words="does not exist"),
    Row("file", "train drl {manifest} --steps 10 --out {tmp}/w.pth", words="trajectories[0]"),
    Row("file", "benchmark {good} --out {tmp}/bench --vocabulary {tmp}/none.txt", words="does not exist"),
    Row("file", "daemon --config {tmp}/none.toml", words="does not exist"),
    Row("file", "hw diagram --wiring {tmp}/none.yaml", words="does not exist"),
    Row("file", "calibrate-crf {tmp}/none --out {tmp}/p.txt", words="does not exist"),
    Row("file", "calibrate crf {tmp}/none --out {tmp}/p.txt", words="does not exist"),
    Row("file", "calibrate solve {tmp}/none --out {tmp}/cal", words="does not exist"),
    Row("file", "calibrate solve {tmp} --out {tmp}/cal", words="no board.yaml"),
    Row("file", "calibrate solve {tmp} --out {tmp}/cal --board {tmp}/keep.txt", words="board definition"),
    Row("number", "calibrate solve {tmp} --out {tmp}/cal --trials 0", words="--trials"),
    Row("number", "calibrate solve {tmp} --out {tmp}/cal --inlier-px nan", words="--inlier-px"),
    Row("path", "calibrate solve {tmp} --out {tmp}/full", words="--overwrite"),
    Row("file", "calibrate capture --from {tmp}/none --out {tmp}/kept", words="does not exist"),
    Row("file", "calibrate capture --from {tmp} --out {tmp}/kept", words="no board.yaml"),
    Row("number", "calibrate capture --from {tmp} --out {tmp}/kept --monitor 70000", words="--monitor"),
    Row("number", "calibrate capture --from {tmp} --out {tmp}/kept --rate-hz -1", words="--rate-hz"),
    Row("file", "status --socket {tmp}/none.sock", words="no daemon is listening"),
    Row("file", "status --config {tmp}/none.toml", words="does not exist"),
    # ---- recordings: empty, not MCAP
    Row("recording", "verify {zero}", words="not an MCAP file"),
    Row("recording", "export {zero} --out {tmp}/exp", words="not an MCAP file"),
    Row("recording", "export {text} --format rosbag1 --out {tmp}/x.bag", words="not an MCAP file"),
    Row("recording", "emulate {zero} --out {tmp}/emu", words="not an MCAP file"),
    Row("recording", "emulate {text} --out {tmp}/emu", words="not an MCAP file"),
    Row("recording", "accuracy neighbours {zero} --out {tmp}/acc", words="not an MCAP file"),
    Row("recording", "verify {tmp}/full", words="no .mcap files"),
    Row("recording", "export {tmp}/full --out {tmp}/exp", words="no .mcap files"),
    Row("recording", "verify --repair {zero}", words="not an MCAP file"),
    # ---- network: camera addresses are IPv4 only (a name would be resolved by a discovery broadcast)
    Row("network", "cameras probe --address camera.local", words="not an IPv4 address"),
    Row("network", "cameras configure --address 999.1.1.1", words="not an IPv4 address"),
    Row("network", "cameras grab --address 255.255.255.255", words="unicast"),
    Row("network", "cameras probe --address ''", words="not an IPv4 address"),
]


def _subprocess(argv: list[str]) -> int:
    """Run a command that does real work (closed loops) in its own process: its threads and worker processes never
    share this test process with later tests that fork."""
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", "bracketry", *argv], capture_output=True, text=True, timeout=300)
    assert "Traceback" not in res.stderr, res.stderr
    return res.returncode


def _snapshot(root: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(root.rglob("*"))}


def _scratch(tmp: Path) -> None:
    (tmp / "keep.txt").write_text("keep me\n")
    (tmp / "keep.mcap").write_bytes(b"healthy recording stand-in")
    (tmp / "keep.bag").write_bytes(b"bag")
    (tmp / "keep.svg").write_text("<svg/>")
    (tmp / "keep.json").write_text("[]")
    (tmp / "full").mkdir()
    (tmp / "full" / "old.txt").write_text("earlier run\n")


@pytest.mark.parametrize("row", ROWS, ids=[f"{r.cls}:{r.argv.split(' --')[0]}:{i}" for i, r in enumerate(ROWS)])
def test_bad_input_is_one_line_and_changes_nothing(row: Row, inputs: dict[str, Path], tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    import shlex

    _scratch(tmp_path)
    before = _snapshot(tmp_path)
    argv = [a.format(tmp=tmp_path, **inputs) for a in shlex.split(row.argv)]
    rc = main(argv)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, f"{row.argv}: expected one line on stderr, got:\n{err}"
    assert rc == row.code, f"{row.argv}: exit {rc}, expected {row.code}: {err}"
    assert lines[0].startswith("error: "), lines[0]
    assert "Traceback" not in err and "internal error" not in err
    assert row.words.lower() in lines[0].lower(), f"{row.argv}: {lines[0]!r} lacks {row.words!r}"
    assert _snapshot(tmp_path) == before, f"{row.argv} changed the disk"
    assert not Path("/nonexistent").exists()


def test_the_table_covers_every_subcommand_and_class() -> None:
    used = {r.argv.split()[0] for r in ROWS}
    wanted = set(COMMANDS) - {"doctor"}  # doctor takes no input (only --json)
    assert wanted <= used, f"subcommands without bad-input rows: {sorted(wanted - used)}"
    assert {r.cls for r in ROWS} == {"number", "path", "file", "recording", "network"}
    assert len(ROWS) >= 80


def test_internal_errors_have_their_own_exit_code(monkeypatch: pytest.MonkeyPatch,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    import click

    from bracketry import cli as cli_mod

    @click.command("boom")
    def boom() -> None:
        raise KeyError("a bug")

    monkeypatch.setattr(cli_mod.LazyGroup, "get_command", lambda self, ctx, name: boom)
    rc = main(["boom"])
    err = capsys.readouterr().err
    assert rc == EXIT_INTERNAL and rc not in (0, EXIT_PROBLEMS, EXIT_USAGE)
    assert err.count("\n") == 1 and "internal error: KeyError" in err


def test_verify_repair_keeps_a_healthy_file_and_overwrites_only_when_asked(
        inputs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    healthy = tmp_path / "good.mcap"
    healthy.write_bytes(inputs["good"].read_bytes())
    assert main(["verify", "--repair", "--out", str(healthy), str(inputs["trunc"])]) == EXIT_USAGE
    assert healthy.read_bytes() == inputs["good"].read_bytes()
    capsys.readouterr()
    rc = main(["verify", "--repair", "--out", str(healthy), "--overwrite", "--json", str(inputs["trunc"])])
    doc = json.loads(capsys.readouterr().out)
    assert rc == EXIT_PROBLEMS  # the truncated input has problems; the copy was written on request
    assert doc["repaired"][0]["repaired"] == str(healthy) and healthy.read_bytes() != inputs["good"].read_bytes()
    assert [p.name for p in tmp_path.iterdir()] == ["good.mcap"]  # no temporary file left


def test_truncated_recording_is_read_alike_by_verify_export_and_emulate(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """One reader for all: a recording cut by a power loss, with one frame whose right partner was lost."""
    good = _record(tmp_path / "rec", 40, drop={13: "right"})
    data = good.read_bytes()
    cut = tmp_path / "cut"
    cut.mkdir()
    (cut / good.name).write_bytes(data[: int(len(data) * 0.7)])
    capsys.readouterr()
    assert main(["verify", "--json", str(cut)]) == EXIT_PROBLEMS
    report = json.loads(capsys.readouterr().out)["reports"][0]
    assert report["truncated"] and report["readable"]
    images = {s: report["sides"][s]["images"] for s in ("left", "right")}
    assert report["sides"]["left"]["unpaired"] == 1 and images["left"] == images["right"] + 1
    # export: the unpaired left frame is not written, and that is said
    assert main(["export", str(cut), "--out", str(tmp_path / "tree"), "-q"]) == 0
    err = capsys.readouterr().err
    assert "1 frame(s) whose other-camera partner was lost" in err
    pngs = {s: sorted(p.name for p in (tmp_path / "tree" / f"camera_{s}").rglob("*.png")) for s in ("left", "right")}
    assert pngs["left"] == pngs["right"] and len(pngs["left"]) == images["right"]
    # emulate reads the same truncated file through the same reader
    out = tmp_path / "emu"
    assert _subprocess(["emulate", str(cut), "--out", str(out), "-m", "ae50", "-j", "1", "--no-images", "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sequences"] >= 1
    assert any("truncated" in p for p in summary["dataset_problems"])


def test_emulate_overwrite_replaces_the_earlier_run(inputs: dict[str, Path], tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "emu"
    base = ["emulate", str(inputs["good"]), "--out", str(out), "-j", "1", "--no-images", "-q",
            "--max-sequences", "2"]
    assert _subprocess([*base, "-m", "ae50,shim"]) == 0
    assert (out / "shim").is_dir()
    capsys.readouterr()
    assert main([*base, "-m", "ae50"]) == EXIT_USAGE  # refused while parsing: not empty
    assert "--overwrite" in capsys.readouterr().err
    assert _subprocess([*base, "-m", "ae50", "--overwrite"]) == 0
    assert list(json.loads((out / "summary.json").read_text())["methods"]) == ["ae50"]
    assert not (out / "shim").exists()


def test_every_option_has_help_text() -> None:
    import click

    from bracketry.cli import LazyGroup, cli

    ctx = click.Context(cli)
    missing = []

    def walk(cmd: click.Command, path: str) -> None:
        if isinstance(cmd, click.Group):
            for name in cmd.list_commands(ctx):
                sub = cmd.get_command(ctx, name)
                if sub is not None:
                    walk(sub, f"{path} {name}")
            return
        for p in cmd.params:
            if isinstance(p, click.Option) and not p.hidden and not (p.help or "").strip():
                missing.append(f"{path} {p.opts[0]}")

    assert isinstance(cli, LazyGroup)
    walk(cli, "bracketry")
    assert not missing, missing
    assert os.environ.get("BRACKETRY_DEBUG") != "1"
