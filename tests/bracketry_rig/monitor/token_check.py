"""Run inside a private network namespace (``10.77.0.1`` on its ``lo``): a daemon whose monitor listens on that
non-loopback address, probed with no, a wrong and the right token. Prints one JSON object (the probes' results)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from bracketry.testing.http import http_json
from bracketry_rig.daemon.config import parse_config
from bracketry_rig.daemon.rig import RigDaemon

ADDRESS = "10.77.0.1"


def probe(url: str, token: str | None = None, body: dict[str, Any] | None = None) -> list[Any]:
    return list(http_json(url, body, token))


def main(work: Path) -> None:
    cfg = parse_config({
        "rig": {"output_dir": str(work / "rec"), "brackets_ms": [1, 2, 4], "fps": 20,
                "status_socket": str(work / "status.sock")},
        "panel": {"enabled": False},
        "monitor": {"listen": f"{ADDRESS}:8470"},
        "cameras": [{"side": "left", "profile": "aravis_fake", "address": "127.0.0.2"},
                    {"side": "right", "profile": "aravis_fake", "address": "127.0.0.3"}],
    })
    daemon = RigDaemon(cfg).start()
    try:
        token = daemon.monitor_server.token
        base = f"http://{ADDRESS}:8470"
        apply = {"action": "apply_brackets", "brackets_us": [500, 1000, 2000]}
        out = {
            "token": token, "message": daemon.state.snapshot().message,
            "page_none": probe(f"{base}/"), "page_wrong": probe(f"{base}/", "x" + token),
            "page_query": probe(f"{base}/?token={token}"),
            "status_none": probe(f"{base}/api/status"), "status_wrong": probe(f"{base}/api/status", token[:-1]),
            "status_right": probe(f"{base}/api/status", token),
            "apply_none": probe(f"{base}/api/action", None, apply),
            "apply_wrong": probe(f"{base}/api/action", token.upper(), apply),
            "apply_too_long": probe(f"{base}/api/action", token, {"action": "apply_brackets",
                                                                 "brackets_us": [1000, 49900]}),
            "apply_right": probe(f"{base}/api/action", token, apply),
            "brackets_after": list(daemon.config.brackets_us),
        }
        # the other actions on a rig whose devices are absent: sensors go ERR, a recording waits for them
        out["sensors_on"] = probe(f"{base}/api/action", token, {"action": "sensors_on"})
        out["sensors_on_status"] = probe(f"{base}/api/status", token)[1]["sensors"]
        out["record_start"] = probe(f"{base}/api/action", token, {"action": "record_start"})
        out["apply_recording"] = probe(f"{base}/api/action", token, apply)
        out["sensors_off_recording"] = probe(f"{base}/api/action", token, {"action": "sensors_off"})
        out["record_stop"] = probe(f"{base}/api/action", token, {"action": "record_stop"})
        out["sensors_off"] = probe(f"{base}/api/action", token, {"action": "sensors_off"})
        out["unknown"] = probe(f"{base}/api/action", token, {"action": "reboot"})
    finally:
        daemon.close()
    print(json.dumps(out))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
