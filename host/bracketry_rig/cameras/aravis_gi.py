"""The one import point of Aravis 0.8 through PyGObject (GObject introspection).

``load_aravis()`` returns the ``Aravis`` module or raises ``MissingComponentError`` with the fix (Debian package
``gir1.2-aravis-0.8`` and the Python package PyGObject<3.51, extra ``host``).
"""

from __future__ import annotations

import functools
from typing import Any

from bracketry_base.errors import BracketryError, MissingComponentError


class CameraError(BracketryError):
    """A camera cannot be opened, configured or streamed; the message names the camera and the cause."""


@functools.cache
def load_aravis() -> Any:
    """Import ``gi.repository.Aravis`` (version 0.8) once."""
    try:
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis
    except ImportError as exc:
        raise MissingComponentError(
            f"Aravis through PyGObject is unavailable ({exc}); install PyGObject<3.51 (pip install -e '.[host]')"
        ) from exc
    except ValueError as exc:
        raise MissingComponentError(
            f"the Aravis 0.8 typelib is missing ({exc}); install the Debian package gir1.2-aravis-0.8"
        ) from exc
    return Aravis


def glib_error_message(exc: Exception) -> str:
    """A one-line message from a GLib.Error (or any exception)."""
    message = getattr(exc, "message", None)
    return str(message if message else exc).strip().splitlines()[0] if str(exc) else type(exc).__name__
