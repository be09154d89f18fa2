"""The board capture on the monitor page in headless Chromium (#35): a capture fed from a rendered board session
serves its state; the page shows the latest pair with its corners drawn, the four coverage bars as they fill, and
says when the set is enough. A screenshot is kept (``build/test-artifacts/monitor_calibration.png``)."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path
from typing import Any

import aiohttp
import cv2
import numpy as np
import pytest
from monitor_chromium import Chromium, Page, chromium_path

from bracketry_base.calibration.board import BoardSpec
from bracketry_base.calibration.detect import detect, to_gray8
from bracketry_base.paths import repo_root
from bracketry_emulator.synth.board_session import render_session
from bracketry_emulator.synth.calibration import default_calibration
from bracketry_rig.boardcapture.selection import FolderBackend as _FolderBackend
from bracketry_rig.monitor.calibration_feed import CaptureFeed
from bracketry_rig.monitor.hub import PreviewHub
from bracketry_rig.monitor.server import MonitorServer
from bracketry_testkit import missing_component

pytestmark = [pytest.mark.chromium]

STATE = ("(() => { const c = document.getElementById('calibration'); const bars = {}; "
         "for (const b of document.querySelectorAll('#cal-bars .bar')) bars[b.dataset.param] = "
         "Number(b.dataset.value || 0); return {hidden: c.hidden, kept: Number(c.dataset.kept || -1), "
         "enough: c.dataset.enough, badge: document.getElementById('cal-enough').textContent, bars: bars, "
         "advice: document.getElementById('cal-advice').textContent, "
         "info: document.getElementById('cal-info').textContent, "
         "corners: [Number(document.getElementById('cal-left').dataset.corners || 0), "
         "Number(document.getElementById('cal-right').dataset.corners || 0)]}; })()")


async def _drive(url: str, chromium: Chromium, feed: CaptureFeed, pairs: list[Any], shot: Path) -> dict[str, Any]:
    async with aiohttp.ClientSession() as session, session.ws_connect(chromium.page_ws_url(),
                                                                       max_msg_size=0) as ws:
        page = Page(ws)
        await page.call("Page.enable")
        await page.call("Page.navigate", url=url)
        await page.wait_for("document.getElementById('calibration') && "
                            "!document.getElementById('calibration').hidden", 30)
        first_half = len(pairs) // 3
        for grays, dets in pairs[:first_half]:
            feed.offer(grays, dets)
        kept = len(feed.coverage.kept)
        await page.wait_for(f"Number(document.getElementById('calibration').dataset.kept) === {kept}", 20)
        early = await page.evaluate(STATE)
        for grays, dets in pairs[first_half:]:
            feed.offer(grays, dets)
        kept = len(feed.coverage.kept)
        await page.wait_for(f"Number(document.getElementById('calibration').dataset.kept) === {kept} && "
                            "Number(document.getElementById('cal-left').dataset.version) === "
                            f"{feed.snapshot()['version']}", 20)
        late = await page.evaluate(STATE)
        await page.screenshot(shot)
        return {"early": early, "late": late}


def test_capture_coverage_on_the_monitor_page(tmp_path: Path) -> None:
    if chromium_path() is None:
        missing_component("chromium not found (apt-get install chromium, or ./setup.sh)")
    board = BoardSpec()
    calib = default_calibration(640, 400)
    _views, frames = render_session(board, calib, 8, 24)
    pairs = []
    for left, right in frames:
        grays = (to_gray8(left), to_gray8(right))
        pairs.append((grays, (detect(grays[0], board), detect(grays[1], board))))
    last_seen = next(k for k in range(len(pairs) - 1, -1, -1) if all(d is not None for d in pairs[k][1]))
    pairs.append(pairs[last_seen])  # the stream ends on a pair with the board in both images (a near-duplicate)
    feed = CaptureFeed(board, calib.size)
    server = MonitorServer(_FolderBackend(tmp_path), PreviewHub(), "127.0.0.1", 0, calibration=feed).start()
    chromium = None
    try:
        chromium = Chromium(tmp_path)
        shot = Path(os.environ.get("BRACKETRY_ARTIFACTS", repo_root() / "build" / "test-artifacts"))
        shot.mkdir(parents=True, exist_ok=True)
        got = asyncio.run(_drive(server.url, chromium, feed, pairs, shot / "monitor_calibration.png"))
    finally:
        if chromium is not None:
            chromium.close()
        server.close()
    early, late = got["early"], got["late"]
    assert not early["hidden"] and early["kept"] >= 1
    assert set(late["bars"]) == {"x", "y", "size", "skew"}
    assert all(late["bars"][k] >= early["bars"][k] for k in late["bars"]) and sum(late["bars"].values()) > sum(
        early["bars"].values())
    final = feed.snapshot()
    assert late["bars"] == pytest.approx(final["bars"], abs=1e-9) and late["kept"] == final["kept"]
    # the last pair's corners are drawn on both previews, counted as the detector found them
    dets = pairs[-1][1]
    assert late["corners"] == [dets[0].n, dets[1].n]
    assert "too close" in late["info"]
    assert (late["enough"] == "true") == final["enough"]
    assert late["badge"] == ("ENOUGH" if final["enough"] else f"{final['kept']} kept")
    assert late["advice"] == final["advice"]
    img = cv2.imread(str(shot / "monitor_calibration.png"))
    assert img is not None and img.shape[1] >= 1000
    assert np.all(img == (51, 255, 51), axis=-1).sum() + np.all(img == (51, 170, 255), axis=-1).sum() > 100
