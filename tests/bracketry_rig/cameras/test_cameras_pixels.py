"""Pixel unpacking (PFNC BayerRG12p, bit-exact against a per-pixel reference) and 16-bit frame-id wrap."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bracketry_rig.cameras.frame_ids import FrameIdUnwrapper, id_delta
from bracketry_rig.cameras.pixels import pack_bayer_rg12p, payload_bytes, payload_to_image, unpack_bayer_rg12p


def reference_unpack(raw: bytes, n_pixels: int) -> list[int]:
    """Per-pixel PFNC Mono12p/BayerRG12p reading straight from the spec: pixel i starts at bit 12*i, LSB first."""
    out = []
    for i in range(n_pixels):
        bit = 12 * i
        value = 0
        for b in range(12):
            byte = raw[(bit + b) // 8]
            value |= ((byte >> ((bit + b) % 8)) & 1) << b
        out.append(value)
    return out


def test_known_vector() -> None:
    # p0 = 0xABC, p1 = 0x123 -> b0 = 0xBC, b1 = 0x3A (p1 low nibble 3, p0 high nibble A), b2 = 0x12
    raw = bytes([0xBC, 0x3A, 0x12])
    assert unpack_bayer_rg12p(raw, 2, 1).tolist() == [[0xABC, 0x123]]
    assert pack_bayer_rg12p(np.array([[0xABC, 0x123]], np.uint16)) == raw


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 8), st.integers(1, 6).map(lambda w: 2 * w), st.randoms(use_true_random=False))
def test_unpack_matches_reference(height: int, width: int, rnd) -> None:  # type: ignore[no-untyped-def]
    raw = bytes(rnd.getrandbits(8) for _ in range(width * height * 3 // 2))
    got = unpack_bayer_rg12p(raw, width, height)
    assert got.dtype == np.uint16 and got.shape == (height, width)
    assert got.ravel().tolist() == reference_unpack(raw, width * height)
    assert pack_bayer_rg12p(got) == raw


def test_full_frame_round_trip_and_errors() -> None:
    rng = np.random.default_rng(1)
    img = rng.integers(0, 4096, size=(1200, 1920), dtype=np.uint16)
    raw = pack_bayer_rg12p(img)
    assert len(raw) == payload_bytes("BayerRG12p", 1920, 1200) == 1920 * 1200 * 3 // 2
    assert np.array_equal(payload_to_image(raw + b"chunkdata", "BayerRG12p", 1920, 1200), img)
    with pytest.raises(ValueError):
        unpack_bayer_rg12p(raw[:-1], 1920, 1200)
    with pytest.raises(ValueError):
        pack_bayer_rg12p(np.array([4096, 0], np.uint16))


def test_mono16_and_8bit_payloads() -> None:
    img = np.array([[1, 4095], [256, 7]], np.uint16)
    assert np.array_equal(payload_to_image(img.astype("<u2").tobytes(), "Mono16", 2, 2), img)
    assert payload_to_image(bytes([1, 2, 3, 255]), "BayerRG8", 2, 2).tolist() == [[1, 2], [3, 255]]


def test_frame_id_wrap_skips_zero() -> None:
    assert id_delta(65535, 1) == 1
    assert id_delta(65534, 2) == 3
    u = FrameIdUnwrapper()
    ids = [65533, 65534, 65535, 1, 2, 4, 5]
    results = [u.update(i) for i in ids]
    assert [r[0] for r in results] == [0, 1, 2, 3, 4, 6, 7]
    assert [r[1] for r in results] == [0, 0, 0, 0, 0, 1, 0]
    # a repeated id is flagged, not turned into a 65534-frame gap
    assert u.update(5) == (8, -1)


def test_a_late_buffer_gets_its_own_index_and_does_not_shift_the_next_frames() -> None:
    """Aravis hands over a timed-out buffer after newer frames: it takes its own place, later frames keep theirs
    (arrival order would shift every following frame by one pulse)."""
    u = FrameIdUnwrapper()
    got = [u.update(i) for i in (65420, 65421, 65422, 65424, 65425)]  # 65423 not there yet
    assert [g[0] for g in got] == [0, 1, 2, 4, 5] and got[3][1] == 1
    assert u.update(65423) == (3, -1)  # late: its own index, flagged
    assert u.update(65426) == (6, 0)  # the next frame is not shifted
    assert u.update(65535) == (115, 108) and u.update(2) == (117, 1)  # across the wrap (0 is skipped)
    assert u.update(65534) == (114, -1)  # late across the wrap
    assert u.update(3) == (118, 0)
    # a camera reset (ids far behind) is not a late buffer: the index just goes on
    assert u.update(40000) == (119, -1)


def test_a_buffer_without_an_id_stands_for_the_next_id() -> None:
    """Under GVSP packet loss Aravis hands over a frame whose leader was lost with id 0: it is the frame between its
    neighbours, so the frame after it keeps its own index (counting it as one more frame shifted every later frame
    by one pulse, and its pulse became a drop)."""
    u = FrameIdUnwrapper()
    assert [u.update(i) for i in (65414, 65415, 0, 65417, 65418)] == [(0, 0), (1, 0), (2, 0), (3, 0), (4, 0)]
    assert [u.update(i) for i in (65535, 0, 2)] == [(121, 116), (122, 0), (123, 0)]  # across the wrap (0 skipped)
    assert u.update(0) == (124, 0) and u.update(5) == (126, 1)  # a frame really missing after it is still counted
