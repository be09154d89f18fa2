"""Boot the real trigger firmware ELF in QEMU (``qemu-system-arm -M netduinoplus2``, an STM32F405) and say where to
connect.

USART2 of the firmware is QEMU's second ``-serial`` (the first, USART1, goes to ``null``); it is exposed either as a
loopback TCP server (``socket://127.0.0.1:PORT`` for pyserial) or as a pty (``/dev/pts/N``). What QEMU models and
what it does not (GPIO, RCC, DMA; timer rates) is described in ``firmware/stm32_trigger/README.md``.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

from bracketry_base import paths
from bracketry_base.errors import BracketryError, MissingComponentError

QEMU_BINARY = "qemu-system-arm"
QEMU_MACHINE = "netduinoplus2"
_PTY_RE = re.compile(r"char device redirected to (/dev/pts/\d+) \(label serial1\)")


def firmware_source_dir() -> Path:
    """``firmware/stm32_trigger`` of the checkout."""
    return paths.firmware_dir() / "stm32_trigger"


def default_elf() -> Path:
    """Where ``make -C firmware/stm32_trigger`` puts the ELF."""
    return firmware_source_dir() / "build" / "stm32_trigger.elf"


def build_firmware(build_dir: str | Path | None = None, polarity: str = "low", timeout_s: float = 300.0) -> Path:
    """Run ``make`` for the firmware (into ``build_dir``, default ``firmware/stm32_trigger/build``); returns the ELF.

    Raises MissingComponentError without ``make``/``arm-none-eabi-gcc``, BracketryError if the build fails.
    """
    for tool in ("make", "arm-none-eabi-gcc"):
        if shutil.which(tool) is None:
            raise MissingComponentError(f"{tool} not found (Debian: apt-get install make gcc-arm-none-eabi "
                                        "libnewlib-arm-none-eabi)")
    out_dir = Path(build_dir).resolve() if build_dir is not None else firmware_source_dir() / "build"
    cmd = ["make", "-C", str(firmware_source_dir()), f"BUILD_DIR={out_dir}", f"POLARITY={polarity}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
    if proc.returncode != 0:
        last = (proc.stderr.strip() or proc.stdout.strip()).splitlines()[-1:] or ["?"]
        raise BracketryError(f"firmware build failed: {last[0]}")
    return out_dir / "stm32_trigger.elf"


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class QemuTrigger:
    """One QEMU process running the trigger firmware.

    Args:
        elf: firmware ELF (default: :func:`default_elf`, built by :func:`build_firmware` if it does not exist).
        serial: ``"tcp"`` (loopback TCP server, ``url`` is ``socket://127.0.0.1:PORT``) or ``"pty"`` (``url`` is the
            pty path).
        port: TCP port (``serial="tcp"``); a free one if None.
        log_path: file for QEMU's stderr (a temp file if None).

    Use as a context manager or call :meth:`start` / :meth:`stop`. :attr:`url` is what to pass to
    :class:`bracketry_rig.wire.link.SerialLink` or ``bracketry trigger ... --port``.
    """

    def __init__(self, elf: str | Path | None = None, serial: str = "tcp", port: int | None = None,
                 log_path: str | Path | None = None) -> None:
        if serial not in ("tcp", "pty"):
            raise BracketryError(f"serial must be tcp or pty, not {serial!r}")
        self._build_default = elf is None
        self.elf = Path(elf) if elf is not None else default_elf()
        self.serial = serial
        self.port = port
        self._log_path = Path(log_path) if log_path is not None else None
        self._tmp_log: Path | None = None
        self.proc: subprocess.Popen | None = None
        self.url = ""

    def command(self) -> list[str]:
        """The qemu-system-arm command line."""
        if self.serial == "tcp":
            backend = f"tcp:127.0.0.1:{self.port},server=on,wait=off,nodelay=on"
        else:
            backend = "pty"
        return [QEMU_BINARY, "-M", QEMU_MACHINE, "-nographic", "-monitor", "none", "-kernel", str(self.elf),
                "-serial", "null", "-serial", backend]

    def start(self, timeout_s: float = 20.0) -> QemuTrigger:
        """Launch QEMU and wait until its serial port is reachable. Returns self."""
        if shutil.which(QEMU_BINARY) is None:
            raise MissingComponentError(f"{QEMU_BINARY} not found (Debian: apt-get install qemu-system-arm)")
        if not self.elf.is_file() and self._build_default:
            self.elf = build_firmware()
        if not self.elf.is_file():
            raise BracketryError(f"firmware ELF not found: {self.elf} (build it: make -C firmware/stm32_trigger)")
        if self.serial == "tcp" and self.port is None:
            self.port = _free_port()
        if self._log_path is None:
            fd, name = tempfile.mkstemp(prefix="bracketry-qemu-", suffix=".log")
            os.close(fd)
            self._log_path = Path(name)
            self._tmp_log = self._log_path
        with open(self._log_path, "wb") as log:
            self.proc = subprocess.Popen(self.command(), stdin=subprocess.DEVNULL, stdout=log, stderr=log)
        try:
            self._wait_ready(timeout_s)
        except BaseException:
            self.stop()
            raise
        return self

    def _wait_ready(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        assert self.proc is not None and self._log_path is not None
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise BracketryError(f"qemu exited with code {self.proc.returncode}: {self.log_tail()}")
            if self.serial == "pty":
                m = _PTY_RE.search(self._log_path.read_text(errors="replace"))
                if m:
                    self.url = m.group(1)
                    return
            else:
                try:
                    # QEMU's server=on,wait=off socket: a probe connection, released at once (QEMU listens again)
                    with socket.create_connection(("127.0.0.1", int(self.port or 0)), timeout=0.5):
                        pass
                    self.url = f"socket://127.0.0.1:{self.port}"
                    time.sleep(0.1)
                    return
                except OSError:
                    pass
            time.sleep(0.05)
        raise BracketryError(f"qemu serial port not ready after {timeout_s:.0f} s: {self.log_tail()}")

    def log_tail(self, n_chars: int = 300) -> str:
        """Last characters of QEMU's stderr (one line)."""
        if self._log_path is None or not self._log_path.exists():
            return ""
        return " ".join(self._log_path.read_text(errors="replace")[-n_chars:].split())

    def stop(self) -> None:
        """Terminate QEMU (by its PID), then SIGKILL after 5 s; remove the temp log."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5.0)
        if self._tmp_log is not None:
            with contextlib.suppress(OSError):
                self._tmp_log.unlink()
            self._tmp_log = None

    def __enter__(self) -> QemuTrigger:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
