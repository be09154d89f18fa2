"""Free-space checks of the recording disk."""

from __future__ import annotations

import shutil
from pathlib import Path


def free_mb(path: Path) -> int:
    """Free space (MiB) available to this user on the filesystem holding ``path`` (or its nearest parent)."""
    p = Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    return int(shutil.disk_usage(p).free // (1024 * 1024))
