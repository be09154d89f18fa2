"""Synthetic benchmark results (the JSON form the report reads) and a headless-Chromium probe of a report page.

``synthetic_results``: many trajectories in two subsets, methods with long plug-in names carrying LaTeX special
characters, repeated SLAM runs (``*_runs`` / ``*_spread``), a failed run, per-frame lists, exposure traces
(``steps.csv``) and a kept middle frame (``preview_left.png``) per run: the report's widest case without running a
benchmark.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np

CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run", "--hide-scrollbars",
                  "--allow-file-access-from-files")

LONG_METHODS = ["ae50", "fix", "ae30", "shim", "my_lab.exposure:TargetMedian_v2", "wang_50%&more",
                "a_really_long_plugin_method_name_for_layout", "kim"]


def synthetic_results(root: Path, n_traj: int = 30, methods: list[str] | None = None, repeats: int = 3,
                      seed: int = 0, subsets: tuple[str, ...] = ("Campus_1", "Forest", "Forest")) -> list[dict]:
    """Results for ``n_traj`` trajectories x ``methods``, each combined from ``repeats`` SLAM runs; trajectory t is
    in ``subsets[t % len(subsets)]``."""
    methods = methods or LONG_METHODS
    rng = np.random.default_rng(seed)
    out = []
    for t in range(n_traj):
        traj = f"trajectory_{t:02d}"
        subset = subsets[t % len(subsets)]
        for k, m in enumerate(methods):
            run_dir = root / "runs" / traj / f"m{k}"
            vo_dir = root / "vo" / traj / f"m{k}"
            run_dir.mkdir(parents=True, exist_ok=True)
            vo_dir.mkdir(parents=True, exist_ok=True)
            n = 20
            exp = np.exp(rng.normal(np.log(4.0), 0.3, n))
            (run_dir / "steps.csv").write_text("timestamp_ns,target_exposure_ms\n" + "".join(
                f"{i * 50_000_000},{e:.3f}\n" for i, e in enumerate(exp)))
            if t == 0:
                img = (np.clip(rng.normal(100 + 10 * k, 30, (60, 80)), 0, 255)).astype(np.uint8)
                cv2.imwrite(str(vo_dir / "preview_left.png"), img)
            rte_runs = list(rng.gamma(4.0, 1.0 + 0.1 * k, repeats))
            rre_runs = list(rng.gamma(4.0, 0.05, repeats))
            dist_runs = list(rng.uniform(0.5, 1.0, repeats))
            failed = t == 1 and k == 2 and repeats > 1
            cov = list(rng.uniform(0.2, 0.6, n))
            mat = list(rng.integers(50, 300, n).astype(float))
            r = {"trajectory": traj, "subset": subset, "method": m, "slam": "builtin", "repeats": repeats,
                 "repeats_ok": repeats, "n_frames": n, "success": bool(rng.random() > 0.3),
                 "time_before_failure_s": float(rng.uniform(0.2, 1.0)), "duration_s": 1.0,
                 "tracked_fraction": float(np.median(dist_runs)),
                 "tracked_distance_fraction": float(np.median(dist_runs)),
                 "tracked_distance_fraction_runs": dist_runs,
                 "tracked_distance_fraction_spread": float(np.ptp(dist_runs)),
                 "n_segments": 1, "coverage_mean": float(np.mean(cov)), "matches_mean": float(np.mean(mat)),
                 "keypoints_mean": 500.0, "rte_pct": float(np.median(rte_runs)), "rte_pct_runs": rte_runs,
                 "rte_pct_spread": float(np.ptp(rte_runs)), "rre_deg_per_m": float(np.median(rre_runs)),
                 "rre_deg_per_m_runs": rre_runs, "rre_deg_per_m_spread": float(np.ptp(rre_runs)),
                 "s_per_frame": 0.01, "reference": "groundtruth", "coverage": cov, "matches": mat,
                 "windows": [{"window_m": 1.0, "n_pairs": 10, "rte_pct": float(np.median(rte_runs)),
                              "rre_deg_per_m": float(np.median(rre_runs))}],
                 "run_dir": str(run_dir), "vo_dir": str(vo_dir), "errors": []}
            if failed:
                r.update(errors=["orbslam3 child died (signal 11)"], repeats_ok=repeats - 1)
            out.append(r)
    return out


def chromium_probe(page: Path, work: Path, width_px: int = 1280, height_px: int = 2000) -> tuple[dict, Path]:
    """Load ``page`` (a report.html beside its figures) in headless Chromium ``width_px`` wide: returns the page's
    layout facts (``scrollWidth``/``clientWidth`` of the scrolling element, ``innerWidth``, every image's src and
    naturalWidth once loaded) and a screenshot's path. The facts come from a copy of the page with a small script
    that writes them into the DOM on ``load``, read back with ``--dump-dom``."""
    exe = shutil.which("chromium")
    assert exe is not None
    probe = page.with_name("probe_" + page.name)
    script = ("<script>window.addEventListener('load',()=>{const s=document.scrollingElement;"
              "const f={scrollWidth:s.scrollWidth,clientWidth:s.clientWidth,innerWidth:window.innerWidth,"
              "images:[...document.images].map(i=>({src:i.getAttribute('src'),complete:i.complete,"
              "naturalWidth:i.naturalWidth}))};const p=document.createElement('pre');p.id='probe';"
              "p.style.display='none';p.textContent=JSON.stringify(f);document.body.appendChild(p);});</script>")
    probe.write_text(page.read_text().replace("</body>", script + "</body>"))
    size = f"--window-size={width_px},{height_px}"
    common = [exe, *CHROMIUM_FLAGS, size, "--virtual-time-budget=10000"]
    profile = work / "chromium-profile"
    dom = subprocess.run([*common, f"--user-data-dir={profile}", "--dump-dom", probe.as_uri()],
                         capture_output=True, text=True, timeout=120, check=True).stdout
    start = dom.index("<pre id=\"probe\"")
    text = dom[dom.index(">", start) + 1:dom.index("</pre>", start)]
    facts = json.loads(text.replace("&quot;", '"').replace("&amp;", "&").replace("&lt;", "<").replace("&gt;", ">"))
    shot = work / "report_1280.png"
    subprocess.run([*common, f"--user-data-dir={profile}", f"--screenshot={shot}", page.as_uri()],
                   capture_output=True, timeout=120, check=True)
    probe.unlink()
    return facts, shot
