"""Run a command inside a private network namespace (``unshare -n``) with extra loopback addresses.

Several fake cameras need one IP each (GVCP port 3956 is fixed), and Aravis discovery broadcasts on every interface:
both are safe only inside a namespace of our own, whose only interface is its own ``lo``. Needs root (or
CAP_SYS_ADMIN) and the ``unshare`` and ``ip`` tools.
"""

from __future__ import annotations

import functools
import shlex
import shutil
import subprocess


def netns_argv(argv: list[str], addresses: tuple[str, ...] = ("127.0.0.2", "127.0.0.3")) -> list[str]:
    """``argv`` wrapped so that it runs in a fresh network namespace with ``lo`` up and ``addresses`` on it."""
    setup = ["ip link set lo up"] + [f"ip addr add {shlex.quote(a)}/8 dev lo" for a in addresses]
    script = " && ".join(setup) + ' && exec "$@"'
    return ["unshare", "--net", "sh", "-c", script, "netns", *argv]


@functools.cache
def netns_available() -> str | None:
    """None when private namespaces work here, else the reason they do not."""
    for tool in ("unshare", "ip"):
        if shutil.which(tool) is None:
            return f"{tool} not found"
    try:
        res = subprocess.run(netns_argv(["true"]), capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"unshare failed: {exc}"
    if res.returncode != 0:
        return f"unshare -n failed (needs root): {res.stderr.strip()[:200]}"
    return None
