"""Stereo visual odometry on OpenCV that mimics the paper's modified ORB-SLAM2 tracking.

Per frame (every frame becomes a keyframe; no motion model; no loop closure; no bundle adjustment):

1. ORB features on both rectified images (:class:`~bracketry_emulator.features.OrbExtractor`), stereo matches and
   depths (:func:`~bracketry_emulator.vo.stereo.match_stereo`).
2. Not initialised: a frame with more than 500 keypoints and at least ``min_init_stereo`` stereo points starts a new
   segment (pose = identity) and a new map from its stereo points (ORB-SLAM2's stereo initialisation).
3. Track the reference keyframe (the previous frame): its map points are matched to the frame by descriptor
   (Hamming <= 50, ratio 0.7, one-to-one, rotation-consistency histogram of 30 bins keeping the 3 largest), then the
   pose is found by PnP (SQPnP) + RANSAC with NO prior (no motion model) and refined.
4. Track the local map (points seen in the last ``local_window`` frames): project, search by projection
   (radius ``3 * 1.2^octave`` px, Hamming <= 100, ratio 0.8), refine the pose on all matches, drop outliers
   (chi-square 5.991 at the keypoint's scale, 4 rounds, as ORB-SLAM's pose optimisation).
5. New map points from stereo points not matched: the close ones (depth < ``th_depth`` baselines), or the 100
   nearest when fewer than 100 are close (ORB-SLAM2's ``CreateNewKeyFrame`` rule).

Lost criteria (ORB-SLAM2's, kept by the authors' fork): fewer than 15 reference-keyframe matches, fewer than 10
inliers after the reference pose, or fewer than 30 inliers after the local map. A lost frame gets no pose; the map
is dropped and the next frame that satisfies step 2 starts a new segment (a new ``CameraTrajectory<n>.txt``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from bracketry_emulator.features.coverage import grid_coverage
from bracketry_emulator.features.orb import Features, OrbExtractor, OrbSettings, hamming_distance
from bracketry_emulator.vo.calibration import StereoRectifier
from bracketry_emulator.vo.stereo import match_stereo

STATE_OK = "OK"
STATE_INIT = "INIT"  # first frame of a segment (tracked, pose = identity of the new segment)
STATE_LOST = "LOST"  # tracking failed on this frame
STATE_NO_INIT = "NO_INIT"  # not initialised and this frame could not initialise
TRACKED_STATES = (STATE_OK, STATE_INIT)


@dataclass(frozen=True)
class VOSettings:
    """Tracking parameters (ORB-SLAM2 values unless stated)."""

    orb: OrbSettings = field(default_factory=OrbSettings)
    th_depth: float = 35.0  # close-point threshold, in baselines (ORB-SLAM ThDepth)
    min_init_keypoints: int = 500
    min_init_stereo: int = 50  # ours: a map needs stereo points to exist
    min_ref_matches: int = 15
    min_ref_inliers: int = 10
    min_map_inliers: int = 30
    local_window: int = 5  # frames whose points form the local map (ours; ORB-SLAM uses covisibility)
    search_radius_px: float = 3.0
    ransac_reproj_px: float = 3.0
    ransac_iterations: int = 200
    coverage_grid: int = 20


@dataclass
class FrameResult:
    """What the VO did with one frame.

    Attributes:
        t_ns: timestamp (ns). state: one of OK, INIT, LOST, NO_INIT. segment: index of the trajectory segment
        (-1 when not tracked). pose_wc: float64 4x4 camera-to-segment-world (None when not tracked).
        n_keypoints: left keypoints. coverage: fraction of the 20x20 grid filled by left keypoints.
        n_stereo: keypoints with a stereo depth. n_ref_matches: matches to the reference keyframe.
        n_map_matches: keypoints matched to map points and inliers of the final pose ("matches to map").
        reason: why the frame is LOST / NO_INIT (empty when tracked).
    """

    t_ns: int
    state: str
    segment: int
    pose_wc: np.ndarray | None
    n_keypoints: int
    coverage: float
    n_stereo: int
    n_ref_matches: int = 0
    n_map_matches: int = 0
    reason: str = ""

    @property
    def tracked(self) -> bool:
        return self.state in TRACKED_STATES


class _Map:
    """Map points: world position (M,3), descriptor (M,32), last octave/angle, last frame that saw them."""

    def __init__(self) -> None:
        self.pos_w = np.zeros((0, 3))
        self.desc = np.zeros((0, 32), np.uint8)
        self.octave = np.zeros(0, np.int16)
        self.angle = np.zeros(0, np.float32)
        self.last_seen = np.zeros(0, np.int64)

    def __len__(self) -> int:
        return len(self.pos_w)

    def add(self, pos_w: np.ndarray, desc: np.ndarray, octave: np.ndarray, angle: np.ndarray, frame: int) -> None:
        self.pos_w = np.vstack([self.pos_w, pos_w])
        self.desc = np.vstack([self.desc, desc])
        self.octave = np.concatenate([self.octave, octave])
        self.angle = np.concatenate([self.angle, angle])
        self.last_seen = np.concatenate([self.last_seen, np.full(len(pos_w), frame, np.int64)])

    def prune(self, oldest_frame: int) -> None:
        keep = self.last_seen >= oldest_frame
        self.pos_w, self.desc, self.octave = self.pos_w[keep], self.desc[keep], self.octave[keep]
        self.angle, self.last_seen = self.angle[keep], self.last_seen[keep]


def _pose_from_rt(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """4x4 world-to-camera from OpenCV rvec/tvec."""
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.ravel()
    return T


def _rotation_consistent(d_angle_deg: np.ndarray, bins: int = 30) -> np.ndarray:
    """bool mask keeping matches whose orientation change falls in the 3 most populated of ``bins`` bins."""
    if len(d_angle_deg) == 0:
        return np.zeros(0, bool)
    b = (np.mod(d_angle_deg, 360.0) * bins / 360.0).astype(int) % bins
    counts = np.bincount(b, minlength=bins)
    top = np.argsort(counts)[::-1][:3]
    top = top[counts[top] >= 0.1 * counts[top[0]]]  # ORB-SLAM drops the 2nd/3rd bins when < 10 % of the 1st
    return np.isin(b, top)


class StereoVO:
    """The tracker. Feed frames in time order with :meth:`track`; read results from the returned objects."""

    def __init__(self, rectifier: StereoRectifier, settings: VOSettings | None = None) -> None:
        self.rect = rectifier
        self.settings = settings or VOSettings()
        self.extractor = OrbExtractor(self.settings.orb)
        self.K = rectifier.K
        self.frame_index = -1
        self.segment = -1
        self.map: _Map | None = None
        self.T_cw = np.eye(4)
        self._mask = rectifier.valid_mask()

    # -- per-frame front end --------------------------------------------------------------------------------
    def _frontend(self, left_gray8: np.ndarray, right_gray8: np.ndarray) -> tuple[Features, np.ndarray]:
        left = self.rect.rectify(left_gray8, "left")
        right = self.rect.rectify(right_gray8, "right")
        fl = self.extractor.detect_and_compute(left, self._mask)
        fr = self.extractor.detect_and_compute(right, self._mask)
        stereo = match_stereo(fl, fr, left, right, self.rect.fx, self.rect.bf)
        return fl, stereo.depth_m

    def _backproject(self, feats: Features, depth_m: np.ndarray, idx: np.ndarray, T_cw: np.ndarray) -> np.ndarray:
        """World points (len(idx), 3) of keypoints ``idx`` with depths, given world-to-camera ``T_cw``."""
        z = depth_m[idx]
        x = (feats.xy_px[idx, 0] - self.rect.cx) * z / self.rect.fx
        y = (feats.xy_px[idx, 1] - self.rect.cy) * z / self.rect.fy
        pc = np.stack([x, y, z], axis=1)
        T_wc = np.linalg.inv(T_cw)
        return pc @ T_wc[:3, :3].T + T_wc[:3, 3]

    def _new_points(self, feats: Features, depth_m: np.ndarray, exclude: np.ndarray) -> np.ndarray:
        """Indices of keypoints that make new map points (ORB-SLAM2 close-point rule)."""
        cand = np.flatnonzero(np.isfinite(depth_m) & ~exclude)
        if len(cand) == 0:
            return cand
        close = cand[depth_m[cand] < self.settings.th_depth * self.rect.baseline_m]
        if len(close) >= 100:
            return close
        return cand[np.argsort(depth_m[cand])[:100]]

    # -- pose estimation ------------------------------------------------------------------------------------
    def _refine(self, pts_w: np.ndarray, uv: np.ndarray, octave: np.ndarray, T_cw: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """Iterative LM refinement with chi-square outlier rejection; returns (T_cw, inlier mask).

        Inliers: reprojection error^2 < 5.991 * (1.2^octave)^2 and positive depth (ORB-SLAM's monocular test).
        Four rounds of (Levenberg-Marquardt on the inliers, re-classification); a round that loses more than half of
        the inliers is rejected (keeps the previous pose).
        """
        sigma2 = self.extractor.scale_factors[octave] ** 2
        pts = pts_w.astype(np.float64)

        def classify(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
            proj, _ = cv2.projectPoints(pts, rvec, tvec, self.K, None)
            err2 = ((proj.reshape(-1, 2) - uv) ** 2).sum(axis=1)
            z = (pts @ cv2.Rodrigues(rvec)[0].T + tvec.ravel())[:, 2]
            return (err2 < 5.991 * sigma2) & (z > 0)

        rvec = cv2.Rodrigues(T_cw[:3, :3])[0]
        tvec = T_cw[:3, 3].reshape(3, 1).copy()
        inl = classify(rvec, tvec)
        for _ in range(4):
            if inl.sum() < 6:
                break
            r2, t2 = cv2.solvePnPRefineLM(pts[inl], uv[inl].astype(np.float64), self.K, None, rvec.copy(),
                                          tvec.copy())
            inl2 = classify(r2, t2)
            if inl2.sum() < 0.5 * inl.sum():
                break
            rvec, tvec, inl = r2, t2, inl2
        return _pose_from_rt(rvec, tvec), inl

    def _match_reference(self, feats: Features, m: _Map, ref_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(map ids, keypoint ids) matched by descriptor between the reference keyframe's points and the frame."""
        if len(ref_ids) == 0 or len(feats) < 2:
            return np.zeros(0, int), np.zeros(0, int)
        matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        knn = matcher.knnMatch(m.desc[ref_ids], feats.descriptors, k=2)
        mids, kids, dists = [], [], []
        for pair in knn:
            if len(pair) < 2:
                continue
            a, b = pair
            if a.distance <= 50 and a.distance < 0.7 * b.distance:
                mids.append(ref_ids[a.queryIdx])
                kids.append(a.trainIdx)
                dists.append(a.distance)
        mids_a, kids_a, dist_a = np.array(mids, int), np.array(kids, int), np.array(dists)
        if len(mids_a) == 0:
            return mids_a, kids_a
        order = np.lexsort((dist_a, kids_a))  # one-to-one: best distance per keypoint
        first = np.r_[True, kids_a[order][1:] != kids_a[order][:-1]]
        mids_a, kids_a = mids_a[order][first], kids_a[order][first]
        keep = _rotation_consistent(feats.angle_deg[kids_a] - m.angle[mids_a])
        return mids_a[keep], kids_a[keep]

    def _search_by_projection(self, feats: Features, m: _Map, ids: np.ndarray, T_cw: np.ndarray,
                              taken: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(map ids, keypoint ids) found by projecting local-map points ``ids`` with ``T_cw``."""
        if len(ids) == 0 or len(feats) == 0:
            return np.zeros(0, int), np.zeros(0, int)
        pc = m.pos_w[ids] @ T_cw[:3, :3].T + T_cw[:3, 3]
        front = pc[:, 2] > 1e-6
        ids, pc = ids[front], pc[front]
        u = self.rect.fx * pc[:, 0] / pc[:, 2] + self.rect.cx
        v = self.rect.fy * pc[:, 1] / pc[:, 2] + self.rect.cy
        inside = (u >= 0) & (u < self.rect.width_px) & (v >= 0) & (v < self.rect.height_px)
        ids, u, v = ids[inside], u[inside], v[inside]
        if len(ids) == 0:
            return np.zeros(0, int), np.zeros(0, int)
        from scipy.spatial import cKDTree

        tree = cKDTree(feats.xy_px.astype(np.float64))
        radius = self.settings.search_radius_px * self.extractor.scale_factors[m.octave[ids]]
        k = min(8, len(feats))
        dist_px, cand = tree.query(np.stack([u, v], axis=1), k=k, distance_upper_bound=float(radius.max()))
        dist_px = dist_px.reshape(len(ids), k)
        cand = cand.reshape(len(ids), k)
        valid = np.isfinite(dist_px) & (dist_px <= radius[:, None])
        cand_safe = np.where(valid, cand, 0)
        valid &= ~taken[cand_safe]
        ham = hamming_distance(m.desc[ids][:, None, :], feats.descriptors[cand_safe])
        ham = np.where(valid, ham, 10_000)
        order = np.argsort(ham, axis=1)
        best = ham[np.arange(len(ids)), order[:, 0]]
        second = ham[np.arange(len(ids)), order[:, 1]] if k > 1 else np.full(len(ids), 10_000)
        ok = (best <= 100) & ((second >= 10_000) | (best <= 0.8 * second))
        mids = ids[ok]
        kids = cand_safe[np.arange(len(ids)), order[:, 0]][ok]
        bd = best[ok]
        o = np.lexsort((bd, kids))
        first = np.r_[True, kids[o][1:] != kids[o][:-1]]
        return mids[o][first], kids[o][first]

    # -- main entry -----------------------------------------------------------------------------------------
    def track(self, t_ns: int, left_gray8: np.ndarray, right_gray8: np.ndarray) -> FrameResult:
        """Process one stereo pair (uint8 HxW gray images, unrectified) and return what happened."""
        s = self.settings
        self.frame_index += 1
        fi = self.frame_index
        feats, depth = self._frontend(left_gray8, right_gray8)
        cov = grid_coverage(feats.xy_px, feats.width_px, feats.height_px, s.coverage_grid)
        has_depth = np.isfinite(depth)
        result = FrameResult(int(t_ns), STATE_NO_INIT, -1, None, len(feats), cov, int(has_depth.sum()))
        if self.map is None:
            if len(feats) > s.min_init_keypoints and has_depth.sum() >= s.min_init_stereo:
                self.segment += 1
                self.T_cw = np.eye(4)
                self.map = _Map()
                idx = np.flatnonzero(has_depth)
                self.map.add(self._backproject(feats, depth, idx, self.T_cw), feats.descriptors[idx],
                             feats.octave[idx], feats.angle_deg[idx], fi)
                result.state, result.segment, result.pose_wc = STATE_INIT, self.segment, np.eye(4)
            else:
                result.reason = (f"cannot initialise: {len(feats)} keypoints (need > {s.min_init_keypoints}), "
                                 f"{int(has_depth.sum())} stereo points (need >= {s.min_init_stereo})")
            return result
        m = self.map
        # 3. reference keyframe = previous frame
        ref_ids = np.flatnonzero(m.last_seen == fi - 1)
        mids, kids = self._match_reference(feats, m, ref_ids)
        result.n_ref_matches = len(mids)
        if len(mids) < s.min_ref_matches:
            return self._lose(result, f"{len(mids)} reference matches < {s.min_ref_matches}")
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            m.pos_w[mids].astype(np.float64), feats.xy_px[kids].astype(np.float64), self.K, None,
            iterationsCount=s.ransac_iterations, reprojectionError=s.ransac_reproj_px, confidence=0.99,
            flags=cv2.SOLVEPNP_SQPNP)
        n_ransac = 0 if not ok or inliers is None else len(inliers)
        if n_ransac < s.min_ref_inliers:
            return self._lose(result, f"{n_ransac} PnP RANSAC inliers < {s.min_ref_inliers}")
        inl_idx = inliers.ravel()
        T_cw, inl = self._refine(m.pos_w[mids[inl_idx]], feats.xy_px[kids[inl_idx]].astype(np.float64),
                                 feats.octave[kids[inl_idx]], _pose_from_rt(rvec, tvec))
        if inl.sum() < s.min_ref_inliers:
            return self._lose(result, f"{inl.sum()} reference inliers < {s.min_ref_inliers}")
        mids, kids = mids[inl_idx][inl], kids[inl_idx][inl]
        # 4. local map
        taken = np.zeros(len(feats), bool)
        taken[kids] = True
        local = np.flatnonzero(m.last_seen >= fi - s.local_window)
        local = local[~np.isin(local, mids)]
        lm, lk = self._search_by_projection(feats, m, local, T_cw, taken)
        all_m = np.concatenate([mids, lm])
        all_k = np.concatenate([kids, lk])
        T_cw, inl = self._refine(m.pos_w[all_m], feats.xy_px[all_k].astype(np.float64), feats.octave[all_k], T_cw)
        result.n_map_matches = int(inl.sum())
        if inl.sum() < s.min_map_inliers:
            return self._lose(result, f"{inl.sum()} local-map inliers < {s.min_map_inliers}")
        all_m, all_k = all_m[inl], all_k[inl]
        # 5. map update: every frame is a keyframe
        m.desc[all_m] = feats.descriptors[all_k]
        m.octave[all_m] = feats.octave[all_k]
        m.angle[all_m] = feats.angle_deg[all_k]
        m.last_seen[all_m] = fi
        used = np.zeros(len(feats), bool)
        used[all_k] = True
        new = self._new_points(feats, depth, used)
        if len(new):
            m.add(self._backproject(feats, depth, new, T_cw), feats.descriptors[new], feats.octave[new],
                  feats.angle_deg[new], fi)
        m.prune(fi - s.local_window)
        self.T_cw = T_cw
        result.state, result.segment, result.pose_wc = STATE_OK, self.segment, np.linalg.inv(T_cw)
        return result

    def _lose(self, result: FrameResult, reason: str) -> FrameResult:
        self.map = None
        result.state = STATE_LOST
        result.reason = reason
        return result
