"""The monitor's HTTP server (aiohttp, in a thread of its own with its own event loop).

Endpoints (JSON unless noted; documented in ``host/bracketry_rig/monitor/MONITOR.md``):

- ``GET /`` the page (``static/index.html``; its script and style come from ``/static/``, nothing from elsewhere);
- ``GET /api/status`` sensors, cameras, disk, recording;
- ``GET /api/previews`` per camera and bracket: exposure, histogram, over/under-exposed shares, preview URL;
- ``GET /api/preview/{side}/{bracket}.png`` the preview image (PNG);
- ``GET /api/advisor`` dynamic range, coverage and a suggested table (per camera and for the rig);
- ``GET /api/calibration`` a board capture's coverage and latest corners (``{"active": false}`` without one);
- ``GET /api/calibration/{side}.png`` the capture's latest preview of a camera (PNG);
- ``POST /api/action`` ``{"action": "sensors_on" | "sensors_off" | "record_start" | "record_stop" |
  "apply_brackets", "brackets_us": [...]}``: always needs the token.

The token goes in the ``X-Bracketry-Token`` header or the ``token`` query parameter. When the server listens on a
loopback address, reading needs no token; on any other address every request needs it (401 without, 403 wrong).
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import secrets
import threading
from dataclasses import dataclass
from importlib import resources
from typing import Any, Protocol

from aiohttp import web

from bracketry_base.errors import BracketryError
from bracketry_rig.monitor.address import is_loopback
from bracketry_rig.monitor.advisor import advise
from bracketry_rig.monitor.calibration_feed import CaptureFeed
from bracketry_rig.monitor.hub import PreviewHub

log = logging.getLogger("bracketry_rig.monitor")

STATIC_FILES = {"monitor.js": "text/javascript", "monitor.css": "text/css"}
ACTIONS = ("sensors_on", "sensors_off", "record_start", "record_stop", "apply_brackets")
#: token alphabet: no look-alike characters (read off a 20-character LCD and typed on a phone)
TOKEN_ALPHABET = "abcdefghjkmnpqrstuvwxyz23456789"


class ActionError(BracketryError):
    """An action the rig refuses; ``status`` is the HTTP status (409: not now, 400: bad request)."""

    def __init__(self, message: str, status: int = 409) -> None:
        super().__init__(message)
        self.status = status


class Backend(Protocol):
    """What the server needs from the rig (the daemon implements it)."""

    def monitor_status(self) -> dict[str, Any]: ...

    def monitor_action(self, action: str, body: dict[str, Any]) -> dict[str, Any]: ...

    def monitor_limits_us(self) -> tuple[tuple[int, ...], int, int]:
        """(current table, shortest allowed, longest allowed exposure), microseconds."""
        ...


def new_token(n: int = 10) -> str:
    """A random token of ``n`` characters from :data:`TOKEN_ALPHABET` (10 characters: 49 bits)."""
    return "".join(secrets.choice(TOKEN_ALPHABET) for _ in range(n))


@dataclass
class _Ctx:
    backend: Backend
    hub: PreviewHub
    token: str
    read_needs_token: bool
    calibration: CaptureFeed | None = None


class MonitorServer:
    """Serve the monitor of ``backend`` on ``host:port``; :meth:`start` raises BracketryError if it cannot listen."""

    def __init__(self, backend: Backend, hub: PreviewHub, host: str, port: int, token: str | None = None,
                 calibration: CaptureFeed | None = None) -> None:
        self.host, self.port = host, port
        self.token = token or new_token()
        self._ctx = _Ctx(backend, hub, self.token, not is_loopback(host), calibration)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._runner: web.AppRunner | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None

    @property
    def url(self) -> str:
        """The page's URL with the token."""
        return f"http://{self.host}:{self.port}/?token={self.token}"

    def start(self) -> MonitorServer:
        self._thread = threading.Thread(target=self._serve, name="monitor-http", daemon=True)
        self._thread.start()
        self._ready.wait(15.0)
        if self._error is not None:
            raise BracketryError(f"monitor cannot listen on {self.host}:{self.port}: {self._error}")
        return self

    def _serve(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._setup())
        except BaseException as exc:
            self._error = exc
            self._ready.set()
            loop.close()
            return
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            if self._runner is not None:
                loop.run_until_complete(self._runner.cleanup())
            loop.close()

    async def _setup(self) -> None:
        app = make_app(self._ctx)
        self._runner = web.AppRunner(app, access_log=None)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port, reuse_address=True)
        await site.start()
        if self.port == 0:  # the port the system chose (tests)
            server = getattr(site, "_server", None)
            if server is not None and server.sockets:
                self.port = server.sockets[0].getsockname()[1]

    def close(self) -> None:
        if self._loop is not None and self._thread is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=5.0)


def make_app(ctx: _Ctx) -> web.Application:
    """The aiohttp application (routes and the token check)."""

    @web.middleware
    async def guard(request: web.Request, handler: Any) -> web.StreamResponse:
        needs = ctx.read_needs_token or request.method != "GET"
        if needs:
            given = request.headers.get("X-Bracketry-Token") or request.query.get("token")
            if not given:
                return web.json_response({"error": "token required"}, status=401)
            if not hmac.compare_digest(given.encode(), ctx.token.encode()):
                return web.json_response({"error": "wrong token"}, status=403)
        resp = await handler(request)
        resp.headers["Cache-Control"] = "no-store"
        return resp

    app = web.Application(middlewares=[guard], client_max_size=64 * 1024)
    static = resources.files("bracketry_rig.monitor") / "static"

    async def index(_request: web.Request) -> web.Response:
        return web.Response(text=(static / "index.html").read_text(encoding="utf-8"), content_type="text/html")

    async def static_file(request: web.Request) -> web.Response:
        name = request.match_info["name"]
        if name not in STATIC_FILES:
            raise web.HTTPNotFound()
        return web.Response(text=(static / name).read_text(encoding="utf-8"), content_type=STATIC_FILES[name])

    async def status(_request: web.Request) -> web.Response:
        data = ctx.backend.monitor_status()
        data["monitor"] = {"previews_rendered": ctx.hub.rendered, "previews_dropped": ctx.hub.dropped,
                           "render_ms_total": round(ctx.hub.render_s * 1000.0, 1),
                           "token_for_reading": ctx.read_needs_token}
        return web.json_response(data)

    async def previews(_request: web.Request) -> web.Response:
        out: dict[str, list[dict[str, Any]]] = {}
        for (side, bracket), p in sorted(ctx.hub.latest().items()):
            out.setdefault(side, []).append({
                "bracket": bracket, "exposure_us": p.exposure_us, "t_ns": p.t_ns, "version": p.version,
                "width": p.width, "height": p.height, "histogram": list(p.histogram),
                "over": round(p.over, 4), "under": round(p.under, 4),
                "url": f"/api/preview/{side}/{bracket}.png?v={p.version}"})
        return web.json_response({"cameras": out})

    async def preview_png(request: web.Request) -> web.Response:
        side = request.match_info["side"]
        try:
            bracket = int(request.match_info["bracket"])
        except ValueError:
            raise web.HTTPNotFound() from None
        p = ctx.hub.latest().get((side, bracket))
        if p is None:
            raise web.HTTPNotFound()
        return web.Response(body=p.png, content_type="image/png")

    async def advisor(_request: web.Request) -> web.Response:
        loop = asyncio.get_running_loop()
        return web.json_response(await loop.run_in_executor(None, advisor_report, ctx.backend, ctx.hub))

    async def calibration(_request: web.Request) -> web.Response:
        feed = ctx.calibration
        return web.json_response({"active": False} if feed is None else feed.snapshot())

    async def calibration_png(request: web.Request) -> web.Response:
        png = None if ctx.calibration is None else ctx.calibration.preview_png(request.match_info["side"])
        if png is None:
            raise web.HTTPNotFound()
        return web.Response(body=png, content_type="image/png")

    async def action(request: web.Request) -> web.Response:
        try:
            body = await request.json()
        except ValueError:
            return web.json_response({"ok": False, "error": "body must be JSON"}, status=400)
        if not isinstance(body, dict) or body.get("action") not in ACTIONS:
            return web.json_response({"ok": False, "error": f"action must be one of {', '.join(ACTIONS)}"},
                                     status=400)
        loop = asyncio.get_running_loop()
        try:
            result = await loop.run_in_executor(None, ctx.backend.monitor_action, str(body["action"]), body)
        except ActionError as exc:
            return web.json_response({"ok": False, "error": str(exc)}, status=exc.status)
        log.info("monitor action %s from %s", body["action"], request.remote)
        return web.json_response({"ok": True, **result})

    app.router.add_get("/", index)
    app.router.add_get("/static/{name}", static_file)
    app.router.add_get("/api/status", status)
    app.router.add_get("/api/previews", previews)
    app.router.add_get("/api/preview/{side}/{bracket}.png", preview_png)
    app.router.add_get("/api/advisor", advisor)
    app.router.add_get("/api/calibration", calibration)
    app.router.add_get("/api/calibration/{side}.png", calibration_png)
    app.router.add_post("/api/action", action)
    return app


def advisor_report(backend: Backend, hub: PreviewHub) -> dict[str, Any]:
    """Advice per camera and for the rig (both cameras' pixels) from the latest preview of every current bracket."""
    table, min_us, max_us = backend.monitor_limits_us()
    latest = hub.latest()
    out: dict[str, Any] = {"brackets_us": list(table), "min_us": min_us, "max_us": max_us, "cameras": {}}
    rig_lums: list[list[Any]] = [[] for _ in table]
    sides = sorted({side for side, _ in latest})
    for side in sides:
        frames = [latest.get((side, i)) for i in range(len(table))]
        if any(p is None or p.exposure_us != table[i] for i, p in enumerate(frames)):
            continue  # not every bracket of the current table seen yet
        lums = [p.lum for p in frames if p is not None]
        a = advise(list(table), lums, min_us=min_us, max_us=max_us, white_dn=hub.white_dn)
        out["cameras"][side] = _advice_json(a)
        for i, lum in enumerate(lums):
            rig_lums[i].append(lum.ravel())
    if out["cameras"]:
        import numpy as np

        lums = [np.concatenate(parts) for parts in rig_lums]
        out["rig"] = _advice_json(advise(list(table), lums, min_us=min_us, max_us=max_us, white_dn=hub.white_dn))
    else:
        out["rig"] = None
    return out


def _advice_json(a: Any) -> dict[str, Any]:
    return {"dynamic_range_stops": a.dynamic_range_stops, "coverage": a.coverage,
            "suggested_us": list(a.suggested_us), "suggested_coverage": a.suggested_coverage,
            "clipped_share": a.clipped_share}
