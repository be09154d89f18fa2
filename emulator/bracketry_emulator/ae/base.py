"""The AE method protocol and the image helpers every method shares.

An AE method is any object with::

    name: str
    reset(init_exposure_us: float) -> None
    next_exposure_us(image: np.ndarray, exposure_us: float, meta: dict) -> float

``image`` is the emulated raw RGGB Bayer mosaic (np.ndarray uint16 HxW, 12-bit codes 0..4095) that the camera
would have delivered at ``exposure_us`` (the exposure the method chose at the previous step, after the runner's
bounds; with gain, the exposure-equivalent: exposure x linear gain). The return value is the exposure (us) for the
next frame; the runner clamps it to its bounds. Beyond the longest bracket the camera takes the longest bracket's
exposure and the rest as analog gain (the emulator's ``beyond="gain"``). A method that sets the gain itself returns
a :class:`CameraSetting` (exposure us, gain dB) instead: the runner clamps the exposure to its bounds and the gain to
[0, ``max_gain_db``], and the image is the camera's at that exposure amplified by that gain (the sensor's noise at
that gain; ``exposure_us`` of the next call is then exposure x gain).

``meta`` (a plain dict, read-only for methods) holds at least:
    step (int, 0-based), timestamp_ns (int, timestamp of the frame), side ("left"/"right"),
    sequence_index (int), response (:class:`bracketry_emulator.crf.Response`, the camera response the emulator
    uses: methods that synthesise images with the CRF use the same curve), source_exposure_us (int, the bracket
    the image was emulated from), bounds_us ((min_us, max_us), the runner's exposure bounds),
    shared_gray (:class:`SharedGray` of this image: the runner shares gray conversions between the methods that see
    the same image; methods read it through :func:`gray_for` / :func:`work_gray_for`, which compute when absent),
    gain_db (float, the analog gain the image was taken with) and camera_exposure_us (float, its exposure:
    ``exposure_us`` / 10^(gain_db / 20)).

Optional attributes: ``init_exposure_us`` (the method's own first exposure, us), and the scheduling hints
``step_cost``, ``step_group``, ``created_in_worker`` (see :class:`.registry.MethodTraits` and PLUGINS.md).
"""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol, runtime_checkable

import cv2
import numpy as np

#: 12-bit full scale used by the authors' brightness targets (T = int(P / 100 * 4096)).
FULL_SCALE_12BIT = 4096


class CameraSetting(NamedTuple):
    """What a method that sets the gain itself returns from ``next_exposure_us``: the camera's exposure (us) and
    analog gain (dB, >= 0) for the next frame (module docstring)."""

    exposure_us: float
    gain_db: float


def gain_exposure_us(target_us: float, gain_db: float | None) -> float:
    """The camera exposure (us) of an exposure-equivalent ``target_us`` taken with ``gain_db`` (None: no gain)."""
    return target_us if gain_db is None else target_us / float(10.0 ** (gain_db / 20.0))


@runtime_checkable
class AEMethod(Protocol):
    """Protocol of an auto-exposure method (see the module docstring)."""

    name: str

    def reset(self, init_exposure_us: float) -> None:
        """Forget all state; the first image will be taken at ``init_exposure_us``."""

    def next_exposure_us(self, image: np.ndarray, exposure_us: float,
                         meta: dict[str, Any]) -> float | CameraSetting:
        """Exposure (us) of the next frame from the current image (uint16 HxW Bayer) taken at ``exposure_us``, or
        the camera's exposure and gain (:class:`CameraSetting`)."""


def bayer_gray(image: np.ndarray) -> np.ndarray:
    """Gray image of a raw RGGB mosaic exactly as the authors compute it: ``cv2.COLOR_BAYER_RG2GRAY``.

    Returns np.ndarray of the input dtype (uint16 12-bit codes -> uint16), HxW. Reproduced quirk: OpenCV's "RG"
    names the second row, so on this RGGB sensor true blue is weighted 0.299 and true red 0.114; the classical
    methods' brightness (and so their parity with the authors' runs) depends on this exact conversion.
    """
    if image.ndim != 2:
        raise ValueError(f"expected a HxW Bayer mosaic, got shape {image.shape}")
    return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BAYER_RG2GRAY)


def work_gray(image: np.ndarray, width: int) -> np.ndarray:
    """Float32 gray image (12-bit code units) downscaled with area averaging to ``width`` columns (0 = full size).

    Gradient-based methods work at a reduced size for speed (documented per method); the aspect ratio is kept.
    """
    return _work_from_gray(bayer_gray(image), width)


def _work_from_gray(gray_codes: np.ndarray, width: int) -> np.ndarray:
    gray = gray_codes.astype(np.float32)
    h, w = gray.shape
    if width <= 0 or width >= w:
        return gray
    height = max(1, round(h * width / w))
    return cv2.resize(gray, (width, height), interpolation=cv2.INTER_AREA)


class SharedGray:
    """Memo of one image's gray conversions, shared by the methods that see the same (never modified) image.

    The arrays it returns are read-only and equal :func:`bayer_gray` / :func:`work_gray` of ``image`` bit for bit.
    """

    def __init__(self, image: np.ndarray) -> None:
        self.image = image
        self._gray: np.ndarray | None = None
        self._work: dict[int, np.ndarray] = {}

    def gray(self) -> np.ndarray:
        """:func:`bayer_gray` of the image (uint16 HxW, read-only)."""
        if self._gray is None:
            self._gray = bayer_gray(self.image)
            self._gray.setflags(write=False)
        return self._gray

    def work(self, width: int) -> np.ndarray:
        """:func:`work_gray` of the image at ``width`` columns (float32, read-only)."""
        out = self._work.get(width)
        if out is None:
            out = _work_from_gray(self.gray(), width)
            out.setflags(write=False)
            self._work[width] = out
        return out


def _shared(image: np.ndarray, meta: dict[str, Any] | None) -> SharedGray | None:
    shared = meta.get("shared_gray") if meta else None
    return shared if isinstance(shared, SharedGray) and shared.image is image else None


def gray_for(image: np.ndarray, meta: dict[str, Any] | None = None) -> np.ndarray:
    """:func:`bayer_gray` of ``image``, from the runner's ``meta["shared_gray"]`` when it holds this image (then
    read-only: do not modify the result)."""
    shared = _shared(image, meta)
    return shared.gray() if shared is not None else bayer_gray(image)


def work_gray_for(image: np.ndarray, width: int, meta: dict[str, Any] | None = None) -> np.ndarray:
    """:func:`work_gray` of ``image``, shared like :func:`gray_for` (read-only when shared)."""
    shared = _shared(image, meta)
    return shared.work(width) if shared is not None else work_gray(image, width)


#: Default-mode saturation guard of the synthesis-based methods (Shim, Wang): above this fraction of pixels at the
#: saturated code, the method takes its own largest step towards a shorter exposure (see their docstrings).
SATURATION_GUARD = 0.10


def saturated_fraction(image: np.ndarray, meta: dict[str, Any] | None = None) -> float:
    """Fraction of the mosaic's pixels at or above the camera's saturated code (``meta["response"]``, else 4094)."""
    resp = meta.get("response") if meta else None
    code = int(getattr(resp, "saturated_code", 4094))
    return float(np.count_nonzero(image >= code)) / float(image.size)


class MethodError(ValueError):
    """A method got an input it cannot use (wrong shape, non-positive exposure)."""


def check_input(image: np.ndarray, exposure_us: float) -> None:
    """Raise MethodError unless ``image`` is a 2-D array and ``exposure_us`` a positive finite number."""
    if not isinstance(image, np.ndarray) or image.ndim != 2:
        raise MethodError(f"expected a HxW uint16 Bayer mosaic, got {getattr(image, 'shape', type(image))}")
    if not np.isfinite(exposure_us) or exposure_us <= 0:
        raise MethodError(f"exposure must be a positive number of us, got {exposure_us}")
