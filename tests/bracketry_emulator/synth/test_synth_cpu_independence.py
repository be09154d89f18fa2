"""The synthetic frames are the same bits on every x86-64 CPU (issue #29).

What could make them depend on the CPU: OpenBLAS (numpy's ``@``, ``np.dot``, ``np.linalg``) picks its kernel, and so
its rounding, by CPU (``OPENBLAS_CORETYPE`` forces one), and numpy's transcendental functions round differently under
its SIMD dispatch (``NPY_DISABLE_CPU_FEATURES`` turns targets off). The renderer uses neither: the ray rotation and
the pose products are explicit float64 sums (:func:`bracketry_emulator.synth.render.rotate_rays`,
:func:`bracketry_emulator.synth.trajectory.mat_mul`), the sky's halo its own exp
(:func:`bracketry_emulator.synth.render.exp_f32`). Here frames of both presets are rendered in subprocesses under
each OpenBLAS kernel the CPU runs and under numpy's baseline dispatch, and their bytes compared. Before those changes,
the Sandybridge and Prescott kernels changed 0.35 % of the pixels of a frame (some from black to white) and numpy's
baseline dispatch the radiance of 0.4 % of them (1 code in 6 of 17 million pixels)."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bracketry_emulator.synth.camera_model import N_LEVELS, srgb_oetf
from bracketry_emulator.synth.render import exp_f32, rotate_rays
from bracketry_emulator.synth.trajectory import mat_mul

#: renders a few frames of both presets and prints the digest of their radiance, range, codes (motion-blurred: the
#: reprojection of :mod:`bracketry_emulator.synth.blur`) and poses, then that of a product numpy sends to OpenBLAS
#: (it shows the kernels really differ)
_SCRIPT = """
import hashlib
import numpy as np
from bracketry_emulator.synth import World
h = hashlib.sha256()
for preset in ("forest-winter", "campus-summer"):
    w = World(preset, seed=0, resolution=(320, 200), detail=0.25)
    for t in (0.0, 7.7, 23.1):
        for side in ("left", "right"):
            r = w.radiance(side, t)
            for a in (r.radiance, r.range_m, w.render(side, t, 4000.0), w.render(side, t, 32000.0), w.pose(t, side),
                      *w.rates_e_per_us(side, [(t, 1000.0), (t + 0.1, 32000.0)], t_ref_s=t + 0.05)):
                h.update(np.ascontiguousarray(a).tobytes())
R = w.world_pose(7.7, "left")[0].astype(np.float32)
print(h.hexdigest(), hashlib.sha256((R @ w._renderer("left").rays).tobytes()).hexdigest())
"""

#: OpenBLAS kernels and the CPU flags each needs (forcing a kernel the CPU lacks would crash OpenBLAS)
_KERNELS = {"Haswell": {"avx2", "fma"}, "Sandybridge": {"avx"}, "Prescott": {"sse3"}}
_NUMPY_BASELINE = "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"


def _cpu_flags() -> set[str]:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    for line in text.splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return set()


def test_frames_are_the_same_under_every_openblas_kernel_and_numpy_dispatch() -> None:
    if platform.machine() not in ("x86_64", "AMD64"):
        pytest.skip("the OpenBLAS kernels compared are x86-64 ones")
    flags = _cpu_flags()
    settings: dict[str, dict[str, str]] = {"default": {}}
    settings.update({k: {"OPENBLAS_CORETYPE": k} for k, need in _KERNELS.items() if need <= flags})
    settings["numpy baseline"] = {"NPY_DISABLE_CPU_FEATURES": _NUMPY_BASELINE}
    base = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES")}
    procs = {name: subprocess.Popen([sys.executable, "-c", _SCRIPT], env={**base, **extra}, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True) for name, extra in settings.items()}
    out = {}
    for name, proc in procs.items():
        stdout, stderr = proc.communicate(timeout=300)
        assert proc.returncode == 0, (name, stderr[-2000:])
        out[name] = stdout.split()
    frames = {name: v[0] for name, v in out.items()}
    assert len(set(frames.values())) == 1, frames
    if {"Haswell", "Sandybridge"} <= settings.keys():
        # the kernels were really switched: OpenBLAS's product of the same rays differs
        assert out["Haswell"][1] != out["Sandybridge"][1]


def test_rotate_rays_is_the_float32_product_to_its_rounding() -> None:
    rng = np.random.default_rng(3)
    rays = rng.standard_normal((3, 10_000)).astype(np.float32)
    q = rng.standard_normal(4)
    a, b, c, d = q / np.sqrt(np.sum(q * q))
    R = np.array([[1 - 2 * (c * c + d * d), 2 * (b * c - a * d), 2 * (b * d + a * c)],
                  [2 * (b * c + a * d), 1 - 2 * (b * b + d * d), 2 * (c * d - a * b)],
                  [2 * (b * d - a * c), 2 * (c * d + a * b), 1 - 2 * (b * b + c * c)]])
    got = rotate_rays(R, rays, block=999)  # several chunks, the last one short
    exact = R.astype(np.float32).astype(np.float64) @ rays.astype(np.float64)
    assert got.dtype == np.float32
    # each step rounds to float32: within a few float32 ulps of the exact product
    assert np.all(np.abs(got - exact) <= 4 * np.spacing(np.abs(exact).astype(np.float32) + np.float32(1.0)))


def test_mat_mul_is_the_matrix_product() -> None:
    rng = np.random.default_rng(4)
    A, B, v = rng.standard_normal((3, 3)), rng.standard_normal((3, 3)), rng.standard_normal(3)
    assert np.allclose(mat_mul(A, B), A @ B, rtol=0, atol=1e-15)
    assert np.allclose(mat_mul(A, v), A @ v, rtol=0, atol=1e-15)
    assert mat_mul(A, v).shape == (3,)
    with pytest.raises(ValueError):
        mat_mul(A, np.zeros((3, 4)))


def test_exp_f32_is_exp_rounded_to_float32() -> None:
    x = np.concatenate([-np.geomspace(1e-8, 150.0, 20_000), [0.0, -1e-30, -87.0, -103.0, -104.0, -300.0]])
    x = x.astype(np.float32)
    got = exp_f32(x)
    assert got.dtype == np.float32
    ref = np.exp(x.astype(np.float64)).astype(np.float32)  # float64 exp rounded once: correct but at midpoints
    assert np.count_nonzero(got != ref) <= 2
    assert got[-6] == 1.0 and got[-1] == 0.0


def test_srgb_lut_is_far_from_its_rounding_thresholds() -> None:
    """The sRGB response LUT floors 4095 * OETF, a float64 power whose last bit depends on numpy's dispatch: every
    value lies far (relative to that last bit) from the integers where the floor would change."""
    v = 4095.0 * srgb_oetf(np.arange(N_LEVELS) / 4095.0)
    gap = np.abs(v - np.rint(v))[1:-1]  # not level 0 (exactly 0) nor 4095 (capped at the saturated code)
    assert np.all(gap > 1e-8 * v[1:-1])  # measured at least 3.3e-8 of the value; its last bit is 1.1e-16
