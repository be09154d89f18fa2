"""One JSON-over-HTTP call for the harnesses and tests that drive the monitor's endpoints (see
``host/bracketry_rig/monitor/MONITOR.md``)."""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from typing import Any

#: the header the monitor reads its token from
TOKEN_HEADER = "X-Bracketry-Token"


def http_json(url: str, body: dict[str, Any] | None = None, token: str | None = None,
              timeout_s: float = 10.0) -> tuple[int, Any]:
    """GET ``url`` (or POST ``body`` as JSON) with ``token``; returns (HTTP status, the JSON answer or None when the
    answer is not JSON). Error statuses are returned, not raised."""
    headers = {"Content-Type": "application/json", **({TOKEN_HEADER: token} if token is not None else {})}
    req = urllib.request.Request(url, data=json.dumps(body).encode() if body is not None else None, headers=headers)
    try:
        with urllib.request.urlopen(req, timeout=timeout_s) as r:
            raw = r.read()
            is_json = (r.headers.get("Content-Type") or "").startswith("application/json")
            return r.status, json.loads(raw) if is_json else None
    except urllib.error.HTTPError as exc:
        raw = exc.read()
        try:
            return exc.code, json.loads(raw)
        except ValueError:
            return exc.code, None
