"""The daemon's status over a local UNIX socket: one JSON request line, one JSON reply line.

Requests: ``{"cmd": "status"}`` returns the state snapshot; ``{"cmd": "button", "button": "sensors"|"record"}``
acts as a panel button press (for operators without a panel and for tests). The socket file is created with mode
0660 and removed on close.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bracketry_base.errors import BracketryError

Handler = Callable[[dict[str, Any]], dict[str, Any]]


class StatusServer:
    """Serves requests on ``path`` in a background thread; ``handler`` maps a request dict to a reply dict."""

    def __init__(self, path: Path, handler: Handler) -> None:
        self.path = Path(path)
        self._handler = handler
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.exists() or self.path.is_symlink():
            self.path.unlink()
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._sock.bind(str(self.path))
        os.chmod(self.path, 0o660)
        self._sock.listen(8)
        self._sock.settimeout(0.5)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="status-socket", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            with conn:
                conn.settimeout(2.0)
                try:
                    line = _read_line(conn)
                    request = json.loads(line)
                    if not isinstance(request, dict):
                        raise ValueError("request must be a JSON object")
                    reply = self._handler(request)
                except (ValueError, OSError) as exc:
                    reply = {"ok": False, "error": str(exc)}
                except Exception as exc:  # the daemon must survive any bad request
                    reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
                with contextlib.suppress(OSError):
                    conn.sendall((json.dumps(reply) + "\n").encode())

    def close(self) -> None:
        """Stop serving and remove the socket file."""
        self._stop.set()
        self._sock.close()
        self._thread.join(timeout=2.0)
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()


def _read_line(conn: socket.socket, limit: int = 65536) -> str:
    data = b""
    while not data.endswith(b"\n"):
        chunk = conn.recv(4096)
        if not chunk:
            break
        data += chunk
        if len(data) > limit:
            raise ValueError("request too long")
    return data.decode()


def query(path: Path, request: dict[str, Any], timeout_s: float = 3.0) -> dict[str, Any]:
    """Send one request to a running daemon and return its reply; BracketryError if none is listening."""
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.settimeout(timeout_s)
            s.connect(str(path))
            s.sendall((json.dumps(request) + "\n").encode())
            reply = json.loads(_read_line(s))
    except (FileNotFoundError, ConnectionRefusedError):
        raise BracketryError(f"no daemon is listening on {path} (is `bracketry daemon` running?)") from None
    except (OSError, ValueError) as exc:
        raise BracketryError(f"status socket {path}: {exc}") from None
    if not isinstance(reply, dict):
        raise BracketryError(f"status socket {path}: unexpected reply {reply!r}")
    return reply
