"""Walking trajectory of the backpack rig: a closed loop at constant speed with gait bounce, sway and roll.

World frame: x east, y north, z up (metres), ground at z = 0. Camera frame (OpenCV): x right, y down, z forward.
A pose is ``(R_wc, p_w)``: R_wc (3, 3) maps camera-frame vectors to the world, p_w (3,) is the optical centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from bracketry_base.errors import BracketryError


def _fma(a: float, b: float, c: float) -> float:
    """a * b + c rounded once (exact rationals, correctly rounded by the conversion; math.fma from Python 3.13)."""
    return float(Fraction(a) * Fraction(b) + Fraction(c))


fma = getattr(math, "fma", _fma)


def mat_mul(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A @ B`` of a float64 (3, 3) matrix and a (3, 3) matrix or a (3,) vector, the same bits on every CPU.

    numpy's ``@`` calls OpenBLAS, whose kernel (and so rounding) depends on the CPU; this computes each entry as
    the chain the AVX2 and AVX-512 kernels use (bit for bit theirs, measured over 18,000 poses of the walk):
    ``fma(a2, b2, fma(a1, b1, a0 * b0))``."""
    A = np.asarray(A, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)
    if A.shape != (3, 3) or B.shape not in ((3, 3), (3,)):
        raise ValueError(f"mat_mul: (3, 3) @ (3, 3) or (3,) only (got {A.shape} @ {B.shape})")
    a = A.tolist()
    cols = [B.tolist()] if B.ndim == 1 else B.T.tolist()
    out = [[fma(r[2], c[2], fma(r[1], c[1], r[0] * c[0])) for c in cols] for r in a]
    return np.array(out).ravel() if B.ndim == 1 else np.array(out)


def vec_norm(v: np.ndarray) -> float:
    """Euclidean norm of a float64 vector, summed in index order (``np.linalg.norm`` of a vector calls BLAS)."""
    total = 0.0
    for x in np.asarray(v, dtype=np.float64).tolist():
        total += x * x
    return math.sqrt(total)


def rot_x(a: float) -> np.ndarray:
    """Rotation about x by ``a`` radians, float64 (3, 3)."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_z(a: float) -> np.ndarray:
    """Rotation about z by ``a`` radians, float64 (3, 3)."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def level_camera(heading_rad: float) -> np.ndarray:
    """R_wc of a level camera looking along ``heading_rad`` (from +x towards +y): x right, y down, z forward."""
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    return np.array([[s, 0.0, c], [-c, 0.0, s], [0.0, -1.0, 0.0]])


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (qx, qy, qz, qw) with qw >= 0 of a rotation matrix (3, 3)."""
    m = np.asarray(R, dtype=np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = np.array([(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s])
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = np.array([0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s])
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = np.array([(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = np.array([(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s])
    q /= vec_norm(q)
    return -q if q[3] < 0 else q


def matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of a quaternion (qx, qy, qz, qw)."""
    x, y, z, w = np.asarray(q, dtype=np.float64) / vec_norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


#: downward pitch of the rig's optical axis on a scenario's walk: the real sample's horizon (the foot of the treeline)
#: lies at row 34 of 200 (fy 195, cy 97 at 320x200: atan(63 / 195) = 18 degrees), its view holds no sky; a level
#: camera would fill half its view with sky and silhouettes of trunks (emulator/DATASET.md)
RIG_PITCH_DEG = 18.0


@dataclass
class LoopTrajectory:
    """A closed, smooth loop walked at constant speed, with a walking gait.

    Attributes:
        radius_m: mean radius of the loop; its radius varies with azimuth by ``wobble`` (relative, 2nd and 3rd
            harmonics) so that the view direction sweeps all azimuths (towards and away from the sun).
        speed_kmh: walking speed along the loop.
        height_m: optical centre height above the ground.
        pitch_deg: downward pitch of the optical axis.
        step_hz: step frequency (vertical bounce at step_hz, roll/sway/yaw at step_hz / 2).
        bounce_m, roll_deg, sway_m, yaw_deg, nod_deg: gait amplitudes of the trunk that carries the backpack
            (walking: the trunk bobs 2 cm per step, sways 2 cm and rolls 1.6 degrees per stride; the upper trunk,
            where the rig rides, turns 1.6 degrees; it pitches 0.8 degree). The rotations are set so that the
            camera's turn over a bracket cycle (0.27 s) and its change from one cycle to the next, what a
            constant-velocity prediction gets wrong, match the real sample's IMU (emulator/DATASET.md, "Motion").
        phase_rad: start position on the loop.
        turn_deg, turn_period_s: the walker looking around: a yaw of ``turn_deg`` amplitude with that period, on
            top of the gait (0: none). A 15-degree look every 7 s turns at up to 13 degrees/s.
    """

    radius_m: float = 12.0
    wobble: tuple[float, float] = (0.18, 0.08)
    speed_kmh: float = 2.0
    height_m: float = 1.55
    pitch_deg: float = 6.0
    step_hz: float = 1.7
    bounce_m: float = 0.02
    roll_deg: float = 1.6
    sway_m: float = 0.02
    yaw_deg: float = 1.6
    nod_deg: float = 0.8
    phase_rad: float = 0.0
    turn_deg: float = 0.0
    turn_period_s: float = 7.0
    _s_table: np.ndarray = field(init=False, repr=False)
    _th_table: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.radius_m <= 1 or self.speed_kmh <= 0 or self.height_m <= 0 or self.turn_period_s <= 0:
            raise BracketryError("trajectory: radius_m > 1, speed_kmh > 0, height_m > 0 and turn_period_s > 0 "
                                 "required")
        th = np.linspace(0.0, 2 * np.pi, 20001)
        xy = self.curve(th)
        seg = np.hypot(np.diff(xy[0]), np.diff(xy[1]))
        self._th_table = th
        self._s_table = np.concatenate([[0.0], np.cumsum(seg)])

    @property
    def length_m(self) -> float:
        """Length of one loop in metres."""
        return float(self._s_table[-1])

    @property
    def speed_mps(self) -> float:
        """Walking speed in m/s."""
        return self.speed_kmh / 3.6

    def curve(self, theta: np.ndarray) -> np.ndarray:
        """Loop centre line at polar angle ``theta`` (rad): float64 (2, N) world x, y."""
        th = np.asarray(theta, dtype=np.float64) + self.phase_rad
        w2, w3 = self.wobble
        r = self.radius_m * (1.0 + w2 * np.sin(2 * th) + w3 * np.cos(3 * th))
        return np.stack([r * np.cos(th), r * np.sin(th)])

    def centreline(self, n: int = 2000) -> np.ndarray:
        """``n`` points of the loop, float64 (n, 2) metres (used to lay the trail)."""
        return self.curve(np.linspace(0.0, 2 * np.pi, n, endpoint=False)).T

    def _theta_at(self, s_m: float) -> float:
        return float(np.interp(s_m % self.length_m, self._s_table, self._th_table))

    def pose(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Left camera pose at time ``t_s``: (R_wc float64 (3, 3), p_w float64 (3,))."""
        s = self.speed_mps * t_s
        th = self._theta_at(s)
        dth = 1e-4
        p0, p1 = self.curve(np.array([th - dth, th + dth])).T
        heading = float(np.arctan2(p1[1] - p0[1], p1[0] - p0[0]))
        centre = self.curve(np.array([th]))[:, 0]
        w_step = 2 * np.pi * self.step_hz * t_s
        w_stride = 0.5 * w_step
        left = np.array([-np.sin(heading), np.cos(heading)])
        xy = centre + left * self.sway_m * np.sin(w_stride)
        z = self.height_m + self.bounce_m * np.cos(w_step)
        yaw = heading + np.radians(self.yaw_deg) * np.sin(w_stride + 0.5)
        if self.turn_deg:
            yaw += np.radians(self.turn_deg) * np.sin(2 * np.pi * t_s / self.turn_period_s)
        pitch = np.radians(self.pitch_deg + self.nod_deg * np.cos(w_step + 0.3))
        roll = np.radians(self.roll_deg) * np.sin(w_stride)
        R = mat_mul(mat_mul(level_camera(yaw), rot_x(-pitch)), rot_z(roll))
        return R, np.array([xy[0], xy[1], z])
