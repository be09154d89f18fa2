"""Output paths are checked before any work: existing file or non-empty folder, missing parent, not writable, a file
where a folder is expected. Used by the CLI option types (``bracketry_base.options``) and by library functions that
pick an output path themselves (``verify --repair``)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Literal

from bracketry_base.errors import BracketryError

Kind = Literal["file", "dir"]
Existing = Literal["refuse", "replace", "resume"]


def _writable_dir(folder: Path) -> bool:
    """True when a file can be created in ``folder`` (probed: os.access is wrong for root and for /proc)."""
    if not os.access(folder, os.W_OK | os.X_OK):
        return False
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".bracketry-probe-")
    except OSError:
        return False
    os.close(fd)
    os.unlink(probe)
    return True


def check_output(path: Path, kind: Kind = "file", *, overwrite: bool = False, existing: Existing = "refuse",
                 suffixes: tuple[str, ...] = (), what: str = "--out", parents: bool = False) -> Path:
    """Check an output path before any work; BracketryError with one line when it cannot or must not be written.

    kind ``file``: a file (not a folder) whose folder exists and is writable; an existing file needs ``overwrite``.
    kind ``dir``: a folder (not a file) whose parent exists; an existing non-empty folder needs ``overwrite``
    (``existing="resume"``: an existing folder is fine, the command resumes into it). ``existing="replace"``: the
    output is rewritten by design (a live status file) and never needs ``overwrite``. ``suffixes``: the allowed file
    name endings (lower case, with the dot). ``parents``: missing parent folders are fine (the program creates them,
    as the daemon does for its output_dir) when the nearest existing one is a writable folder. Nothing is created.
    """
    p = Path(path)
    if str(p) == "":
        raise BracketryError(f"{what}: empty path")
    if kind == "file":
        if p.is_dir():
            raise BracketryError(f"{what} {p} is a folder; expected a file")
        if suffixes and p.suffix.lower() not in suffixes:
            raise BracketryError(f"{what} {p}: expected a {' or '.join(suffixes)} file name")
        if (p.exists() or p.is_symlink()) and existing == "refuse" and not overwrite:
            raise BracketryError(f"{what} {p} exists (add --overwrite to replace it)")
        parent = p.parent
    else:
        if p.exists() and not p.is_dir():
            raise BracketryError(f"{what} {p} is a file; expected a folder")
        if p.is_dir():
            if existing == "refuse" and not overwrite and any(p.iterdir()):
                raise BracketryError(f"{what} {p} is not empty (add --overwrite to write into it)")
            if not _writable_dir(p):
                raise BracketryError(f"{what} {p}: folder is not writable")
            return p
        parent = p.parent
    if parents:
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
    if not parent.exists():
        raise BracketryError(f"{what} {p}: folder {parent} does not exist (create it first)")
    if not parent.is_dir():
        raise BracketryError(f"{what} {p}: {parent} is not a folder")
    if not _writable_dir(parent):
        raise BracketryError(f"{what} {p}: cannot write in {parent}")
    if kind == "file" and p.exists() and not os.access(p, os.W_OK):
        raise BracketryError(f"{what} {p}: file is not writable")
    return p
