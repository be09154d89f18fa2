"""Panel firmware core cost per main-loop iteration, CPython vs the MicroPython WebAssembly runtime, side by side.

Measures (median of repeats, microseconds): ``render_status`` (one full 4x20 status screen), ``PanelApp.step`` with a
PANEL_STATE frame to decode + ACK + render (the heaviest iteration), and an idle ``step``. The board's budget is the
10 ms loop period; the ESP32 runs MicroPython roughly an order of magnitude slower than the WebAssembly build here,
so the MicroPython column is the one to compare with 10 000 us (after scaling).

usage: .venv/bin/python benchmarks/bench_panel.py [--quick]
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from bracketry_base import paths

ROOT = paths.repo_root()
FIRMWARE = ROOT / "firmware" / "esp32_panel"
BPROTO = ROOT / "host" / "bracketry_rig" / "wire" / "bproto.py"
RUNNER = ROOT / "tests" / "firmware" / "esp32_panel" / "panel_mpy_run.mjs"

SCRIPT = """
import time
import bproto, panel_app, panel_layout
N = {n}
REPEATS = {repeats}
try:
    clock = time.ticks_us
    diff = time.ticks_diff
except AttributeError:
    clock = lambda: int(time.perf_counter() * 1e6)
    diff = lambda a, b: a - b
st = dict(cam_left=2, cam_right=2, trigger=2, imu=4, lidar=3, gnss=1, free_disk_mb=931000, fps_left_centi=2190,
          fps_right_centi=2200, rec_seconds=754, message="BENCH MESSAGE")
frame = bproto.encode_message(bproto.MSG_PANEL_STATE, 1, st)
out = []
app = panel_app.PanelApp(out.append, b"123456", 0)
def med(xs):
    xs = sorted(xs)
    return xs[len(xs) // 2]
res = {{}}
for name in ("render_status", "step_with_state", "step_idle"):
    per = []
    for r in range(REPEATS):
        t0 = clock()
        for i in range(N):
            if name == "render_status":
                panel_layout.render_status(st, i & 1)
            elif name == "step_with_state":
                app.step(r * N + i, frame)
            else:
                app.step(r * N + i)
        per.append(diff(clock(), t0) / N)
    res[name] = med(per)
for k in res:
    print("RESULT", k, res[k])
"""


def run(n: int, repeats: int) -> dict[str, dict[str, float]]:
    with tempfile.TemporaryDirectory() as tmp:
        script = Path(tmp) / "bench.py"
        script.write_text(SCRIPT.format(n=n, repeats=repeats))
        cp = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, check=True,
                            env={"PYTHONPATH": f"{FIRMWARE}:{BPROTO.parent}"})
        files = [str(BPROTO), *map(str, sorted(FIRMWARE.glob("panel_*.py")))]
        mp = subprocess.run(["node", str(RUNNER), str(paths.micropython_module_path()), str(script), *files],
                            capture_output=True, text=True, check=True)
    out: dict[str, dict[str, float]] = {}
    for label, text in (("cpython", cp.stdout), ("micropython", mp.stdout)):
        for name, value in re.findall(r"RESULT (\w+) ([\d.]+)", text):
            out.setdefault(name, {})[label] = float(value)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    res = run(200 if args.quick else 1000, 3 if args.quick else 7)
    print(f"{'operation':<18} {'CPython us':>11} {'MicroPython(wasm) us':>21} {'ratio':>7}")
    for name, v in res.items():
        print(f"{name:<18} {v['cpython']:>11.1f} {v['micropython']:>21.1f} {v['micropython'] / v['cpython']:>7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
