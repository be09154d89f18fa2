"""``bracketry accuracy motion``: emulated long exposures of a walking synthetic camera against true renders."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bracketry.cli import main
from bracketry_emulator.accuracy.motion import run_motion


def test_motion_protocol_blur_helps_when_moving_and_changes_nothing_when_still() -> None:
    """The former protocol (the world's reprojected point-sampled frames as the truth)."""
    res = run_motion(seed=5, resolution=(480, 300), speeds_kmh=(0.0, 5.0), sources_ms=(2.0,), targets_ms=(32.0,),
                     n_instants=1, reference="reproject", supersample=1)
    still, moving = res["rows"]
    assert still["speed_kmh"] == 0 and moving["speed_kmh"] == 5
    assert still["rmse_dn_blur"] == still["rmse_dn_plain"] and still["rmse_dn_plain"] < 10.0
    assert res["goals"]["blur_not_worse_still"]["met"]
    # walking: the true 32 ms frame is blurred; the plain emulation from 2 ms is too sharp, the blurred one close
    assert moving["sharpness_plain"] > moving["sharpness_true"]
    assert moving["sharpness_error_blur"] < 0.5 * moving["sharpness_error_plain"]
    assert moving["rmse_dn_blur"] < moving["rmse_dn_plain"]


def test_motion_protocol_exact_reference_and_where_the_error_is() -> None:
    """The default reference (exact integral, area-sampled pixels): blur emulation lowers the RMSE by more than
    against the reprojected point-sampled frames (whose own error is as large as the emulator's), changes nothing on
    the still camera, and most of what remains sits on depth edges."""
    res = run_motion(seed=5, resolution=(320, 200), speeds_kmh=(0.0, 5.0), sources_ms=(2.0,), targets_ms=(32.0,),
                     n_instants=1)
    assert res["settings"]["reference"] == "exact" and res["settings"]["supersample"] == 2
    still, moving = res["rows"]
    assert still["rmse_dn_blur"] == still["rmse_dn_plain"] < 10.0
    red = 1 - moving["rmse_dn_blur"] / moving["rmse_dn_plain"]
    red_reproject = 1 - moving["rmse_dn_blur_reproject"] / moving["rmse_dn_plain_reproject"]
    assert red > 0.25 and red > red_reproject + 0.1, (red, red_reproject)  # seed 5: 33 % vs 13 %
    assert moving["sharpness_blur"] < moving["sharpness_plain"]
    # depth edges: a minority of the pixels, most of the blurred emulation's squared error
    assert moving["depth_edge_pixel_share"] < 0.35 and moving["depth_edge_error_share_blur"] > 0.5
    assert moving["rmse_dn_blur_off_edges"] < 0.7 * moving["rmse_dn_blur"]
    with pytest.raises(ValueError, match="reference"):
        run_motion(reference="dense")


@pytest.mark.slow
def test_accuracy_motion_command_writes_rows(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "m"
    code = main(["accuracy", "motion", "--seed", "2", "--out", str(out), "--instants", "1", "--resolution",
                 "256x160"])
    assert code in (0, 1)
    doc = json.loads((out / "motion.json").read_text())
    rows = doc["rows"]
    assert len(rows) == 3 * 4 * 2
    assert {(r["speed_kmh"], r["source_ms"], r["target_ms"]) for r in rows} == {
        (v, s, t) for v in (0.0, 2.0, 5.0) for s in (1.0, 2.0, 4.0, 8.0) for t in (16.0, 32.0)}
    for r in rows:
        assert {"rmse_dn_plain", "rmse_dn_blur", "sharpness_error_plain", "sharpness_error_blur"} <= set(r)
    assert "goal blur_not_worse_still: met" in capsys.readouterr().out
    # an existing output is refused without --overwrite (one line, exit 2)
    assert main(["accuracy", "motion", "--out", str(out)]) == 2
