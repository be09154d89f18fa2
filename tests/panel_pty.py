"""Pseudo-terminal helpers for the panel's end-to-end tests: a pty whose slave path a simulator opens, and a relay
between two ptys that can drop chosen host->panel frames (a lossy cable)."""

from __future__ import annotations

import contextlib
import os
import select
import subprocess
import sys
import termios
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path

from bracketry_rig.wire import bproto


class Pty:
    """A pty: the test keeps ``master`` (and the slave open, so the other side may close and reopen ``path``)."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave, termios.TCSANOW)
        self.path = os.ttyname(self.slave)
        os.set_blocking(self.master, False)

    def read(self, timeout_s: float = 0.05) -> bytes:
        r, _w, _x = select.select([self.master], [], [], timeout_s)
        if not r:
            return b""
        try:
            return os.read(self.master, 4096)
        except (BlockingIOError, OSError):
            return b""

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.master, view)
            except BlockingIOError:
                time.sleep(0.005)
                continue
            view = view[n:]

    def close(self) -> None:
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)


class PtyRelay:
    """Two ptys joined by a thread: the panel opens ``panel_path``, the host ``host_path``.

    ``drop(frame) -> bool`` sees every complete host->panel frame (bytes incl. the 0x00) and drops it when True.
    """

    def __init__(self, drop: Callable[[bytes], bool] | None = None) -> None:
        self.panel = Pty()
        self.host = Pty()
        self.drop = drop
        self.dropped: list[bytes] = []
        self._pending = b""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="pty-relay")
        self._thread.start()

    @property
    def panel_path(self) -> str:
        return self.panel.path

    @property
    def host_path(self) -> str:
        return self.host.path

    def _host_to_panel(self, data: bytes) -> None:
        if self.drop is None:
            self.panel.write(data)
            return
        self._pending += data
        out = b""
        while True:
            z = self._pending.find(b"\x00")
            if z < 0:
                break
            frame, self._pending = self._pending[:z + 1], self._pending[z + 1:]
            if self.drop(frame):
                self.dropped.append(frame)
            else:
                out += frame
        if out:
            self.panel.write(out)

    def _run(self) -> None:
        fds = [self.panel.master, self.host.master]
        while not self._stop.is_set():
            try:
                r, _w, _x = select.select(fds, [], [], 0.05)
            except (OSError, ValueError):
                return
            for fd in r:
                try:
                    data = os.read(fd, 4096)
                except (BlockingIOError, OSError):
                    continue
                if not data:
                    continue
                if fd == self.panel.master:
                    self.host.write(data)
                else:
                    self._host_to_panel(data)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.panel.close()
        self.host.close()


def first_ack_dropper() -> Callable[[bytes], bool]:
    """A ``drop`` function that loses exactly the first ACK the host sends."""
    state = {"left": 1}

    def drop(frame: bytes) -> bool:
        try:
            fr = bproto.decode_frame(frame)
        except ValueError:
            return False
        if fr is not None and fr.msg_type == bproto.MSG_ACK and state["left"] > 0:
            state["left"] -= 1
            return True
        return False

    return drop


def start_simulator(link_path: str, screen_file: Path) -> subprocess.Popen[str]:
    """``bracketry panel simulate --link PATH --screen-file FILE --quiet`` as a child with a stdin pipe."""
    return subprocess.Popen([sys.executable, "-m", "bracketry", "panel", "simulate", "--link", link_path,
                             "--screen-file", str(screen_file), "--quiet"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def read_screen(screen_file: Path) -> list[str] | None:
    """The simulator's screen file as 4 lines, or None before it exists."""
    try:
        text = screen_file.read_text()
    except FileNotFoundError:
        return None
    return text.split("\n")[:-1] if text.endswith("\n") else text.split("\n")


def wait_for(pred: Callable[[], object], timeout_s: float = 20.0, step_s: float = 0.05) -> bool:
    """Poll ``pred`` until truthy or ``timeout_s``; returns whether it became true."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(step_s)
    return bool(pred())
