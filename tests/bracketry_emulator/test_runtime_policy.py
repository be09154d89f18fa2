"""The runtime policy (runtime_policy.py): each profile's settings are in force after it is applied, applying it again
changes nothing, and a caller's own settings are kept. Each case runs in a fresh process: the policy is
process-wide."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from bracketry_emulator.runtime_policy import BATCH_GC_GEN0, PROFILES

PROBE = r"""
import ctypes, gc, json, sys
from bracketry_emulator.runtime_policy import apply_profile, applied_profiles

name = sys.argv[1]
if name != "-":
    apply_profile(name)
import numpy as np  # after the profile, as at an entry point
import cv2

def blas_threads():
    # the OpenBLAS numpy loaded, found among the mapped libraries
    libs = {line.split()[-1] for line in open("/proc/self/maps") if "openblas" in line.lower()}
    for lib in sorted(libs):
        dll = ctypes.CDLL(lib)
        for sym in ("scipy_openblas_get_num_threads64_", "openblas_get_num_threads64_", "openblas_get_num_threads"):
            if hasattr(dll, sym):
                return getattr(dll, sym)()
    return None

class MallInfo2(ctypes.Structure):
    _fields_ = [(f, ctypes.c_size_t) for f in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks",
                 "keepcost")]

def heap():
    # a 40 MB block: its own mmap (glibc's default: above 32 MiB always) or from the heap; kept after free or not
    libc = ctypes.CDLL(None)
    if not hasattr(libc, "mallinfo2"):
        return None
    libc.mallinfo2.restype = MallInfo2
    libc.malloc.restype = ctypes.c_void_p
    libc.free.argtypes = [ctypes.c_void_p]
    before = libc.mallinfo2()
    p = libc.malloc(40 << 20)
    during = libc.mallinfo2()
    libc.free(p)
    after = libc.mallinfo2()
    return {"mmapped": during.hblks - before.hblks, "kept_after_free": after.arena >= during.arena}

json.dump({"blas": blas_threads(), "opencv": cv2.getNumThreads(), "gc": list(gc.get_threshold()),
           "heap": heap(), "applied": sorted(applied_profiles())}, sys.stdout)
"""


_SETTINGS_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "GOTO_NUM_THREADS", "MKL_NUM_THREADS",
                 "OPENCV_FOR_THREADS_NUM", "GLIBC_TUNABLES")


def _probe(profile: str, **env: str) -> dict:
    # a fresh process with none of the thread and heap settings this test process may have picked up (e.g. Dask's
    # nanny puts OMP_NUM_THREADS=1 into os.environ when an earlier test of the session started a cluster)
    base = {k: v for k, v in os.environ.items() if k not in _SETTINGS_ENV and not k.startswith("MALLOC_")}
    res = subprocess.run([sys.executable, "-c", PROBE, profile], env={**base, **env}, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


@pytest.fixture(scope="module")
def untouched() -> dict:
    return _probe("-")


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_profile_settings_are_in_force(name: str, untouched: dict) -> None:
    profile = PROFILES[name]
    got = _probe(name)
    assert got["applied"] == [name]
    assert got["blas"] == (profile.blas_threads or untouched["blas"])
    assert got["opencv"] == (profile.opencv_threads or untouched["opencv"])
    assert got["gc"][0] == (profile.gc_gen0 or untouched["gc"][0])
    assert got["gc"][1:] == untouched["gc"][1:]
    if untouched["heap"] is None:
        pytest.skip("no mallinfo2 (not glibc >= 2.33)")
    if profile.heap is None:
        assert got["heap"] == untouched["heap"]
    else:  # an image-sized block comes from the heap and stays there for the next step
        assert got["heap"] == {"mmapped": 0, "kept_after_free": True}


def test_untouched_process_differs_from_the_profiles(untouched: dict) -> None:
    """The probe sees each setting change: glibc maps a 40 MB block of its own, OpenBLAS and OpenCV use the cores."""
    if untouched["heap"] is not None:
        assert untouched["heap"]["mmapped"] == 1
    assert untouched["gc"][0] < BATCH_GC_GEN0
    if (os.cpu_count() or 1) > 1:
        assert untouched["blas"] > 1
        assert untouched["opencv"] > 1


def test_caller_settings_are_kept() -> None:
    got = _probe("emulate", OPENBLAS_NUM_THREADS="2", GLIBC_TUNABLES="glibc.malloc.mmap_threshold=1048576")
    assert got["blas"] == 2
    if got["heap"] is not None:
        assert got["heap"]["mmapped"] == 1  # the caller's mmap threshold, not the profile's


def test_applying_again_changes_nothing_and_a_disabled_collector_stays_disabled() -> None:
    code = ("import gc\nfrom bracketry_emulator.runtime_policy import apply_profile\n"
            "apply_profile('emulate')\ngc.set_threshold(1234)\napply_profile('emulate')\n"
            "assert gc.get_threshold()[0] == 1234, gc.get_threshold()\n"
            "gc.set_threshold(0)\nfrom bracketry_emulator.runtime_policy import collect_less_often\n"
            "collect_less_often(20000)\nassert gc.get_threshold()[0] == 0\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr


def test_unknown_profile_is_refused() -> None:
    from bracketry_emulator.runtime_policy import apply_profile

    with pytest.raises(KeyError):
        apply_profile("no-such-profile")

