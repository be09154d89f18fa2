"""The cause of a lost track from constructed frame logs: one log per cause, the order of the causes, the blur length
from a known rotation, and the rows of a run's failures."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bracketry_emulator.metrics.failure_causes import (
    BLUR_PX,
    CAUSES,
    DARK_SHARE,
    JUMP_STOPS,
    SATURATED_SHARE,
    TEXTURE_KEYPOINTS,
    classify_loss,
    failure_rows,
    first_loss_index,
    frame_log,
    loss_cause,
    rotation_blur_px,
    window_change_stops,
)

N = 8
LOSS = 5


def _log(**change: tuple[int, float]) -> dict[str, np.ndarray]:
    """A healthy 8-frame log (little clipping, no blur, steady exposure, 1500 keypoints, 200 map matches) with
    ``name=(frame, value)`` changes."""
    log = {"saturated_share": np.full(N, 0.02), "dark_share": np.full(N, 0.05), "blur_px": np.full(N, 0.5),
           "exposure_ratio": np.r_[np.nan, np.full(N - 1, 1.05)], "keypoints": np.full(N, 1500.0),
           "map_matches": np.full(N, 200.0)}
    for name, (k, v) in change.items():
        log[name][k] = v
    return log


@pytest.mark.parametrize("change,cause", [
    ({"saturated_share": (LOSS, SATURATED_SHARE + 0.1)}, "saturation"),
    ({"dark_share": (LOSS, DARK_SHARE + 0.1)}, "underexposure"),
    ({"blur_px": (LOSS, BLUR_PX * 2)}, "blur"),
    ({"exposure_ratio": (LOSS, 2.0 ** (JUMP_STOPS + 0.5))}, "exposure_jump"),
    ({"exposure_ratio": (LOSS, 2.0 ** -(JUMP_STOPS + 0.5))}, "exposure_jump"),  # a jump down too
    ({"keypoints": (LOSS, TEXTURE_KEYPOINTS - 100)}, "texture"),
    ({"keypoints": (LOSS, TEXTURE_KEYPOINTS)}, "texture"),  # ORB-SLAM's stereo start needs more than 500
    ({"keypoints": (LOSS, TEXTURE_KEYPOINTS + 1)}, "other"),
    ({"map_matches": (LOSS, 3.0)}, "other"),
])
def test_one_log_per_cause(change: dict, cause: str) -> None:
    assert classify_loss(**_log(**change), loss_index=LOSS) == cause


def test_every_cause_is_reachable_and_the_healthy_log_is_other() -> None:
    assert CAUSES == ("saturation", "underexposure", "blur", "exposure_jump", "texture", "other")
    assert classify_loss(**_log(), loss_index=LOSS) == "other"


def test_the_frame_before_the_loss_counts_and_older_ones_do_not() -> None:
    assert classify_loss(**_log(saturated_share=(LOSS - 1, 0.6)), loss_index=LOSS) == "saturation"
    assert classify_loss(**_log(saturated_share=(LOSS - 2, 0.6)), loss_index=LOSS) == "other"
    assert classify_loss(**_log(exposure_ratio=(LOSS - 1, 3.0)), loss_index=LOSS) == "exposure_jump"


def test_image_causes_come_before_a_jump_and_a_jump_before_texture() -> None:
    both = _log(saturated_share=(LOSS, 0.5), exposure_ratio=(LOSS, 4.0))
    assert classify_loss(**both, loss_index=LOSS) == "saturation"
    jump_flat = _log(exposure_ratio=(LOSS, 4.0), keypoints=(LOSS, 100.0))
    assert classify_loss(**jump_flat, loss_index=LOSS) == "exposure_jump"


def test_unknown_values_are_no_cause() -> None:
    log = {k: np.full(N, np.nan) for k in _log()}
    assert classify_loss(**log, loss_index=0) == "other"
    with pytest.raises(ValueError):
        classify_loss(**_log(), loss_index=N)


def test_rotation_blur_from_a_known_yaw_rate() -> None:
    """A camera yawing at 0.5 rad/s: over 10 ms it turns 5 mrad, 2.5 px at fx = 500; outside the reference: NaN."""
    t = np.linspace(0.0, 2.0, 201)
    poses = np.tile(np.eye(4), (len(t), 1, 1))
    poses[:, :3, :3] = Rotation.from_euler("y", 0.5 * t[:, None]).as_matrix()
    blur = rotation_blur_px(t, poses, np.array([1.0, 1.5, 1.999]), np.array([0.010, 0.020, 0.010]), 500.0)
    np.testing.assert_allclose(blur[:2], [2.5, 5.0], rtol=1e-6)
    assert np.isnan(blur[2])


def test_frame_log_joins_the_closed_loop_by_step(tmp_path) -> None:
    """ae.csv gives the shares and the exposure ratio (exposure x gain), frames.csv the states and counts; the
    camera exposure is the exposure without the gain."""
    ae = tmp_path / "ae.csv"
    ae.write_text("step,timestamp_ns,exposure_ms,next_exposure_ms,source_exposure_ms,ae_ms,gain_db,saturated_share,"
                  "dark_share\n"
                  "0,0,4,4,4,0,0,0.01,0.02\n1,1,4,16,4,0,0,0.01,0.02\n2,2,16,16,16,0,6.0206,0.4,0.0\n")
    frames = [{"t_ns": k * 250_000_000, "state": s, "n_keypoints": 900, "n_map_matches": 100}
              for k, s in enumerate(["INIT", "OK", "LOST"])]
    log = frame_log(frames, ae)
    assert first_loss_index(log.states) == 2
    np.testing.assert_allclose(log.exposure_ratio[1:], [1.0, 4.0])
    assert log.camera_exposure_s[2] == pytest.approx(0.008, rel=1e-4)
    assert loss_cause(log, np.zeros(3)) == "saturation"
    assert loss_cause(frame_log(frames[:2], ae), np.zeros(2)) is None
    assert np.isnan(frame_log(frames, tmp_path / "missing.csv").saturated_share).all()


def test_texture_is_judged_on_the_localisations_own_keypoints(tmp_path) -> None:
    """A stereo start that fails with 900 keypoints at the paper's settings but 420 of ORB-SLAM3's own is a view short
    of texture for ORB-SLAM3; a frames.csv without the localisation's count falls back to ``n_keypoints``."""
    ae = tmp_path / "ae.csv"
    ae.write_text("step,timestamp_ns,exposure_ms,next_exposure_ms,source_exposure_ms,ae_ms,gain_db,saturated_share,"
                  "dark_share\n0,0,8,8,8,0,0,0.05,0.05\n1,1,8,8,8,0,0,0.05,0.05\n")
    own = [{"t_ns": k, "state": "LOST", "n_keypoints": 900, "n_slam_keypoints": 420, "n_map_matches": 0}
           for k in range(2)]
    assert loss_cause(frame_log(own, ae), np.zeros(2)) == "texture"
    np.testing.assert_array_equal(frame_log(own, ae).keypoints, [420, 420])
    unknown = [{**f, "n_slam_keypoints": float("nan")} for f in own]
    assert loss_cause(frame_log(unknown, ae), np.zeros(2)) == "other"
    missing = [{k: v for k, v in f.items() if k != "n_slam_keypoints"} for f in own]
    np.testing.assert_array_equal(frame_log(missing, ae).keypoints, [900, 900])


def test_failure_rows_of_single_and_repeated_results() -> None:
    single = {"trajectory": "t", "method": "m", "repeat": 0, "time_before_failure_s": 2.5,
              "failure_cause": "blur"}
    assert failure_rows(single) == [{"repeat": 0, "time_s": 2.5, "cause": "blur"}]
    assert failure_rows({**single, "failure_cause": None}) == []
    combined = {**single, "failure_runs": [{"repeat": 1, "time_s": 1.0, "cause": "texture"}]}
    assert failure_rows(combined) == [{"repeat": 1, "time_s": 1.0, "cause": "texture"}]


def test_a_jump_is_half_a_stop_up_or_down_into_the_window() -> None:
    """0.6 stops into the lost frame or the one before it is a jump, 0.4 is not; the window's change is the largest
    of its frames' (unknown ratios ignored)."""
    assert JUMP_STOPS == 0.5
    for stops, cause in [(0.6, "exposure_jump"), (-0.6, "exposure_jump"), (0.4, "other"), (-0.4, "other")]:
        assert classify_loss(**_log(exposure_ratio=(LOSS, 2.0 ** stops)), loss_index=LOSS) == cause
        assert classify_loss(**_log(exposure_ratio=(LOSS - 1, 2.0 ** stops)), loss_index=LOSS) == cause
    change = window_change_stops(np.array([np.nan, 2.0, 1.0, 0.5, np.nan, 0.0, np.nan]))
    np.testing.assert_allclose(change[1:5], [1.0, 1.0, 1.0, 1.0])
    assert np.isnan(change[[0, 5, 6]]).all()  # a ratio of 0 is unknown, as a missing one
