"""The browser monitor's CPU cost, and the recording rate of the simulated rig with and without a page open.

Usage: .venv/bin/python benchmarks/bench_monitor.py [--seconds S] [--repeats N] [--screenshot PNG] [--no-world]

1. Preview path at the rig's resolution (1920x1200 12-bit RGGB, a smooth scene with noise), medians over repeats:
   ``PreviewHub.offer`` per paired set (the only work on the pairing thread), one preview render (demosaic,
   exposure marks, luminance, histogram, shares, PNG) and one advisor report (6 brackets x 2 cameras); the share of
   one core the preview worker needs at the default rate (1 preview per second per camera and bracket: 12/s).
2. The whole simulated rig (``bracketry simulate``, fake cameras, trigger simulator, panel firmware), side by side in
   one run: *off* (no ``--monitor``) and *page open* (``--monitor`` and a headless Chromium page polling it).
   Per run: frames recorded per second and drops (from ``verify``), and the daemon's CPU use while recording
   (its process CPU seconds per wall second, from /proc, over the recording minus its first 2 s and last 1 s).
   Chromium's own CPU is not counted (in the field the browser runs on the operator's phone).

``--screenshot`` keeps the page-open run's screenshot (the README's figure).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from bracketry_base import paths
from bracketry_rig.monitor.hub import PreviewHub
from bracketry_rig.monitor.server import advisor_report

ROOT = paths.repo_root()
sys.path.insert(0, str(ROOT / "tests" / "bracketry_rig" / "monitor"))
WIDTH, HEIGHT = 1920, 1200
BRACKETS_US = (1000, 2000, 4000, 8000, 16000, 32000)


def scene_frame(exposure_us: int, rng: np.random.Generator) -> np.ndarray:
    """A smooth 12-stop scene seen at one exposure: RGGB mosaic, 12-bit codes with shot and read noise."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    radiance = 0.002 * 2.0 ** (12.0 * x / WIDTH) * (0.7 + 0.3 * np.sin(y / 37.0))
    dn = radiance * exposure_us
    dn = dn + rng.normal(0.0, 1.0, dn.shape).astype(np.float32) * np.sqrt(dn + 4.0)
    return np.clip(dn, 0, 4095).astype(np.uint16)


class _Backend:
    def monitor_limits_us(self) -> tuple[tuple[int, ...], int, int]:
        return BRACKETS_US, 10, 45_254


def bench_previews(repeats: int) -> dict[str, float]:
    from bracketry_rig.cameras.camera import Frame
    from bracketry_rig.events import TriggerEvent
    from bracketry_rig.pairing.pairer import PairedSet

    rng = np.random.default_rng(0)
    frames = [scene_frame(e, rng) for e in BRACKETS_US]
    hub = PreviewHub(rate_hz=1.0, max_items=8)
    offer_us = []
    for k in range(2000):  # pairing-thread cost: the rate limit rejects most sets, as on the rig (22 sets/s)
        b = k % 6
        ev = TriggerEvent(1, k, b, BRACKETS_US[b], k * 45_454, time.time_ns())
        fr = {s: Frame(s, k + 1, k, 0, "success", frames[b], WIDTH, HEIGHT, "BayerRG12p", 0, 0)
              for s in ("left", "right")}
        pset = PairedSet(k, ev, fr, time.time_ns())
        t0 = time.perf_counter()
        hub.offer(pset)
        offer_us.append((time.perf_counter() - t0) * 1e6)
        if k % 64 == 63:
            hub.drain()
    render_ms = []
    for r in range(repeats * 6):
        img = frames[r % 6]
        t0 = time.perf_counter()
        hub.add_image("left", r % 6, BRACKETS_US[r % 6], img)
        hub.add_image("right", r % 6, BRACKETS_US[r % 6], img)
        hub.drain()
        render_ms.append((time.perf_counter() - t0) * 1e3 / 2)
    advisor_ms = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        report = advisor_report(_Backend(), hub)
        advisor_ms.append((time.perf_counter() - t0) * 1e3)
    assert report["rig"] is not None
    render = statistics.median(render_ms)
    return {"offer_us": statistics.median(offer_us), "render_ms": render, "advisor_ms": statistics.median(advisor_ms),
            "worker_core_share": 12 * render / 1000.0, "rig_advice_stops": report["rig"]["dynamic_range_stops"]}


def _cpu_s(pid: int) -> float | None:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_rig(work: Path, seconds: float, world: bool, page: bool, screenshot: Path | None) -> dict[str, Any]:
    out, log = work / ("page" if page else "off"), work / ("page.log" if page else "off.log")
    argv = [sys.executable, "-m", "bracketry", "simulate", "--seconds", str(seconds), "--out", str(out),
            "--resolution", "640x400", "--fps", "10", *([] if world else ["--no-world"])]
    port = None
    if page:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = int(s.getsockname()[1])
        argv += ["--monitor", str(port)]
    samples: list[tuple[float, float]] = []
    rec_t: list[float] = []
    chromium = None
    with open(log, "wb") as log_f:
        sim = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log_f, stderr=subprocess.STDOUT)
    try:
        pid = None
        url = None
        page_thread = None
        while sim.poll() is None:
            text = log.read_text(errors="replace")
            if pid is None and (m := re.search(r"daemon: running \(pid (\d+)\)", text)):
                pid = int(m.group(1))
            if url is None and (m := re.search(r"monitor: (http://\S+)", text)):
                url = m.group(1)
            if not rec_t and "L:REC R:REC TRIG:REC" in text:
                rec_t.append(time.monotonic())
                if page and url:
                    from monitor_chromium import Chromium

                    chromium = Chromium(work / "chromium")
                    page_thread = threading.Thread(target=asyncio.run,
                                                   args=(_hold_page(chromium, url, seconds, screenshot),))
                    page_thread.start()
            if pid is not None and rec_t:
                cpu = _cpu_s(pid)
                if cpu is not None:
                    samples.append((time.monotonic(), cpu))
            time.sleep(0.25)
        if page_thread is not None:
            page_thread.join(timeout=60)
    finally:
        if chromium is not None:
            chromium.close()
        if sim.poll() is None:
            sim.terminate()
            sim.wait(timeout=60)
    summary = json.loads((out / "simulation.json").read_text())
    recorded_s = float(summary["session"]["recorded_s"])
    frames = {s: sum(v["sides"][s]["frames"] for v in summary["verify"] if s in v["sides"]) for s in ("left", "right")}
    drops = {s: sum(v["sides"][s]["drops"] for v in summary["verify"] if s in v["sides"]) for s in ("left", "right")}
    t0, t1 = rec_t[0] + 2.0, rec_t[0] + seconds - 1.0
    window = [(t, c) for t, c in samples if t0 <= t <= t1]
    cpu_share = (window[-1][1] - window[0][1]) / (window[-1][0] - window[0][0]) if len(window) > 1 else float("nan")
    return {"fps": {s: frames[s] / recorded_s for s in frames}, "drops": drops, "daemon_cpu": cpu_share}


async def _hold_page(chromium: Any, url: str, seconds: float, screenshot: Path | None) -> None:
    import aiohttp
    from monitor_chromium import Page

    async with aiohttp.ClientSession() as session, session.ws_connect(chromium.page_ws_url(), max_msg_size=0) as ws:
        page = Page(ws)
        await page.call("Page.enable")
        await page.call("Page.navigate", url=url)
        await asyncio.sleep(min(seconds - 2.0, 12.0))
        if screenshot is not None:
            await page.screenshot(screenshot)
            _crop_to_content(screenshot)
        await asyncio.sleep(max(0.0, seconds - 14.0))


def _crop_to_content(png: Path, margin_px: int = 12) -> None:
    """Cut the page's empty bottom (rows equal to the background colour of the last row)."""
    import cv2

    img = cv2.imread(str(png))
    rows = np.flatnonzero(np.any(img != img[-1, 0], axis=(1, 2)))
    if rows.size:
        cv2.imwrite(str(png), img[: min(img.shape[0], int(rows[-1]) + margin_px)])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="recording time of each rig run")
    ap.add_argument("--repeats", type=int, default=5, help="repeats of the preview measurements")
    ap.add_argument("--screenshot", type=Path, default=None, help="keep the page-open run's screenshot here")
    ap.add_argument("--no-world", action="store_true", help="the simulated cameras serve a test pattern")
    args = ap.parse_args()

    p = bench_previews(args.repeats)
    print(f"preview path at {WIDTH}x{HEIGHT} BayerRG12 (medians):")
    print(f"  PreviewHub.offer on the pairing thread: {p['offer_us']:.1f} us per paired set")
    print(f"  one preview render: {p['render_ms']:.2f} ms; advisor report (6 brackets x 2 cameras): "
          f"{p['advisor_ms']:.1f} ms")
    print(f"  preview worker at 1 preview/s per camera and bracket: {100 * p['worker_core_share']:.1f} % of one core")
    with tempfile.TemporaryDirectory(prefix="bench_monitor_") as tmp:
        off = run_rig(Path(tmp), args.seconds, not args.no_world, False, None)
        on = run_rig(Path(tmp), args.seconds, not args.no_world, True, args.screenshot)
    print(f"simulated rig, 640x400 at 10 fps, {args.seconds:g} s recording each, side by side:")
    print("| run | left fps | right fps | drops L/R | daemon CPU (cores) |")
    print("|---|---|---|---|---|")
    for name, r in (("monitor off", off), ("page open", on)):
        print(f"| {name} | {r['fps']['left']:.2f} | {r['fps']['right']:.2f} | {r['drops']['left']}/"
              f"{r['drops']['right']} | {r['daemon_cpu']:.3f} |")
    ratio = (on["fps"]["left"] + on["fps"]["right"]) / max(1e-9, off["fps"]["left"] + off["fps"]["right"])
    print(f"recording rate ratio page open / off: {ratio:.3f}; daemon CPU added by the monitor: "
          f"{on['daemon_cpu'] - off['daemon_cpu']:+.3f} cores")
    if args.screenshot is not None:
        print(f"screenshot: {args.screenshot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
