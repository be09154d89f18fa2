"""The shared vectors in all three codecs: CPython, the C codec (host gcc with ASan/UBSan), real MicroPython (Node)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import cobs.cobs as cobs_pkg
import pytest
import wire_vectors_check

from bracketry_base import paths
from bracketry_rig.wire import bproto, vectors
from bracketry_testkit import missing_component
from crc16_reference import crc16_bitwise

C_DIR = paths.firmware_dir() / "protocol" / "c"
HERE = Path(__file__).resolve().parent


def test_wire_vectors_file_is_current() -> None:
    """The committed JSON equals what build_vectors() produces (format changes are deliberate)."""
    assert vectors.vectors_path().read_text() == vectors.dumps(vectors.build_vectors())


def test_wire_vectors_cover_every_message_type() -> None:
    v = vectors.load_vectors()
    assert {x["msg_type"] for x in v["valid"]} == set(bproto.MSG_NAMES)
    names = {s["name"] for s in v["streams"]}
    for needed in ("bad_crc", "truncated_frame", "over_long", "garbage_between_frames", "split_across_reads",
                   "unknown_type_is_a_valid_frame", "wrong_payload_length_is_a_valid_frame", "wrong_version"):
        assert needed in names
    assert {p["nack"] for p in v["payload_errors"]} == {bproto.NACK_UNKNOWN_TYPE, bproto.NACK_BAD_LENGTH,
                                                         bproto.NACK_BAD_VALUE}


def test_wire_vectors_independent_of_codec() -> None:
    """Valid frames check out with the `cobs` package and a bitwise CRC, not only with bproto itself."""
    for v in vectors.load_vectors()["valid"]:
        frame = bytes.fromhex(v["frame"])
        assert frame[-1] == 0 and 0 not in frame[:-1]
        body = cobs_pkg.decode(frame[:-1])
        payload = bytes.fromhex(v["payload"])
        assert body[0] == 1 and body[1] == v["msg_type"]
        assert int.from_bytes(body[2:4], "little") == v["seq"]
        assert int.from_bytes(body[4:6], "little") == len(payload)
        assert body[6:-2] == payload
        assert int.from_bytes(body[-2:], "little") == crc16_bitwise(body[:-2])


def test_wire_vectors_cpython() -> None:
    n, fails = wire_vectors_check.run(bproto, vectors.load_vectors())
    assert fails == []
    assert n > 50


def _gcc() -> str:
    gcc = shutil.which("gcc")
    if gcc is None:
        missing_component("host gcc not found; fix: apt-get install gcc")
    return str(gcc)


def test_wire_vectors_c_asan(tmp_path: Path) -> None:
    """Compile the C codec and its harness for the host with ASan/UBSan and run every vector."""
    exe = tmp_path / "bproto_test"
    subprocess.run([_gcc(), "-std=c99", "-Wall", "-Wextra", "-Werror", "-Wconversion", "-g", "-O1",
                    "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer",
                    str(C_DIR / "bproto.c"), str(C_DIR / "bproto_test.c"), "-o", str(exe)], check=True, timeout=120)
    text = tmp_path / "vectors.txt"
    text.write_text(vectors.to_c_text(vectors.load_vectors()))
    proc = subprocess.run([str(exe), str(text)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.strip().splitlines()[-1].startswith("PASS")


@pytest.mark.parametrize("compiler,flags", [
    ("gcc", ["-std=c99", "-Wpedantic", "-Wshadow", "-Wconversion"]),
    ("arm-none-eabi-gcc", ["-std=c99", "-mcpu=cortex-m4", "-mthumb", "-Os"]),
])
def test_wire_c_codec_warning_free(compiler: str, flags: list[str], tmp_path: Path) -> None:
    """-Wall -Wextra -Werror clean for the host and the STM32 compiler (no malloc: the object has no such symbol)."""
    cc = shutil.which(compiler)
    if cc is None:
        missing_component(f"{compiler} not found")
    obj = tmp_path / "bproto.o"
    subprocess.run([str(cc), *flags, "-Wall", "-Wextra", "-Werror", "-c", str(C_DIR / "bproto.c"), "-o", str(obj)],
                   check=True, timeout=120)
    nm = shutil.which("arm-none-eabi-nm" if compiler.startswith("arm") else "nm")
    if nm:
        undefined = subprocess.run([nm, "-u", str(obj)], capture_output=True, text=True, check=True).stdout
        assert "malloc" not in undefined and "free" not in undefined.split()


@pytest.mark.micropython
def test_wire_vectors_micropython(tmp_path: Path) -> None:
    """The very same bproto.py passes the vectors under the real MicroPython WebAssembly runtime."""
    node = shutil.which("node")
    assert node is not None
    proc = subprocess.run(
        [node, str(HERE / "wire_mpy_run.mjs"), str(paths.micropython_module_path()),
         str(HERE / "wire_vectors_check.py"),
         str(Path(bproto.__file__)), str(vectors.vectors_path())],
        capture_output=True, text=True, timeout=180, cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.strip().splitlines()[-1].startswith("PASS")


def test_wire_vectors_cpython_pure_paths(monkeypatch: pytest.MonkeyPatch) -> None:
    """The vectors also pass with the pure-Python CRC and COBS decoder that MicroPython uses."""
    monkeypatch.setattr(bproto, "crc16", bproto.crc16_table)
    monkeypatch.setattr(bproto, "cobs_decode", bproto.cobs_decode_py)
    n, fails = wire_vectors_check.run(bproto, vectors.load_vectors())
    assert fails == [] and n > 50
