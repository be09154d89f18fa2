"""The monitor page in a real browser: ``bracketry simulate --monitor PORT`` serves the simulated rig's page, Debian's
headless Chromium renders it, and the test asserts on the rendered page (both cameras' previews, sensor states,
values that update) and keeps a screenshot (``build/test-artifacts/monitor_page.png``, or ``$BRACKETRY_ARTIFACTS``).
The actions' token checks are exercised against the same daemon."""

from __future__ import annotations

import asyncio
import json
import os
import re
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from typing import Any

import aiohttp
import cv2
import numpy as np
import pytest
from monitor_chromium import Chromium, Page, chromium_path

from bracketry.testing.http import http_json as http
from bracketry_base.paths import repo_root
from bracketry_rig.cameras.netns import netns_available
from bracketry_rig.monitor.core import UNDER_RGB
from bracketry_testkit import missing_component

pytestmark = [pytest.mark.aravis, pytest.mark.socat, pytest.mark.chromium, pytest.mark.slow]
REPO = repo_root()
N_BRACKETS = 6


def artifacts_dir() -> Path:
    return Path(os.environ.get("BRACKETRY_ARTIFACTS", REPO / "build" / "test-artifacts"))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_line(path: Path, pattern: str, proc: subprocess.Popen, timeout_s: float) -> re.Match[str]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        m = re.search(pattern, path.read_text(errors="replace")) if path.exists() else None
        if m:
            return m
        assert proc.poll() is None, f"simulate exited early: {path.read_text()[-3000:]}"
        time.sleep(0.3)
    raise AssertionError(f"timeout waiting for {pattern!r}: {path.read_text()[-3000:]}")


PREVIEWS_LOADED = ("(() => { const ok = (s) => [...document.querySelectorAll('#cam-' + s + ' .bracket img')]"
                   ".filter((i) => i.complete && i.naturalWidth > 0).length; return [ok('left'), ok('right')]; })()")


async def drive_page(url: str, chromium: Chromium, shot: Path) -> dict[str, Any]:
    async with aiohttp.ClientSession() as session, session.ws_connect(chromium.page_ws_url(),
                                                                       max_msg_size=0) as ws:
        page = Page(ws)
        await page.call("Page.enable")
        await page.call("Page.navigate", url=url)
        await page.wait_for(f"(() => {{ const n = {PREVIEWS_LOADED}; return n[0] === {N_BRACKETS} && "
                            f"n[1] === {N_BRACKETS}; }})()", 60)
        await page.wait_for("document.getElementById('state-cam_left')?.textContent.includes('REC') && "
                            "document.getElementById('state-cam_right')?.textContent.includes('REC')", 20)
        await page.wait_for("document.getElementById('advice').textContent.includes('stops')", 20)
        first = await page.evaluate("[Number(document.getElementById('updated').dataset.count), "
                                    "Number(document.querySelector('#cam-left .camstat').dataset.frames), "
                                    "document.getElementById('rec').textContent]")
        await asyncio.sleep(3.0)
        second = await page.evaluate("[Number(document.getElementById('updated').dataset.count), "
                                     "Number(document.querySelector('#cam-left .camstat').dataset.frames), "
                                     "document.getElementById('rec').textContent]")
        texts = await page.evaluate("({cams: [...document.querySelectorAll('.camstat')].map((e) => e.textContent),"
                                    " advice: document.getElementById('advice').textContent,"
                                    " caption: document.querySelector('#cam-right .bracket .cap').textContent,"
                                    " apply: document.getElementById('apply').disabled})")
        png = await page.screenshot(shot)
        # the page's own button: applying the suggested table while recording is refused by the rig
        await page.evaluate("document.getElementById('apply').click()")
        refused = await page.wait_for("(() => { const t = document.getElementById('action-result').textContent; "
                                      "return t.includes('apply_brackets:') && t; })()", 20)
        return {"first": first, "second": second, "texts": texts, "png": png, "refused": refused}


def test_monitor_page_in_headless_chromium(tmp_path: Path) -> None:
    reason = netns_available()
    if reason:
        missing_component(f"private network namespace unavailable: {reason}")
    if chromium_path() is None:
        missing_component("chromium not found (apt-get install chromium, or ./setup.sh)")
    port = free_port()
    out, log = tmp_path / "sim", tmp_path / "simulate.log"
    with open(log, "wb") as log_f:
        sim = subprocess.Popen([sys.executable, "-m", "bracketry", "simulate", "--seconds", "45", "--out", str(out),
                                "--monitor", str(port), "--no-world", "--resolution", "320x200", "--fps", "10"],
                               stdin=subprocess.DEVNULL, stdout=log_f, stderr=subprocess.STDOUT)
    chromium = None
    try:
        m = wait_line(log, r"monitor: (http://127\.0\.0\.1:\d+/\?token=(\w+))", sim, 180)
        url, token = m.group(1), m.group(2)
        base = f"http://127.0.0.1:{port}"
        wait_line(log, r"L:REC R:REC TRIG:REC", sim, 90)
        chromium = Chromium(tmp_path)
        shot = artifacts_dir() / "monitor_page.png"
        got = asyncio.run(drive_page(url, chromium, shot))

        # values update without reloading: the page polled again and the frame counter moved
        assert got["second"][0] > got["first"][0] and got["second"][1] > got["first"][1], got["texts"]
        assert got["first"][2].startswith("REC"), got["first"]
        cams = got["texts"]["cams"]
        assert all(re.match(r"REC · [\d.]+ fps · frames \d+ · drops \d+ · ", t) for t in cams), cams
        assert "ms · sat" in got["texts"]["caption"] and "covers" in got["texts"]["advice"], got["texts"]
        assert got["texts"]["apply"] is False  # the page has the token
        assert "stop it before changing the bracket table" in got["refused"], got["refused"]
        img = cv2.imdecode(np.frombuffer(got["png"], np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
        assert img.shape[0] >= 600 and img.shape[1] >= 1000
        assert np.all(img == np.array(UNDER_RGB, np.uint8), axis=-1).sum() > 500  # under-exposed marks rendered

        # the endpoints the page uses
        code, status = http(f"{base}/api/status")
        assert code == 200 and status["recording"]["active"] and status["cameras"]["left"]["frames"] > 0
        assert status["monitor"]["previews_rendered"] >= 2 * N_BRACKETS
        with urllib.request.urlopen(f"{base}/api/preview/left/0.png", timeout=10) as r:
            assert r.headers["Content-Type"] == "image/png" and r.read(8) == b"\x89PNG\r\n\x1a\n"
        # actions need the token; the bracket table never changes while recording
        table = {"action": "apply_brackets", "brackets_us": [500, 1000, 2000, 4000, 8000, 16000]}
        assert http(f"{base}/api/action", table)[0] == 401
        assert http(f"{base}/api/action", table, token="x" + token)[0] == 403
        code, reply = http(f"{base}/api/action", table, token=token)
        assert code == 409 and "recording" in reply["error"], reply
        assert http(f"{base}/api/status")[1]["brackets_us"] == [1000, 2000, 4000, 8000, 16000, 32000]

        # the run ends normally (exit 1 = verify found drops: the fake cameras miss software triggers when the
        # machine is overloaded, with or without a page open; the monitor benchmark compares the rates)
        assert sim.wait(timeout=150) in (0, 1), log.read_text()[-3000:]
        assert json.loads((out / "simulation.json").read_text())["recordings"]
    finally:
        if chromium is not None:
            chromium.close()
        if sim.poll() is None:
            sim.terminate()
            sim.wait(timeout=60)
